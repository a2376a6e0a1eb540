// `brdfkit run`: plans that compute only what the requested outputs need,
// the content-keyed cache, malformed scenes rejected before any work, the
// report in a headless browser, and Ctrl-C.
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <map>
#include <regex>
#include <thread>

#include "tests/cli_util.h"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using brdfkit::test::Brdfkit;
using brdfkit::test::CliRun;
using brdfkit::test::FreshDir;
using brdfkit::test::ReadText;
using brdfkit::test::WriteText;

// A small scene with every task type; `outputs` chooses what is wanted.
json SmallScene(const json& outputs = nullptr) {
  json s = json::parse(R"({
    "title": "test scene",
    "output": "out",
    "materials": {
      "plastic": {"model": "lambert+ggx", "params": {"lambert.albedo": [0.1, 0.2, 0.4], "ggx.alpha": 0.2, "ggx.f0": 0.04}},
      "phong": {"model": "phong_original", "params": "ks=1,n=1"},
      "fitted": {"fit": "fit_a"}
    },
    "instruments": {"gonio": {"type": "gonioreflectometer", "spec": {
      "source": {"type": "collimated", "irradiance": 10},
      "detector": {"angular_radius_deg": 0, "responsivity": 1e18, "exposure_time": 0.001},
      "sample": {"area": 1e-4, "tilt_x_deg": 0, "tilt_y_deg": 0},
      "plan": {"type": "in_plane", "theta_i_deg": {"start": 0, "stop": 60, "count": 3},
               "theta_o_deg": {"start": -80, "stop": 80, "count": 33}}}}},
    "tasks": [
      {"name": "ggx_table", "type": "albedo", "model": "ggx", "axes": "mu:6,alpha:5:0.05:1", "formats": ["csv"]},
      {"name": "beckmann_table", "type": "albedo", "model": "beckmann", "axes": "mu:6,alpha:5:0.05:1", "formats": ["csv"]},
      {"name": "measure", "type": "synth", "material": "plastic", "instrument": "gonio", "seed": 3},
      {"name": "fit_a", "type": "fit", "data": "measure", "model": "lambert+ggx", "starts": 2},
      {"name": "fit_b", "type": "fit", "data": "measure", "model": "lambert+beckmann", "starts": 2},
      {"name": "verdicts", "type": "check", "materials": ["phong", "fitted"], "sampling": false}
    ]
  })");
  if (!outputs.is_null()) s["outputs"] = outputs;
  return s;
}

std::map<std::string, std::string> PlanActions(const CliRun& r) {
  std::map<std::string, std::string> out;
  const json j = json::parse(r.out);
  for (const json& p : j.at("plan")) out[p.at("task").get<std::string>()] = p.at("action").get<std::string>();
  return out;
}

std::vector<std::string> PlanOrder(const CliRun& r) {
  std::vector<std::string> out;
  const json j = json::parse(r.out);
  for (const json& p : j.at("plan"))
    if (p.at("action").get<std::string>() != "skip") out.push_back(p.at("task").get<std::string>());
  return out;
}

std::size_t IndexOf(const std::vector<std::string>& v, const std::string& x) {
  return static_cast<std::size_t>(std::find(v.begin(), v.end(), x) - v.begin());
}

TEST(Run, DryRunOfAnAlbedoOnlySceneComputesNothingElse) {
  const fs::path d = FreshDir("albedo-only");
  WriteText(d / "scene.json", SmallScene({"ggx_table"}).dump());
  const CliRun r = Brdfkit("run " + (d / "scene.json").string() + " --out " + (d / "out").string() + " --dry-run --json");
  ASSERT_EQ(r.code, 0) << r.out;
  const auto actions = PlanActions(r);
  EXPECT_EQ(actions.at("ggx_table"), "run");
  for (const char* other : {"beckmann_table", "measure", "fit_a", "fit_b", "verdicts"}) EXPECT_EQ(actions.at(other), "skip") << other;
  EXPECT_FALSE(fs::exists(d / "out")) << "a dry run writes nothing";

  // The real run: only the GGX table is made.
  const CliRun run = Brdfkit("run " + (d / "scene.json").string() + " --out " + (d / "out").string() + " --quiet");
  ASSERT_EQ(run.code, 0) << run.out;
  EXPECT_TRUE(fs::exists(d / "out" / "ggx_table" / "albedo.csv"));
  for (const char* other : {"beckmann_table", "measure", "fit_a", "fit_b", "verdicts"})
    EXPECT_FALSE(fs::exists(d / "out" / other)) << other;
  const json results = json::parse(ReadText(d / "out" / "results.json"));
  ASSERT_EQ(results.at("tasks").size(), 1u);
  EXPECT_EQ(results.at("tasks")[0].at("name"), "ggx_table");
}

