// The command-line tool as a user runs it: output formats, exit codes and
// error messages.
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <array>
#include <cstdio>
#include <string>
#include <sys/wait.h>

#include "brdf/model.h"
#include "tests/cli_util.h"

namespace {

using brdfkit::test::Brdfkit;
using brdfkit::test::CliRun;

TEST(Cli, ModelsJsonListsEveryModelWithItsTable) {
  const CliRun r = Brdfkit("models --json");
  ASSERT_EQ(r.code, 0) << r.out;
  const auto j = nlohmann::json::parse(r.out);
  const auto infos = brdfkit::RegisteredModelInfos();
  ASSERT_EQ(j.size(), infos.size());
  for (std::size_t k = 0; k < infos.size(); ++k) {
    EXPECT_EQ(j[k]["name"], infos[k].name);
    EXPECT_EQ(j[k]["reciprocal"], infos[k].reciprocal);
    EXPECT_EQ(j[k]["energy_conserving"], infos[k].energy_conserving);
    ASSERT_EQ(j[k]["params"].size(), infos[k].params.size());
    for (std::size_t i = 0; i < infos[k].params.size(); ++i) {
      EXPECT_EQ(j[k]["params"][i]["name"], infos[k].params[i].name);
      EXPECT_EQ(j[k]["params"][i]["lower"], infos[k].params[i].lower);
      EXPECT_EQ(j[k]["params"][i]["upper"], infos[k].params[i].upper);
      EXPECT_EQ(j[k]["params"][i]["default"], infos[k].params[i].default_value);
      EXPECT_EQ(j[k]["params"][i]["colour"], infos[k].params[i].colour);
    }
  }
}

// GGX, alpha = 1, F = 1, normal incidence and exit: D = 1/pi, G2 = 1, so
// f_r = D / 4 = 1 / (4 pi).
TEST(Cli, EvalPrintsTheValueInJson) {
  const CliRun r = Brdfkit("eval --model ggx --params alpha=1 --wi 0,0,2 --wo 0,0,1 --json");
  ASSERT_EQ(r.code, 0) << r.out;
  const auto j = nlohmann::json::parse(r.out);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(j["f"][c].get<double>(), 1 / (4 * brdfkit::kPi), 1e-15);
}

TEST(Cli, EvalAcceptsDegreesAndPerChannelColours) {
  const CliRun a = Brdfkit("eval -m lambert+ggx -p lambert.albedo=0.1:0.2:0.3,ggx.alpha=0.2 --wi-deg 30,0 --wo-deg 30,180 --json");
  const CliRun b = Brdfkit("eval -m lambert+ggx -p lambert.albedo=0.1:0.2:0.3,ggx.alpha=0.2 --wi 0.5,0,0.8660254037844386 "
                        "--wo -0.5,0,0.8660254037844386 --json");
  ASSERT_EQ(a.code, 0) << a.out;
  ASSERT_EQ(b.code, 0) << b.out;
  const auto ja = nlohmann::json::parse(a.out), jb = nlohmann::json::parse(b.out);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(ja["f"][c].get<double>(), jb["f"][c].get<double>(), 1e-12);
  // The mirror configuration: the specular lobe is the same in every channel, the diffuse part differs by 0.1/pi.
  EXPECT_NEAR(ja["f"][1].get<double>() - ja["f"][0].get<double>(), 0.1 / brdfkit::kPi, 1e-12);
}

TEST(Cli, BadInputIsNamedAndExitsNonZero) {
  struct Case {
    std::string args, must_contain;
  };
  const std::vector<Case> cases = {
      {"eval -m ggxx --wi 0,0,1 --wo 0,0,1", "unknown model 'ggxx'"},
      {"eval -m lambert+ggxx --wi 0,0,1 --wo 0,0,1", "unknown model 'ggxx'"},
      {"eval -m ggx -p alpha=-0.2 --wi 0,0,1 --wo 0,0,1", "'alpha' = -0.2 is outside its range"},
      {"eval -m ggx -p alpha=0 --wi 0,0,1 --wo 0,0,1", "'alpha'"},
      {"eval -m ggx -p alpha=abc --wi 0,0,1 --wo 0,0,1", "'abc' is not a number"},
      {"eval -m ggx -p roughness=0.1 --wi 0,0,1 --wo 0,0,1", "unknown parameter 'roughness'"},
      {"eval -m ggx --wi 0,0 --wo 0,0,1", "--wi"},
      {"eval -m ggx --wi 0,0,x --wo 0,0,1", "'x' is not a finite number"},
      {"eval -m ggx --wi 0,0,0 --wo 0,0,1", "zero length"},
      {"eval -m ggx --wi 0,0,1", "--wo"},
      {"frobnicate", "frobnicate"},
  };
  for (const Case& c : cases) {
    const CliRun r = Brdfkit(c.args);
    EXPECT_NE(r.code, 0) << c.args;
    EXPECT_NE(r.out.find(c.must_contain), std::string::npos) << c.args << "\n" << r.out;
  }
}

TEST(Cli, EveryCommandHasHelp) {
  const CliRun top = Brdfkit("--help");
  ASSERT_EQ(top.code, 0);
  for (const std::string cmd : {"models", "eval", "run"}) {
    EXPECT_NE(top.out.find(cmd), std::string::npos) << cmd;
    const CliRun r = Brdfkit(cmd + " --help");
    EXPECT_EQ(r.code, 0) << cmd;
    EXPECT_NE(r.out.find("Usage"), std::string::npos) << r.out;
  }
}

}  // namespace
