// Instrument descriptions (strict JSON), sampling plans, and the output
// files of a synthetic measurement (CSV, JSON sidecar, MERL, OpenEXR), plus
// the `brdfkit synth` command.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "brdf/merl.h"
#include "brdf/model.h"
#include "brdf/params.h"
#include "data_synth/outputs.h"
#include "data_synth/synth.h"
#include "tests/cli_util.h"

namespace brdfkit::synth {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

std::string ErrorOf(const json& j) {
  try {
    ParseInstrument(j, "lab.json");
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

std::string Slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

TEST(Instrument, DefaultRoundTripsThroughJson) {
  const json j = InstrumentToJson(DefaultInstrument());
  const Instrument back = ParseInstrument(j, "default");
  EXPECT_EQ(InstrumentToJson(back), j);
  EXPECT_NEAR(back.detector.angular_radius, 1 * kDeg, 1e-15);
  EXPECT_EQ(back.plan.theta_o.size(), 35u);
  EXPECT_FALSE(back.imperfections.Any());
}

TEST(Instrument, EveryImperfectionRoundTrips) {
  json j = InstrumentToJson(DefaultInstrument());
  j["source"] = {{"type", "disc"}, {"angular_radius_deg", 0.5}, {"radiance", {1e4, 2e4, 3e4}}};
  j["imperfections"] = {{"jitter", {{"source_deg", 0.05}, {"detector_deg", 0.1}}},
                        {"shot_noise", true},
                        {"read_noise", {{"electrons", 10}}},
                        {"dark", {{"electrons_per_second", 100}}},
                        {"adc", {{"bits", 14}, {"gain", 3.5}}},
                        {"saturation", {{"full_well", 1e5}, {"hdr_exposures", {1e-4, 1e-3}}}},
                        {"drift", {{"relative_per_sample", 1e-6}}}};
  j["plan"] = {{"type", "full"},
               {"theta_i_deg", {{"start", 0}, {"stop", 60}, {"count", 4}}},
               {"phi_i_deg", {0}},
               {"theta_o_deg", {10, 20}},
               {"phi_o_deg", {{"start", 0}, {"stop", 180}, {"count", 3}}}};
  const Instrument inst = ParseInstrument(j, "lab.json");
  EXPECT_NEAR(inst.plan.theta_i[2], 40 * kDeg, 1e-15);
  EXPECT_EQ(inst.imperfections.adc_bits, 14);
  EXPECT_NEAR(inst.source.BeamIrradiance()[1], 2e4 * kPi * std::pow(std::sin(0.5 * kDeg), 2), 1e-9);
  EXPECT_EQ(InstrumentToJson(ParseInstrument(InstrumentToJson(inst), "again")), InstrumentToJson(inst));
  const ExpandedPlan plan = ExpandPlan(inst.plan);
  EXPECT_EQ(plan.pairs.size(), 4u * 2u * 3u);
  EXPECT_EQ(plan.image_width, 6);
  EXPECT_EQ(plan.image_height, 4);
}

TEST(Instrument, ErrorsNameTheFileAndKeyPath) {
  const json good = InstrumentToJson(DefaultInstrument());
  json j = good;
  j["detector"]["aperture"] = 1;
  EXPECT_NE(ErrorOf(j).find("lab.json: detector.aperture: unknown key"), std::string::npos) << ErrorOf(j);
  j = good;
  j["source"]["irradiance"] = "bright";
  EXPECT_NE(ErrorOf(j).find("lab.json: source.irradiance"), std::string::npos) << ErrorOf(j);
  j = good;
  j["sample"].erase("area");
  EXPECT_NE(ErrorOf(j).find("sample.area: missing"), std::string::npos) << ErrorOf(j);
  j = good;
  j["detector"]["angular_radius_deg"] = -1;
  EXPECT_NE(ErrorOf(j).find("detector.angular_radius_deg: value -1"), std::string::npos) << ErrorOf(j);
  j = good;
  j["plan"] = {{"type", "spiral"}};
  EXPECT_NE(ErrorOf(j).find("plan.type: unknown plan type 'spiral'"), std::string::npos) << ErrorOf(j);
  j = good;
  j["imperfections"] = {{"adc", {{"bits", 12.5}, {"gain", 1}}}};
  EXPECT_NE(ErrorOf(j).find("imperfections.adc.bits"), std::string::npos) << ErrorOf(j);
  j = good;
  j["imperfections"] = {{"shot_noise", true}};
  j["detector"]["angular_radius_deg"] = 0;
  EXPECT_NE(ErrorOf(j).find("point detector"), std::string::npos) << ErrorOf(j);
  EXPECT_THROW(LoadInstrument("/nonexistent/lab.json"), std::runtime_error);
  const fs::path d = test::FreshDir("synth-badjson");
  std::ofstream(d / "lab.json") << "{\"source\": ";
  try {
    LoadInstrument((d / "lab.json").string());
    ADD_FAILURE();
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("lab.json: not valid JSON"), std::string::npos) << e.what();
  }
}

TEST(Instrument, ListPlanReadsRelativeFilesAndReportsBadLines) {
  const fs::path d = test::FreshDir("synth-list");
  std::ofstream(d / "dirs.csv") << "# my plan\ntheta_i,phi_i,theta_o,phi_o\n10,0,20,180\n30 45 40 200\n";
  std::ofstream(d / "lab.json") << json{{"source", {{"type", "collimated"}, {"irradiance", 1}}},
                                        {"detector", {{"angular_radius_deg", 0}, {"responsivity", 1e18},
                                                      {"exposure_time", 1e-3}}},
                                        {"sample", {{"area", 1e-4}, {"tilt_x_deg", 0}, {"tilt_y_deg", 0}}},
                                        {"plan", {{"type", "list"}, {"file", "dirs.csv"}, {"units", "deg"}}}}
                                       .dump();
  const Instrument inst = LoadInstrument((d / "lab.json").string());
  const ExpandedPlan plan = ExpandPlan(inst.plan);
  ASSERT_EQ(plan.pairs.size(), 2u);
  EXPECT_NEAR(plan.pairs[1].phi_i, 45 * kDeg, 1e-15);
  EXPECT_NEAR(plan.pairs[1].phi_o, 200 * kDeg, 1e-15);
  std::ofstream(d / "dirs.csv") << "10,0,20,180\n10,0,abc,180\n";
  try {
    ExpandPlan(inst.plan);
    ADD_FAILURE();
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("dirs.csv:2: 'abc' is not a number"), std::string::npos) << e.what();
  }
}

TEST(Outputs, CsvAndSidecarReproduceTheDataSet) {
  Instrument inst = DefaultInstrument();
  inst.imperfections.shot_noise = true;
  inst.imperfections.read_noise = 20;
  const Model model = Model::Parse("lambert+ggx");
  const std::vector<double> p = ParseParams(model.Info(), "lambert.albedo=0.2,ggx.alpha=0.3");
  const SynthResult r = Synthesize(inst, model, p, 77);
  Provenance prov{model.Spec(), p, FormatParams(model.Info(), p), 77, ""};
  const fs::path d = test::FreshDir("synth-csv");
  const std::string out = (d / "data.csv").string();
  WriteSynthOutput(out, inst, r, prov);
  const BrdfTable t = ReadTableCsv(out);
  EXPECT_TRUE(t.has_sigma);
  ASSERT_EQ(t.rows.size(), r.report.measured);
  std::size_t k = 0;
  for (const SynthSample& s : r.samples) {
    if (!s.valid) continue;
    EXPECT_EQ(t.rows[k].f[1], s.f[1]);
    EXPECT_EQ(t.rows[k].sigma[2], s.sigma[2]);
    EXPECT_GT(s.sigma[0], 0);
    ++k;
  }
  EXPECT_EQ(Slurp(out).substr(0, 64), "theta_i,phi_i,theta_o,phi_o,f_r,f_g,f_b,sigma_r,sigma_g,sigma_b\n");
  // Regenerate from the sidecar alone: identical bytes.
  const json side = json::parse(Slurp(out + ".json"));
  EXPECT_FALSE(side["brdfkit_version"].get<std::string>().empty());
  EXPECT_EQ(side["seed"], 77);
  const Instrument inst2 = ParseInstrument(side["instrument"], "sidecar");
  const Model model2 = Model::Parse(side["model"].get<std::string>());
  const SynthResult r2 =
      Synthesize(inst2, model2, side["params"].get<std::vector<double>>(), side["seed"].get<std::uint64_t>());
  const std::string out2 = (d / "again.csv").string();
  WriteSynthOutput(out2, inst2, r2, prov);
  EXPECT_EQ(Slurp(out), Slurp(out2));
}

TEST(Outputs, MerlPlanWritesAReadableMerlFileAndAnImage) {
  Instrument inst = DefaultInstrument();
  inst.plan.kind = SamplingPlan::Kind::kMerl;
  inst.plan.merl_stride[0] = 10;
  inst.plan.merl_stride[1] = 9;
  inst.plan.merl_stride[2] = 20;
  const Model model = Model::Parse("ggx");
  const std::vector<double> p = ParseParams(model.Info(), "alpha=0.25");
  const SynthResult r = Synthesize(inst, model, p, 0);
  ASSERT_EQ(r.samples.size(), 9u * 10u * 9u);
  const fs::path d = test::FreshDir("synth-merl");
  Provenance prov{model.Spec(), p, FormatParams(model.Info(), p), 0, ""};
  WriteSynthOutput((d / "m.binary").string(), inst, r, prov);
  WriteSynthOutput((d / "m.exr").string(), inst, r, prov);
  EXPECT_EQ(fs::file_size(d / "m.binary"), MerlTable::kFileSize);
  const MerlTable t = MerlTable::Read((d / "m.binary").string());
  const ExrImage img = ReadExrFloat((d / "m.exr").string());
  EXPECT_EQ(img.width, 10);
  EXPECT_EQ(img.height, 9 * 9);
  EXPECT_EQ(img.attributes.at("brdfkit.layout").substr(0, 12), "phi_d blocks");
  std::size_t valid = 0;
  for (std::size_t n = 0; n < r.samples.size(); ++n) {
    const std::size_t cell = static_cast<std::size_t>(r.plan.merl_cell[n]);
    const std::size_t px = static_cast<std::size_t>(r.plan.pixel[n]);
    if (!r.samples[n].valid) {
      EXPECT_LT(t.values[cell], 0);
      EXPECT_EQ(img.channels.at("A")[px], 0.f);
      continue;
    }
    ++valid;
    for (int c = 0; c < 3; ++c) {
      const double v = t.values[c * MerlTable::kCells + cell];
      EXPECT_NEAR(v, r.samples[n].f[c], 1e-12 * r.samples[n].f[c] + 1e-300);
    }
    EXPECT_EQ(img.channels.at("G")[px], float(r.samples[n].f[1]));
    EXPECT_EQ(img.channels.at("A")[px], 1.f);
  }
  EXPECT_GT(valid, 400u);
  // Cells skipped by the stride stay missing.
  EXPECT_LT(t.values[MerlTable::Index(1, 1, 1)], 0);
  // A grid-less plan cannot make an image, a non-MERL plan no MERL file.
  inst.plan.kind = SamplingPlan::Kind::kInPlane;
  const SynthResult r2 = Synthesize(inst, model, p, 0);
  EXPECT_THROW(WriteSynthOutput((d / "x.binary").string(), inst, r2, prov), std::runtime_error);
  EXPECT_FALSE(fs::exists(d / "x.binary"));
  EXPECT_THROW(WriteSynthOutput((d / "x.txt").string(), inst, r2, prov), std::runtime_error);
}

int RunCli(const std::string& args, std::string* err = nullptr) {
  const std::string log = test::ScratchPath("synth_cli_log.txt").string();
  const int rc = std::system((std::string(BRDFKIT_EXE) + " " + args + " 2>" + log).c_str());
  if (err) *err = Slurp(log);
  return WEXITSTATUS(rc);
}

TEST(SynthCli, WritesTableAndSidecarAndRejectsBadInput) {
  const fs::path d = test::FreshDir("synth-cli");
  std::string err;
  ASSERT_EQ(RunCli("synth -m lambert -p albedo=0.5 --seed 3 -q --out " + (d / "a.csv").string(), &err), 0) << err;
  const BrdfTable t = ReadTableCsv((d / "a.csv").string());
  ASSERT_FALSE(t.rows.empty());
  EXPECT_FALSE(t.has_sigma);  // noiseless
  for (const BrdfSample& s : t.rows) EXPECT_NEAR(s.f[0], 0.5 / kPi, 1e-13);
  EXPECT_EQ(json::parse(Slurp(d / "a.csv.json"))["seed"], 3);

  // --print-instrument output is itself a valid instrument.
  ASSERT_EQ(RunCli("synth --print-instrument > " + (d / "lab.json").string()), 0);
  json lab = json::parse(Slurp(d / "lab.json"));
  lab["detector"]["exposure_time"] = "long";
  std::ofstream(d / "bad.json") << lab.dump();
  EXPECT_EQ(RunCli("synth -m lambert --instrument " + (d / "bad.json").string() + " --out " + (d / "b.csv").string(), &err),
            2);
  EXPECT_NE(err.find("bad.json: detector.exposure_time: expected a number"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(d / "b.csv"));
  EXPECT_EQ(RunCli("synth -m ggx -p alpha=-1 --out " + (d / "c.csv").string(), &err), 2);
  EXPECT_NE(err.find("alpha"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(d / "c.csv"));
}

}  // namespace
}  // namespace brdfkit::synth