TEST(Run, ACheckOfAFittedMaterialPullsInTheFitAndItsDataOnce) {
  const fs::path d = FreshDir("deps");
  WriteText(d / "scene.json", SmallScene({"verdicts", "fit_b"}).dump());
  const CliRun r = Brdfkit("run " + (d / "scene.json").string() + " --out " + (d / "out").string() + " --dry-run --json");
  ASSERT_EQ(r.code, 0) << r.out;
  const auto actions = PlanActions(r);
  EXPECT_EQ(actions.at("measure"), "run");
  EXPECT_EQ(actions.at("fit_a"), "run");
  EXPECT_EQ(actions.at("fit_b"), "run");
  EXPECT_EQ(actions.at("verdicts"), "run");
  EXPECT_EQ(actions.at("ggx_table"), "skip");
  EXPECT_EQ(actions.at("beckmann_table"), "skip");
  const auto order = PlanOrder(r);
  ASSERT_EQ(order.size(), 4u) << "measure is synthesised once for both fits";
  EXPECT_LT(IndexOf(order, "measure"), IndexOf(order, "fit_a"));
  EXPECT_LT(IndexOf(order, "measure"), IndexOf(order, "fit_b"));
  EXPECT_LT(IndexOf(order, "fit_a"), IndexOf(order, "verdicts"));
}

TEST(Run, SecondRunRecomputesNothingAndAChangeRecomputesOnlyWhatDependsOnIt) {
  const fs::path d = FreshDir("cache");
  const std::string scene = (d / "scene.json").string(), out = (d / "out").string();
  WriteText(scene, SmallScene().dump());
  const CliRun first = Brdfkit("run " + scene + " --out " + out + " --quiet");
  ASSERT_EQ(first.code, 0) << first.out;
  const auto csv_time = fs::last_write_time(d / "out" / "measure" / "data.csv");
  const auto fit_time = fs::last_write_time(d / "out" / "fit_a" / "fit.json");

  // Unchanged scene: everything up to date, no file rewritten.
  const CliRun plan = Brdfkit("run " + scene + " --out " + out + " --dry-run --json");
  for (const auto& [task, action] : PlanActions(plan)) EXPECT_EQ(action, "cached") << task;
  const CliRun second = Brdfkit("run " + scene + " --out " + out + " --quiet");
  ASSERT_EQ(second.code, 0) << second.out;
  EXPECT_EQ(fs::last_write_time(d / "out" / "measure" / "data.csv"), csv_time);
  EXPECT_EQ(fs::last_write_time(d / "out" / "fit_a" / "fit.json"), fit_time);
  const json results = json::parse(ReadText(d / "out" / "results.json"));
  for (const json& t : results.at("tasks")) EXPECT_EQ(t.at("status").get<std::string>(), "cached");

  // A new material colour: the synth, both fits and the check of the fitted
  // material are out of date; the albedo tables are not.
  json s = SmallScene();
  s["materials"]["plastic"]["params"]["lambert.albedo"] = json::array({0.1, 0.2, 0.5});
  WriteText(scene, s.dump());
  const auto actions = PlanActions(Brdfkit("run " + scene + " --out " + out + " --dry-run --json"));
  EXPECT_EQ(actions.at("ggx_table"), "cached");
  EXPECT_EQ(actions.at("beckmann_table"), "cached");
  for (const char* t : {"measure", "fit_a", "fit_b", "verdicts"}) EXPECT_EQ(actions.at(t), "run") << t;

  // A deleted output is recomputed.
  WriteText(scene, SmallScene().dump());
  fs::remove(d / "out" / "ggx_table" / "albedo.csv");
  const auto again = PlanActions(Brdfkit("run " + scene + " --out " + out + " --dry-run --json"));
  EXPECT_EQ(again.at("ggx_table"), "run");
  EXPECT_EQ(again.at("beckmann_table"), "cached");
}

TEST(Run, TheFitInTheSceneRecoversTheSynthesisedMaterial) {
  const fs::path d = FreshDir("fit");
  WriteText(d / "scene.json", SmallScene({"fit_a"}).dump());
  const CliRun r = Brdfkit("run " + (d / "scene.json").string() + " --out " + (d / "out").string() + " --quiet");
  ASSERT_EQ(r.code, 0) << r.out;
  const json fit = json::parse(ReadText(d / "out" / "fit_a" / "fit.json"));
  // Point apertures, no noise: the data is the model itself.
  EXPECT_NEAR(fit.at("params").at("ggx.alpha").get<double>(), 0.2, 1e-6);
  EXPECT_NEAR(fit.at("params").at("lambert.albedo")[2].get<double>(), 0.4, 1e-6);
  EXPECT_NEAR(fit.at("params").at("ggx.f0")[0].get<double>(), 0.04, 1e-6);
  // The fit result is usable as a model anywhere.
  const CliRun e = Brdfkit("eval --model fit:" + (d / "out" / "fit_a" / "fit.json").string() +
                           " --wi 0,0,1 --wo 0,0,1 --json");
  ASSERT_EQ(e.code, 0) << e.out;
}

