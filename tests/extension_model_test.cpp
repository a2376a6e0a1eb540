// The test-only model test_glossy (tests/test_glossy_model.h), registered
// with one line outside brdf/registry.h, gets every tool: it is listed,
// checked, tabulated, synthesised, fitted back and stress-tested (the
// property suite, tests/model_properties_test.cpp, covers it through the
// registry like every other model).
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <string>

#include "brdf/model.h"
#include "brdf/params.h"
#include "tests/cli_util.h"
#include "validate/integrators.h"
#include "validate/stress.h"

namespace brdfkit {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using test::CliRun;

CliRun Extended(const std::string& args) { return test::Shell(std::string(BRDFKIT_EXTENDED_EXE) + " " + args); }

TEST(ExtensionModel, IsRegisteredAndListed) {
  bool found = false;
  for (const ModelInfo& i : RegisteredModelInfos()) found = found || i.name == "test_glossy";
  EXPECT_TRUE(found);
  const CliRun r = Extended("models --json");
  ASSERT_EQ(r.code, 0) << r.out;
  bool listed = false;
  for (const json& m : json::parse(r.out)) listed = listed || m.at("name") == "test_glossy";
  EXPECT_TRUE(listed) << r.out;
  // The tool itself is built without it.
  EXPECT_EQ(test::Brdfkit("models").out.find("test_glossy"), std::string::npos);
}

TEST(ExtensionModel, PassesCheck) {
  const CliRun r = Extended("check -m test_glossy --samples 20000");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("verdict: plausible"), std::string::npos) << r.out;
}

// The albedo table's half-vector cubature against the adaptive hemisphere
// rule of validate/integrators.h at the same node.
TEST(ExtensionModel, GetsAnAlbedoTable) {
  const fs::path d = test::FreshDir("ext-albedo");
  const CliRun r = Extended("albedo -m test_glossy --axes mu:3,n:2:10:100 --csv " + (d / "t.csv").string());
  ASSERT_EQ(r.code, 0) << r.out;
  const std::string csv = test::ReadText(d / "t.csv");
  ASSERT_FALSE(csv.empty());
  const Model m = Model::Parse("test_glossy");
  const auto b = m.Make<double>();
  // E at mu = 1, n = 100 (the table's last row of the first mu block is
  // read back through the same CSV the tool wrote).
  std::vector<double> p = ParseParams(m.Info(), "n=100");
  validate::IntegrateOptions o;
  o.budget = 400000;
  o.abs_tolerance = 1e-9;
  const double e = validate::DirectionalAlbedo(*b, p.data(), Eigen::Vector3d(0, 0, 1), validate::Method::kAdaptive, o)
                       .value[0];
  bool seen = false;
  std::stringstream ss(csv);
  std::string line;
  while (std::getline(ss, line)) {
    std::vector<double> v;
    std::stringstream ls(line);
    std::string cell;
    while (std::getline(ls, cell, ',')) {
      double x;
      if (ParseDouble(cell, x)) v.push_back(x);
    }
    if (v.size() >= 3 && v[0] == 1.0 && v[1] == 100.0) {
      EXPECT_NEAR(v[2], e, 2e-6) << line;
      seen = true;
    }
  }
  EXPECT_TRUE(seen) << csv;
}

TEST(ExtensionModel, IsSynthesisedAndFittedBack) {
  const fs::path d = test::FreshDir("ext-fit");
  test::WriteText(d / "inst.json", R"({"source": {"type": "collimated", "irradiance": 10},
    "detector": {"angular_radius_deg": 0, "responsivity": 1e18, "exposure_time": 0.001},
    "sample": {"area": 1e-4, "tilt_x_deg": 0, "tilt_y_deg": 0},
    "plan": {"type": "in_plane", "theta_i_deg": {"start": 0, "stop": 60, "count": 4},
             "theta_o_deg": {"start": -80, "stop": 80, "count": 41}}})");
  const CliRun s = Extended("synth -m test_glossy -p kd=0.1:0.2:0.3,ks=0.5:0.4:0.3,n=60 -i " +
                            (d / "inst.json").string() + " -o " + (d / "m.csv").string() + " -q");
  ASSERT_EQ(s.code, 0) << s.out;
  const CliRun f = Extended("fit -d " + (d / "m.csv").string() + " -m test_glossy --starts 3 --json");
  ASSERT_EQ(f.code, 0) << f.out;
  const json j = json::parse(f.out.substr(f.out.find('{')));
  // Point apertures, no noise: the data is the model itself.
  EXPECT_NEAR(j.at("params").at("n").get<double>(), 60.0, 1e-5);
  EXPECT_NEAR(j.at("params").at("kd")[2].get<double>(), 0.3, 1e-7);
  EXPECT_NEAR(j.at("params").at("ks")[0].get<double>(), 0.5, 1e-7);
}

TEST(ExtensionModel, PassesTheStressSweep) {
  validate::StressOptions o;
  o.models = {"test_glossy"};
  const std::vector<validate::StressRow> rows = validate::RunStress(o);
  ASSERT_EQ(rows.size(), 3u);  // float, double, jet
  for (const validate::StressRow& r : rows) {
    SCOPED_TRACE(r.type);
    EXPECT_FALSE(r.skipped);
    EXPECT_GT(r.evaluations, 0);
    EXPECT_EQ(r.nonfinite_count, 0) << r.first_failure;
    EXPECT_EQ(r.negative_count, 0);
    EXPECT_EQ(r.horizon_nonzero_count, 0);
    EXPECT_EQ(r.nonfinite_derivative_count, 0);
    EXPECT_EQ(r.sample_failures, 0);
    EXPECT_EQ(r.bound_failures, 0);
  }
}

}  // namespace
}  // namespace brdfkit