// A scene's fit task takes the random starts and their seed: the optima
// listed are theirs and the synthesised material is recovered.
TEST(Run, ASceneFitTakesRandomStarts) {
  const fs::path d = FreshDir("fit_random");
  json scene = SmallScene({"fit_a"});
  for (json& t : scene["tasks"])
    if (t["name"] == "fit_a") {
      t["random_starts"] = 3;
      t["seed"] = 7;
    }
  WriteText(d / "scene.json", scene.dump());
  const CliRun r = Brdfkit("run " + (d / "scene.json").string() + " --out " + (d / "out").string() + " --quiet");
  ASSERT_EQ(r.code, 0) << r.out;
  const json fit = json::parse(ReadText(d / "out" / "fit_a" / "fit.json"));
  EXPECT_EQ(fit.at("starts").get<int>(), 3);
  for (const json& o : fit.at("local_optima")) EXPECT_EQ(o.at("origin"), "random start");
  EXPECT_NEAR(fit.at("params").at("ggx.alpha").get<double>(), 0.2, 1e-6);
  EXPECT_NEAR(fit.at("params").at("lambert.albedo")[2].get<double>(), 0.4, 1e-6);
}

// A measured material from a MERL file (written by the synthesiser from a
// known lambert+ggx on every 3rd/3rd/6th bin; the rest are missing, -1) is
// fitted back; the check task defined beside it is not requested.
TEST(Run, AMerlMaterialIsFittedBack) {
  const fs::path d = FreshDir("merl");
  WriteText(d / "inst.json", R"({"source": {"type": "collimated", "irradiance": 10},
    "detector": {"angular_radius_deg": 0, "responsivity": 1e18, "exposure_time": 0.001},
    "sample": {"area": 1e-4, "tilt_x_deg": 0, "tilt_y_deg": 0},
    "plan": {"type": "merl", "stride": [3, 3, 6]}})");
  const CliRun s = Brdfkit("synth -m lambert+ggx -p lambert.albedo=0.1:0.2:0.3,ggx.alpha=0.1,ggx.f0=0.05 -i " +
                           (d / "inst.json").string() + " -o " + (d / "scan.binary").string() + " -q");
  ASSERT_EQ(s.code, 0) << s.out;
  WriteText(d / "scene.json", R"({"materials": {"scan": {"merl": "scan.binary"}},
    "tasks": [{"name": "fit_scan", "type": "fit", "data": "scan", "model": "lambert+ggx", "starts": 2},
              {"name": "check_scan", "type": "check", "materials": ["scan"]}],
    "outputs": ["fit_scan"]})");
  const CliRun r = Brdfkit("run " + (d / "scene.json").string() + " --out " + (d / "out").string() + " --quiet");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_FALSE(fs::exists(d / "out" / "check_scan"));
  const json fit = json::parse(ReadText(d / "out" / "fit_scan" / "fit.json"));
  EXPECT_NEAR(fit.at("params").at("ggx.alpha").get<double>(), 0.1, 1e-9);
  EXPECT_NEAR(fit.at("params").at("lambert.albedo")[2].get<double>(), 0.3, 1e-9);
  EXPECT_GT(fit.at("missing").get<long long>(), 1000000) << "the skipped bins are counted as missing";
}

// Every measured format enters a scene as a "measured" material, chosen by
// the file's extension and checked against its header: an ASTM table and a
// UTIA file tabulated from a known model are fitted back to it, and an RGL
// file is checked and measured like any BRDF.
TEST(Run, MeasuredMaterialsOfEveryFormat) {
  const fs::path d = FreshDir("measured");
  const std::string model = "-m lambert+ggx -p lambert.albedo=0.2,ggx.alpha=0.3,ggx.f0=0.04 ";
  for (const char* file : {"scan.astm", "scan.utia", "scan.bsdf"}) {
    // RGL at a reduced resolution: the scene's tasks, not the table's accuracy, are tested here.
    const std::string rgl = std::string(file) == "scan.bsdf" ? "--rgl-theta-i 24 --rgl-samples 64 --rgl-vndf 64 " : "";
    const CliRun c = Brdfkit("convert " + model + rgl + (d / file).string());
    ASSERT_EQ(c.code, 0) << file << "\n" << c.out;
  }
  WriteText(d / "scene.json", R"({"materials": {"astm": {"measured": "scan.astm"}, "utia": {"measured": "scan.utia"},
                                              "rgl": {"measured": "scan.bsdf"}},
    "tasks": [{"name": "fit_astm", "type": "fit", "data": "astm", "model": "lambert+ggx", "starts": 2},
              {"name": "fit_utia", "type": "fit", "data": "utia", "model": "lambert+ggx", "starts": 2},
              {"name": "check_rgl", "type": "check", "materials": ["rgl"], "sampling": false, "albedo_budget": 20000},
              {"name": "measure_rgl", "type": "synth", "material": "rgl", "instrument": "gonio"}],
    "instruments": {"gonio": {"type": "gonioreflectometer"}}})");
  const CliRun r = Brdfkit("run " + (d / "scene.json").string() + " --out " + (d / "out").string() + " --quiet");
  ASSERT_EQ(r.code, 0) << r.out;
  for (const char* task : {"fit_astm", "fit_utia"}) {
    const json fit = json::parse(ReadText(d / "out" / task / "fit.json"));
    // The tables hold the model at their nodes; the formats' own interpolation
    // between them is what the fit sees.
    EXPECT_NEAR(fit.at("params").at("ggx.alpha").get<double>(), 0.3, 0.03) << task;
    EXPECT_NEAR(fit.at("params").at("lambert.albedo")[1].get<double>(), 0.2, 0.02) << task;
  }
  const json check = json::parse(ReadText(d / "out" / "check_rgl" / "check.json"));
  EXPECT_EQ(check[0].at("model").get<std::string>(), "rgl");
  // The table's interpolation keeps the adaptive rule from converging: each
  // albedo spends its budget, here the scene's, not the default 400,000.
  const double albedos = check[0].at("albedo_evaluations").get<double>();
  EXPECT_GT(albedos, 10);
  EXPECT_LT(check[0].at("albedo_integrand_evaluations").get<double>(), 50000 * albedos);
  EXPECT_TRUE(fs::exists(d / "out" / "measure_rgl" / "data.csv"));
  // A file whose header disagrees with its name is named at its key.
  WriteText(d / "fake.bsdf", "not a tensor file");
  WriteText(d / "bad.json", R"({"materials": {"m": {"measured": "fake.bsdf"}},
    "tasks": [{"name": "c", "type": "check", "materials": ["m"]}]})");
  const CliRun b = Brdfkit("run " + (d / "bad.json").string() + " --out " + (d / "bad-out").string());
  EXPECT_EQ(b.code, 2);
  EXPECT_NE(b.out.find("materials.m.measured:"), std::string::npos) << b.out;
  EXPECT_NE(b.out.find("does not start with \"tensor_file\""), std::string::npos) << b.out;
  EXPECT_FALSE(fs::exists(d / "bad-out"));
}

// Each malformed scene: exit 2, a message naming the file and the key path
// (or line), and no output folder: nothing started.
// A renderer's table set in a scene: its files, a figure per table and
// channel, and the result's error.
TEST(Run, APresetTaskWritesTheRenderersFilesAndAFigurePerTable) {
  const fs::path d = FreshDir("albedo-preset");
  const json scene = {
      {"tasks",
       {{{"name", "dfg"}, {"type", "albedo"}, {"preset", "filament"}, {"size", 8}},
        {{"name", "cycles"}, {"type", "albedo"}, {"preset", "cycles"}, {"tables", {"table_ggx_Eavg", "table_ggx_E"}},
         {"formats", {"header", "csv"}}},
        {{"name", "kc"}, {"type", "albedo"}, {"preset", "kulla_conty"}, {"size", 3}, {"tables", {"kc_Favg", "kc_x"}},
         {"formats", {"header"}}}}}};
  WriteText(d / "scene.json", scene.dump(2));
  const CliRun r = Brdfkit("run " + (d / "scene.json").string() + " --out " + (d / "out").string() + " --quiet");
  ASSERT_EQ(r.code, 0) << r.out;
  for (const char* f : {"dfg/dfg.h", "dfg/dfg.inc", "dfg/tables.csv", "dfg/tables.exr", "dfg/DFG_LUT_R.svg",
                        "dfg/DFG_LUT_G.svg", "dfg/DFG_LUT_B.svg", "cycles/shader_tables.h", "cycles/tables.csv",
                        "cycles/table_ggx_E.svg", "cycles/table_ggx_Eavg.svg", "kc/kulla_conty.h", "kc/kc_x.svg",
                        "kc/kc_Favg.svg"})
    EXPECT_TRUE(fs::exists(d / "out" / f)) << f;
  EXPECT_FALSE(fs::exists(d / "out" / "cycles" / "tables.exr")) << "not asked for";
  const json results = json::parse(ReadText(d / "out" / "results.json"));
  ASSERT_EQ(results.at("tasks").size(), 3u);
  for (const json& t : results.at("tasks")) {
    const json& res = t.at("result");
    EXPECT_LE(res.at("max_error").get<double>(), 1e-7) << t.dump();
    EXPECT_EQ(res.at("preset"), t.at("name") == "dfg" ? "filament" : t.at("name") == "kc" ? "kulla_conty" : "cycles");
  }
  EXPECT_NE(ReadText(d / "out" / "kc" / "kulla_conty.h").find("static const float kc_x[9]"), std::string::npos);
  // The header holds the tables in Cycles' order, whatever the scene's order.
  const std::string h = ReadText(d / "out" / "cycles" / "shader_tables.h");
  EXPECT_LT(h.find("table_ggx_E[1024]"), h.find("table_ggx_Eavg[32]"));
}

// An albedo task tabulates a material of the scene as it is, over mu alone
// (a measured lambert table read back through UTIA: E is its albedo at the
// tables' 1e-6; an analytic material: the same entries as its model and
// parameters given in the task), or a fitted one over its fit's parameters
// (the plan runs the fit first; the table holds the fitted values of the
// others).
TEST(Run, AlbedoTasksTabulateTheScenesMaterials) {
  const fs::path d = FreshDir("albedo-materials");
  ASSERT_EQ(Brdfkit("convert -m lambert -p albedo=0.4 --no-sidecar " + (d / "l.utia").string()).code, 0);
  json s = SmallScene({"e_lam", "e_plastic", "e_model", "e_fitted"});
  s["materials"]["lam"] = {{"measured", "l.utia"}};
  s["tasks"].push_back({{"name", "e_lam"}, {"type", "albedo"}, {"material", "lam"}, {"axes", "mu:5"},
                        {"formats", {"csv", "header"}}});
  s["tasks"].push_back({{"name", "e_plastic"}, {"type", "albedo"}, {"material", "plastic"}, {"formats", {"csv"}}});
  s["tasks"].push_back({{"name", "e_model"}, {"type", "albedo"}, {"model", "lambert+ggx"},
                        {"params", s["materials"]["plastic"]["params"]}, {"axes", "mu:32"}, {"formats", {"csv"}}});
  s["tasks"].push_back({{"name", "e_fitted"}, {"type", "albedo"}, {"material", "fitted"},
                        {"axes", "mu:4,ggx.alpha:2:0.1:0.3"}, {"formats", {"csv"}}});
  WriteText(d / "scene.json", s.dump(2));
  const CliRun r = Brdfkit("run " + (d / "scene.json").string() + " --out " + (d / "out").string() + " --quiet");
  ASSERT_EQ(r.code, 0) << r.out;
  const json results = json::parse(ReadText(d / "out" / "results.json"));
  std::map<std::string, json> by_name;
  for (const json& t : results.at("tasks")) by_name[t.at("name").get<std::string>()] = t;
  ASSERT_EQ(by_name.count("fit_a"), 1u) << "the fitted material's fit runs first";
  const json& lam = by_name.at("e_lam").at("result");
  EXPECT_EQ(lam.at("material"), "lam");
  EXPECT_EQ(lam.at("model"), "utia");
  EXPECT_TRUE(lam.at("axes").empty());
  EXPECT_NEAR(lam.at("E_avg")[0].get<double>(), 0.4, 1e-6);
  EXPECT_LE(lam.at("max_error").get<double>(), 1e-6);
  EXPECT_NE(ReadText(d / "out" / "e_lam" / "albedo.h").find("lam_albedo"), std::string::npos);
  EXPECT_TRUE(fs::exists(d / "out" / "e_lam" / "E.svg"));
  EXPECT_FALSE(fs::exists(d / "out" / "e_lam" / "E_avg.svg"));
  EXPECT_NE(ReadText(d / "out" / "report.html").find("material 'lam' (utia): 5 entries over mu (5 nodes); largest"),
            std::string::npos);
  EXPECT_EQ(ReadText(d / "out" / "e_plastic" / "albedo.csv"), ReadText(d / "out" / "e_model" / "albedo.csv"));
  EXPECT_EQ(by_name.at("e_plastic").at("result").at("E_avg"), by_name.at("e_model").at("result").at("E_avg"));
  const json& fitted = by_name.at("e_fitted").at("result");
  EXPECT_EQ(fitted.at("axes")[0].at("name"), "ggx.alpha");
  EXPECT_EQ(fitted.at("E_avg").size(), 2u);
  // The parameters held fixed are the fit's: lambert's albedo of red 0.1.
  const std::string fixed = fitted.at("params").get<std::string>();
  const std::size_t at = fixed.find("lambert.albedo=");
  ASSERT_NE(at, std::string::npos) << fixed;
  EXPECT_NEAR(std::stod(fixed.substr(at + 15)), 0.1, 0.01) << fixed;
}

TEST(Run, MalformedScenesAreRejectedBeforeAnyWork) {
  const fs::path d = FreshDir("malformed");
  struct Case {
    std::string name, text, expect;
  };
  json unknown_key = SmallScene();
  unknown_key["tasks"][3]["metirc"] = "l2";
  json wrong_type = SmallScene();
  wrong_type["tasks"][0]["axes"] = 32;
  json missing_file = SmallScene();
  missing_file["materials"]["measured"] = {{"merl", "no-such-file.binary"}};
  json check_table = SmallScene();
  WriteText(d / "t.csv", "theta_i,phi_i,theta_o,phi_o,f\n0,0,0,0,0.3\n");
  check_table["materials"]["tab"] = {{"table", "t.csv"}};
  check_table["tasks"][5]["materials"] = json::array({"tab"});
  json bad_axis = SmallScene();
  bad_axis["tasks"][0]["axes"] = "mu:8,sigma:4";
  json bad_data = SmallScene();
  bad_data["tasks"][3]["data"] = "ggx_table";
  json bad_param = SmallScene();
  bad_param["materials"]["plastic"]["params"]["ggx.alpha"] = -0.1;
  json typo_model = SmallScene();
  typo_model["tasks"][4]["model"] = "lambert+bekmann";
  json cycle = SmallScene();
  cycle["tasks"][2]["material"] = "fitted";
  json unknown_output = SmallScene({"nothing_like_this"});
  json preset_and_model = SmallScene();
  preset_and_model["tasks"][0]["preset"] = "cycles";
  json bad_table = SmallScene();
  bad_table["tasks"][0] = {{"name", "t"}, {"type", "albedo"}, {"preset", "cycles"}, {"tables", {"table_ggx_F"}}};
  json fixed_size = SmallScene();
  fixed_size["tasks"][0] = {{"name", "t"}, {"type", "albedo"}, {"preset", "cycles"}, {"size", 8}};
  json small_budget = SmallScene();
  small_budget["tasks"][5]["albedo_budget"] = 10;
  json bad_preset = SmallScene();
  bad_preset["tasks"][0] = {{"name", "t"}, {"type", "albedo"}, {"preset", "unreal"}};
  json model_and_material = SmallScene();
  model_and_material["tasks"][0]["material"] = "plastic";
  json table_albedo = check_table;
  table_albedo["tasks"][0] = {{"name", "t"}, {"type", "albedo"}, {"material", "tab"}};
  json material_params = SmallScene();
  material_params["tasks"][0] = {{"name", "t"}, {"type", "albedo"}, {"material", "plastic"}, {"params", {{"ggx.alpha", 0.1}}}};
  json material_axis = SmallScene();
  material_axis["tasks"][0] = {{"name", "t"}, {"type", "albedo"}, {"material", "phong"}, {"axes", "mu:8,alpha:4"}};
  json fitted_axis = SmallScene();
  fitted_axis["tasks"][0] = {{"name", "t"}, {"type", "albedo"}, {"material", "fitted"}, {"axes", "mu:8,beckmann.alpha:4"}};
  json measured_axis = check_table;
  measured_axis["materials"]["tab"] = {{"measured", "l.utia"}};
  measured_axis["tasks"][0] = {{"name", "t"}, {"type", "albedo"}, {"material", "tab"}, {"axes", "mu:8,albedo:2"}};
  json no_model = SmallScene();
  no_model["tasks"][0] = {{"name", "t"}, {"type", "albedo"}, {"axes", "mu:8"}};
  ASSERT_EQ(Brdfkit("convert -m lambert --no-sidecar " + (d / "l.utia").string()).code, 0);
  const std::vector<Case> cases = {
      {"bad_json", "{\n  \"tasks\": [\n    {\"name\": \"a\",, }\n  ]\n}\n", "line 3"},
      {"overflow", "{\"tasks\": [{\"name\": \"a\", \"type\": \"check\", \"samples\": 1E60799}]}", "number overflow"},
      {"unknown_key", unknown_key.dump(2), "tasks[3].metirc: unknown key"},
      {"wrong_type", wrong_type.dump(2), "tasks[0].axes: expected a string"},
      {"missing_file", missing_file.dump(2), "materials.measured.merl: file"},
      {"check_table", check_table.dump(2), "tasks[5].materials[0]"},
      {"bad_axis", bad_axis.dump(2), "tasks[0].axes: axis 'sigma' is not a parameter"},
      {"bad_data", bad_data.dump(2), "tasks[3].data"},
      {"bad_param", bad_param.dump(2), "materials.plastic.params"},
      {"typo_model", typo_model.dump(2), "tasks[4].model"},
      {"cycle", cycle.dump(2), "circular dependency"},
      {"unknown_output", unknown_output.dump(2), "outputs[0]: no task named 'nothing_like_this'"},
      {"preset_and_model", preset_and_model.dump(2), "tasks[0].model: a preset has its own models and axes"},
      {"bad_table", bad_table.dump(2), "tasks[0].tables[0]: preset 'cycles' has no table 'table_ggx_F'"},
      {"bad_preset", bad_preset.dump(2), "tasks[0].preset: unknown table preset 'unreal'"},
      {"fixed_size", fixed_size.dump(2), "tasks[0].size: preset 'cycles' has Cycles' fixed sizes"},
      {"small_budget", small_budget.dump(2), "tasks[5].albedo_budget"},
      {"model_and_material", model_and_material.dump(2), "tasks[0].material: give \"model\" or \"material\", not both"},
      {"table_albedo", table_albedo.dump(2), "tasks[0].material: 'tab' is a data table, which has no BRDF to tabulate"},
      {"material_params", material_params.dump(2), "tasks[0].params: a material has its own parameters"},
      {"material_axis", material_axis.dump(2), "tasks[0].axes: axis 'alpha' is not a parameter of model 'phong_original'"},
      {"fitted_axis", fitted_axis.dump(2), "tasks[0].axes: axis 'beckmann.alpha' is not a parameter of model 'lambert+ggx'"},
      {"measured_axis", measured_axis.dump(2), "tasks[0].axes: 'tab' is measured data, which has no parameters"},
      {"no_model", no_model.dump(2), "tasks[0].model: missing: give \"model\" (and \"params\"), \"material\" or \"preset\""},
  };
  for (const Case& c : cases) {
    const fs::path scene = d / (c.name + ".json");
    WriteText(scene, c.text);
    const CliRun r = Brdfkit("run " + scene.string() + " --out " + (d / ("out-" + c.name)).string());
    EXPECT_EQ(r.code, 2) << c.name << ": " << r.out;
    EXPECT_NE(r.out.find(scene.string()), std::string::npos) << c.name << " names the file: " << r.out;
    EXPECT_NE(r.out.find(c.expect), std::string::npos) << c.name << ": expected '" << c.expect << "' in " << r.out;
    EXPECT_FALSE(fs::exists(d / ("out-" + c.name))) << c.name << ": work started";
  }
  const CliRun missing = Brdfkit("run " + (d / "absent.json").string());
  EXPECT_EQ(missing.code, 2);
  EXPECT_NE(missing.out.find("absent.json: scene file not found"), std::string::npos) << missing.out;
}

TEST(Run, ShippedExamplesParseAndTheDefaultIsTheBuiltInScene) {
  for (const auto& e : fs::directory_iterator(fs::path(BRDFKIT_SOURCE_DIR) / "examples")) {
    if (e.path().extension() != ".json" || e.path().filename() == "scene.schema.json") continue;
    const CliRun r = Brdfkit("run " + e.path().string() + " --dry-run --out /nonexistent-dir-brdfkit");
    EXPECT_EQ(r.code, 0) << e.path() << ": " << r.out;
  }
  const CliRun builtin = Brdfkit("run --dry-run --json --out /nonexistent-dir-brdfkit");
  const CliRun file = Brdfkit("run " + std::string(BRDFKIT_SOURCE_DIR) + "/examples/default.json --dry-run --json --out /nonexistent-dir-brdfkit");
  ASSERT_EQ(builtin.code, 0) << builtin.out;
  ASSERT_EQ(file.code, 0) << file.out;
  const json a = json::parse(builtin.out).at("plan"), b = json::parse(file.out).at("plan");
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t k = 0; k < a.size(); ++k) {
    EXPECT_EQ(a[k].at("task"), b[k].at("task"));
    EXPECT_EQ(a[k].at("key"), b[k].at("key")) << "same inputs, same cache key";
  }
}

// Headless Chromium loads report.html from disk (no network) and the page's
// own script counts the figures that decoded with a size.
TEST(Run, EveryFigureOfTheReportRendersInAHeadlessBrowser) {
  const char* browser = nullptr;
  for (const char* b : {"/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome"})
    if (fs::exists(b)) browser = b;
  ASSERT_NE(browser, nullptr) << "Chromium is needed for this test (bash .ci/setup installs it)";
  const fs::path d = FreshDir("report");
  json s = SmallScene();
  s["tasks"].push_back({{"name", "integrators"}, {"type", "convergence"}, {"quick", true}});
  WriteText(d / "scene.json", s.dump());
  const CliRun r = Brdfkit("run " + (d / "scene.json").string() + " --out " + (d / "out").string() + " --quiet");
  ASSERT_EQ(r.code, 0) << r.out;
  const std::string html = ReadText(d / "out" / "report.html");
  std::size_t figures = 0;
  for (std::size_t p = html.find("<img class=\"plot\""); p != std::string::npos; p = html.find("<img class=\"plot\"", p + 1))
    ++figures;
  EXPECT_GE(figures, 9u) << "2 albedo tables x 2, synth slices, 2 fits x 4 (some), convergence";
  EXPECT_EQ(html.find("http://"), std::string::npos) << "self-contained: no links to the network";
  EXPECT_EQ(html.find("https://"), std::string::npos);
  const std::string cmd = std::string(browser) +
                          " --headless --no-sandbox --disable-gpu --disable-quic --no-first-run "
                          "--disable-background-networking --disable-component-update --disable-sync "
                          "--user-data-dir=" + (d / "profile").string() +
                          " --virtual-time-budget=10000 --dump-dom file://" + (d / "out" / "report.html").string();
  const std::string dom = brdfkit::test::Shell("(" + cmd + ") 2>/dev/null").out;  // the page only, not Chromium's log
  const std::string want = "data-figures-rendered=\"" + std::to_string(figures) + "/" + std::to_string(figures) + "\"";
  EXPECT_NE(dom.find(want), std::string::npos) << "expected " << want << " in the rendered page; body starts: "
                                               << dom.substr(dom.find("<body"), 200);
}

// Ctrl-C during a long task: exit 130, nothing half-written, finished tasks
// kept, and the next run resumes from them.
TEST(Run, InterruptStopsCleanly) {
  const fs::path d = FreshDir("interrupt");
  json s = SmallScene({"ggx_table", "integrators"});
  s["tasks"].push_back({{"name", "integrators"}, {"type", "convergence"}, {"quick", false}});
  WriteText(d / "scene.json", s.dump());
  const fs::path out = d / "out";
  const pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    const std::string scene = (d / "scene.json").string(), o = out.string();
    if (!freopen("/dev/null", "w", stderr)) _exit(126);
    execl(BRDFKIT_EXE, BRDFKIT_EXE, "run", scene.c_str(), "--out", o.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  // Wait until the albedo table is done and the convergence study has started.
  const auto t0 = std::chrono::steady_clock::now();
  while (!fs::exists(out / ".cache" / "ggx_table.json") &&
         std::chrono::steady_clock::now() - t0 < std::chrono::seconds(60))
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  kill(pid, SIGINT);
  int status = 0;
  waitpid(pid, &status, 0);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 130);
  EXPECT_FALSE(fs::exists(out / "results.json"));
  EXPECT_FALSE(fs::exists(out / "report.html"));
  for (const auto& e : fs::recursive_directory_iterator(out))
    EXPECT_EQ(e.path().filename().string().find(".tmp-"), std::string::npos) << "left behind: " << e.path();
  const auto actions = PlanActions(Brdfkit("run " + (d / "scene.json").string() + " --out " + out.string() + " --dry-run --json"));
  EXPECT_EQ(actions.at("ggx_table"), "cached");
  EXPECT_EQ(actions.at("integrators"), "run");
}

TEST(Run, NoProgressBarsWhenStderrIsNotATerminal) {
  const fs::path d = FreshDir("quiet");
  WriteText(d / "scene.json", SmallScene({"ggx_table"}).dump());
  const CliRun r = Brdfkit("run " + (d / "scene.json").string() + " --out " + (d / "out").string());
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_EQ(r.out.find('\r'), std::string::npos);
  EXPECT_EQ(r.out.find("left"), std::string::npos);
}

// Under a terminal (script(1) gives the tool a pseudo-terminal), work longer
// than a second draws a bar with the time left.
TEST(Run, ProgressBarsWithTimeLeftOnATerminal) {
  const fs::path d = FreshDir("tty");
  json s = SmallScene({"integrators"});
  s["tasks"].push_back({{"name", "integrators"}, {"type", "convergence"}, {"quick", false}});
  WriteText(d / "scene.json", s.dump());
  const std::string inner = std::string(BRDFKIT_EXE) + " run " + (d / "scene.json").string() + " --out " + (d / "out").string();
  const CliRun r = brdfkit::test::Shell("script -qfec '" + inner + "' /dev/null");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("convergence ["), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(" left"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find('\r'), std::string::npos);
}

}  // namespace
