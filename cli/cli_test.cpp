// The command-line tool as a user runs it: output formats, exit codes and
// error messages.
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <array>
#include <cstdio>
#include <string>
#include <sys/wait.h>

#include "brdf/model.h"
#include "brdf/params.h"
#include "tests/cli_util.h"

namespace {

namespace fs = std::filesystem;
using brdfkit::test::Brdfkit;
using brdfkit::test::CliRun;
using brdfkit::test::FreshDir;
using brdfkit::test::ReadText;
using brdfkit::test::Shell;
using brdfkit::test::WriteText;

// A program that includes an albedo header (`prog`, written as
// <stem>_main.c and <stem>_main.cpp), built by each compiler with -Wall
// -Wextra -Werror -pedantic and run: it must exit 0 (its own checks) and
// print one value per line of `expected` (the CSV's E column), to 1e-7
// relative. Returns the number of values compared.
std::size_t ExpectHeaderProgramPrints(const std::string& stem, const std::string& prog, const std::string& expected,
                                      const std::vector<std::string>& compilers, const std::string& what) {
  WriteText(stem + "_main.c", prog);
  WriteText(stem + "_main.cpp", prog);
  std::size_t count = 0;
  for (const std::string& compiler : compilers) {
    const bool cpp = compiler.find("++") != std::string::npos;
    const std::string exe = stem + "_prog";
    const CliRun c = Shell(compiler + " -Wall -Wextra -Werror -pedantic " + stem + (cpp ? "_main.cpp" : "_main.c") +
                           " -o " + exe + " -lm");
    EXPECT_EQ(c.code, 0) << compiler << " on " << what << ":\n" << c.out;
    if (c.code != 0) return count;
    const CliRun out = Shell(exe);
    EXPECT_EQ(out.code, 0) << compiler << " on " << what << ": checks that failed\n" << out.out;
    std::istringstream got(out.out), want(expected);
    std::string g, w;
    count = 0;
    while (std::getline(want, w)) {
      if (!std::getline(got, g)) {
        ADD_FAILURE() << compiler << " on " << what << ": fewer values than the CSV";
        return count;
      }
      const double gv = std::stod(g), wv = std::stod(w);
      EXPECT_NEAR(gv, wv, 1e-7 * std::max(1.0, std::abs(wv))) << compiler << " on " << what << ", value " << count;
      ++count;
    }
    EXPECT_FALSE(std::getline(got, g)) << compiler << " on " << what << ": more values than the CSV";
  }
  return count;
}

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
      {"eval -m ggx -p roughness=0.1 --wi 0,0,1 --wo 0,0,1", "did you mean alpha?"},
      {"eval -m ggx_aniso -p roughness=0.1 --wi 0,0,1 --wo 0,0,1", "did you mean alpha_x or alpha_y?"},
      {"eval -m ggx -p alpah=0.1 --wi 0,0,1 --wo 0,0,1", "did you mean alpha?"},
      {"eval -m lambert+ggx -p albedo=0.1 --wi 0,0,1 --wo 0,0,1", "did you mean lambert.albedo?"},
      {"eval -m gxx --wi 0,0,1 --wo 0,0,1", "did you mean ggx?"},
      {"eval -m cook-torrance --wi 0,0,1 --wo 0,0,1", "did you mean cook_torrance?"},
      {"stress -m lamberr", "did you mean lambert?"},
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

// --part picks what a transmitting model's entries hold, and the table says
// which; its "params" lists the parameters held fixed, not the axes'.
TEST(Cli, AlbedoPartOfAGlassAndTheFixedParameters) {
  const fs::path dir = FreshDir("albedo-part");
  const CliRun r = Brdfkit("albedo -m ggx_glass -p alpha=0.3 --axes mu:3:0.5:1,eta:2:1.3:1.5 --part reflected "
                           "--tolerance 1e-5 --json --exr " + (dir / "r.exr").string());
  ASSERT_EQ(r.code, 0) << r.out;
  // The JSON line, among the summary line on stderr.
  const auto json_line = [](const std::string& out) {
    const std::size_t b = out.find('{');
    return nlohmann::json::parse(out.substr(b, out.find('\n', b) - b));
  };
  const nlohmann::json j = json_line(r.out);
  EXPECT_EQ(j["part"], "E_R");
  EXPECT_EQ(j["params"], "alpha=0.3");
  // Normal incidence on eta = 1.5: about the Fresnel reflectance 0.04.
  const std::vector<double> e = j["E"].get<std::vector<double>>();
  ASSERT_EQ(e.size(), 6u);
  EXPECT_NEAR(e[5], 0.04, 5e-3);
  EXPECT_GT(e[5], e[2]);  // more reflected at eta 1.5 than at 1.3
  const CliRun plain = Brdfkit("albedo -m ggx --axes mu:3,alpha:2:0.1:0.5 -p f0=0.5 --json");
  ASSERT_EQ(plain.code, 0) << plain.out;
  const nlohmann::json k = json_line(plain.out);
  EXPECT_EQ(k["part"], "E");
  EXPECT_EQ(k["params"], "f0=0.5:0.5:0.5");
  const CliRun bad = Brdfkit("albedo -m ggx_glass --axes mu:3,eta:2:1.3:1.5 --part both");
  EXPECT_NE(bad.code, 0);
  EXPECT_NE(bad.out.find("--part"), std::string::npos) << bad.out;
}

// Every generated C header compiles with g++ and clang, as C and as C++,
// with -Wall -Wextra -Werror -pedantic, holds only finite literals, its
// arrays read back the CSV's values (to float precision), and its lookup
// functions interpolate them.
TEST(Cli, AlbedoHeadersCompileAsCAndCppAndMatchTheCsv) {
  const fs::path dir = FreshDir("albedo-header");
  struct Case {
    std::string axes, extra;
    std::vector<std::string> arrays;  // name and the CSV file and column holding its values
  };
  // Default alpha range (down to 1e-7: accepted with a looser bound), an
  // explicit range, and an f0 axis.
  const std::vector<std::string> axes = {"mu:5,alpha:4 --accept-error 1", "mu:6,alpha:3:0.001:1", "mu:4,alpha:3:0.05:1,f0:3"};
  for (std::size_t k = 0; k < axes.size(); ++k) {
    const std::string stem = (dir / ("t" + std::to_string(k))).string();
    const CliRun r = Brdfkit("albedo -m ggx --axes " + axes[k] + " --csv " + stem + ".csv --header " + stem + ".h");
    ASSERT_EQ(r.code, 0) << axes[k] << "\n" << r.out;
    const std::string header = ReadText(stem + ".h");
    for (const char* bad : {"inf", "nan", "INF", "NAN"}) EXPECT_EQ(header.find(bad), std::string::npos) << bad;
    // A program that prints every value of E, E_avg and ms_norm, in C and C++.
    const std::string n2 = k == 2 ? "[ggx_albedo_n_f0]" : "";
    const std::string loops =
        k == 2 ? "for (i = 0; i < ggx_albedo_n_alpha; ++i) {\n    for (j = 0; j < ggx_albedo_n_f0; ++j) {\n"
                 "      for (m = 0; m < ggx_albedo_n_mu; ++m) printf(\"%.9g\\n\", (double)ggx_albedo_E[i][j][m]);\n"
                 "    }\n  }"
               : "j = 0;\n  for (i = 0; i < ggx_albedo_n_alpha; ++i) {\n"
                 "    for (m = 0; m < ggx_albedo_n_mu; ++m) printf(\"%.9g\\n\", (double)ggx_albedo_E[i][m]);\n  }";
    // The lookups: exact at every node, the mean of two neighbours halfway
    // between them (in mu, and in sqrt(alpha), the alpha nodes' spacing),
    // clamped outside the table. The exit code counts the failures.
    const std::string f0 = k == 2 ? ", ggx_albedo_f0_nodes[0]" : "";
    const std::string at = k == 2 ? "[0]" : "";
    const std::string checks =
        "  for (i = 0; i < ggx_albedo_n_alpha; ++i) {\n"
        "    for (m = 0; m < ggx_albedo_n_mu; ++m) {\n"
        "      a = ggx_albedo_alpha_nodes[i];\n"
        "      if (ggx_albedo_E_lookup(ggx_albedo_mu_nodes[m], a" + f0 + ") != ggx_albedo_E[i]" + at + "[m]) ++bad;\n"
        "      if (m + 1 < ggx_albedo_n_mu) {\n"
        "        v = ggx_albedo_E_lookup(0.5f * (ggx_albedo_mu_nodes[m] + ggx_albedo_mu_nodes[m + 1]), a" + f0 + ");\n"
        "        if (fabs(v - 0.5 * (ggx_albedo_E[i]" + at + "[m] + ggx_albedo_E[i]" + at + "[m + 1])) > 1e-6) ++bad;\n"
        "      }\n"
        "      if (i + 1 < ggx_albedo_n_alpha) {\n"
        "        a = 0.5 * (sqrt(ggx_albedo_alpha_nodes[i]) + sqrt(ggx_albedo_alpha_nodes[i + 1]));\n"
        "        v = ggx_albedo_E_lookup(ggx_albedo_mu_nodes[m], (float)(a * a)" + f0 + ");\n"
        "        if (fabs(v - 0.5 * (ggx_albedo_E[i]" + at + "[m] + ggx_albedo_E[i + 1]" + at + "[m])) > 1e-5) ++bad;\n"
        "      }\n"
        "    }\n"
        "    if (ggx_albedo_E_avg_lookup(ggx_albedo_alpha_nodes[i]" + f0 + ") != ggx_albedo_E_avg[i]" + at + ") ++bad;\n"
        "  }\n"
        "  if (ggx_albedo_E_lookup(-1.0f, 100.0f" + f0 + ") != ggx_albedo_E[ggx_albedo_n_alpha - 1]" + at + "[0]) ++bad;\n"
        "  if (ggx_albedo_E_lookup(2.0f, 0.0f" + f0 + ") != ggx_albedo_E[0]" + at + "[ggx_albedo_n_mu - 1]) ++bad;\n";
    const std::string prog = "#include <math.h>\n#include <stdio.h>\n#include \"" + stem + ".h\"\n#include \"" + stem +
                             ".h\"\nint main(void) {\n  int i, j, m, bad = 0;\n  double a, v;\n  " + loops +
                             "\n  (void)j;\n" + checks + "  return bad;\n}\n";
    std::string expected;
    {
      // The CSV lists E as mu,<p1>[,<p2>],E with mu fastest: the C array's order.
      std::istringstream in(ReadText(stem + ".csv"));
      std::string line;
      std::getline(in, line);
      while (std::getline(in, line)) expected += line.substr(line.rfind(',') + 1) + "\n";
    }
    EXPECT_GT(ExpectHeaderProgramPrints(stem, prog, expected,
                                        {"gcc -x c -std=c89", "gcc -x c -std=c11", "g++ -x c++ -std=c++11",
                                         "clang -x c -std=c99", "clang++ -x c++ -std=c++20"},
                                        axes[k]),
              10u);
  }
}

// The renderers' table sets: Cycles' arrays and Filament's DFG_LUT (as a
// header and as the .inc body Filament's DFG.cpp includes) compile as C and
// C++ with -Wall -Wextra -Werror -pedantic and hold the JSON's values.
TEST(Cli, PresetHeadersCompileAndHoldTheJsonValues) {
  const fs::path dir = FreshDir("albedo-preset");
  const std::string c = (dir / "cycles").string(), f = (dir / "dfg").string();
  const CliRun rc = Brdfkit("albedo --preset cycles --tables table_ggx_Eavg,table_ggx_gen_schlick_s --header " + c +
                            ".h --json");
  ASSERT_EQ(rc.code, 0) << rc.out;
  const auto jc = nlohmann::json::parse(rc.out.substr(0, rc.out.find('\n')));
  const CliRun rf = Brdfkit("albedo --preset filament --size 4 --header " + f + ".h --json");
  ASSERT_EQ(rf.code, 0) << rf.out;
  ASSERT_EQ(Brdfkit("albedo --preset filament --size 4 --header " + f + ".inc").code, 0);
  const auto jf = nlohmann::json::parse(rf.out.substr(0, rf.out.find('\n')));
  const std::string kc_path = (dir / "kc").string();
  const CliRun rk = Brdfkit("albedo --preset kulla_conty --size 3 --tables kc_Favg,kc_inv_Favg --header " + kc_path + ".h --json");
  ASSERT_EQ(rk.code, 0) << rk.out;
  const auto jk = nlohmann::json::parse(rk.out.substr(0, rk.out.find('\n')));
  ASSERT_EQ(jc["tables"].size(), 2u);
  const std::string prog =
      "#include <stdio.h>\n#include \"" + c + ".h\"\n#include \"" + f + ".h\"\n#include \"" + kc_path + ".h\"\n"
      "static const uint16_t inc[] = {\n#include \"" + f + ".inc\"\n};\n"
      "int main(void) {\n  unsigned i, bad = 0;\n"
      "  for (i = 0; i < 32; ++i) printf(\"%.9g\\n\", (double)table_ggx_Eavg[i]);\n"
      "  for (i = 0; i < 4096; ++i) printf(\"%.9g\\n\", (double)table_ggx_gen_schlick_s[i]);\n"
      "  if (sizeof(inc) != DFG_LUT_SIZE * DFG_LUT_SIZE * 3 * sizeof(uint16_t)) ++bad;\n"
      "  for (i = 0; i < DFG_LUT_SIZE * DFG_LUT_SIZE * 3; ++i) {\n"
      "    if (inc[i] != DFG_LUT[i]) ++bad;\n    printf(\"%u\\n\", (unsigned)DFG_LUT[i]);\n  }\n"
      "  for (i = 0; i < 3; ++i) printf(\"%.9g\\n%.9g\\n\", (double)kc_lookup(kc_Favg, 3, 1, i / 2.0f, 0, 0),\n"
      "                                (double)kc_lookup(kc_inv_Favg, 3, 1, i / 2.0f, 0, 0));\n"
      "  printf(\"%.9g\\n\", (double)kc_lookup(kc_Favg, 3, 1, 0.75f, 0, 0));\n"
      "  for (i = 0; i < 32; ++i) printf(\"%.9g\\n\", (double)cycles_table_lookup(table_ggx_Eavg, 32, 1, i / 31.0f, 0, 0));\n"
      "  printf(\"%.9g\\n\", (double)cycles_table_lookup(table_ggx_gen_schlick_s, 16, 3, 3 / 15.0f, 7 / 15.0f, 11 / 15.0f));\n"
      "  for (i = 0; i < 16; ++i) printf(\"%.9g\\n\", (double)dfg_lookup(((i % 4) + 0.5f) / 4, ((i / 4) + 0.5f) / 4, 1));\n"
      "  printf(\"%.9g\\n\", (double)dfg_lookup(0.5f, 0.5f, 0));\n"
      "  return (int)bad;\n}\n";
  WriteText(dir / "main.c", prog);
  WriteText(dir / "main.cpp", prog);
  std::vector<double> want;
  for (const auto& t : jc["tables"])
    for (const auto& v : t["value"]) want.push_back(v.get<double>());
  const std::size_t n_float = want.size();
  for (const auto& v : jf["tables"][0]["value"]) want.push_back(v.get<double>());
  ASSERT_EQ(n_float, 32u + 4096u);
  ASSERT_EQ(want.size(), n_float + 48u);
  // The lookups at the nodes of kc_Favg and kc_inv_Favg, then half way between nodes 1 and 2.
  std::vector<double> lookups;
  for (std::size_t i = 0; i < 3; ++i)
    for (std::size_t t = 0; t < 2; ++t) lookups.push_back(jk["tables"][t]["value"][i].get<double>());
  lookups.push_back(0.5 * (lookups[2] + lookups[4]));
  // Cycles' lookups at the nodes of table_ggx_Eavg and at node (3, 7, 11) of gen_schlick_s; Filament's
  // G at the 16 texel centres, then R at the centre of the texture (the mean of the four middle texels).
  for (std::size_t i = 0; i < 32; ++i) lookups.push_back(jc["tables"][0]["value"][i].get<double>());
  lookups.push_back(jc["tables"][1]["value"][(11 * 16 + 7) * 16 + 3].get<double>());
  const auto& dfg = jf["tables"][0]["value"];
  for (std::size_t i = 0; i < 16; ++i) lookups.push_back(dfg[3 * i + 1].get<double>());
  lookups.push_back(0.25 * (dfg[3 * 5].get<double>() + dfg[3 * 6].get<double>() + dfg[3 * 9].get<double>() +
                            dfg[3 * 10].get<double>()));
  for (const std::string compiler : {"gcc -x c -std=c99", "g++ -x c++ -std=c++11", "clang -x c -std=c11",
                                     "clang++ -x c++ -std=c++20"}) {
    const bool cpp = compiler.find("++") != std::string::npos;
    const std::string exe = (dir / "prog").string();
    const CliRun cc = Shell(compiler + " -Wall -Wextra -Werror -pedantic " + (dir / (cpp ? "main.cpp" : "main.c")).string() +
                            " -o " + exe);
    ASSERT_EQ(cc.code, 0) << compiler << ":\n" << cc.out;
    const CliRun out = Shell(exe);
    ASSERT_EQ(out.code, 0) << compiler << ": the .inc body differs from the header's DFG_LUT";
    std::istringstream got(out.out);
    std::string line;
    for (std::size_t k = 0; k < want.size(); ++k) {
      ASSERT_TRUE(std::getline(got, line)) << "fewer values than the JSON";
      if (k < n_float) {
        EXPECT_NEAR(std::stod(line), want[k], 1e-7 * std::max(1.0, std::abs(want[k]))) << compiler << " " << k;
      } else {
        // IEEE half: sign, 5 exponent bits, 10 mantissa bits.
        const unsigned h = std::stoul(line), e = (h >> 10) & 31u, m = h & 1023u;
        const double v = (h & 0x8000u ? -1 : 1) * (e ? std::ldexp(1024.0 + m, int(e) - 25) : std::ldexp(double(m), -24));
        EXPECT_NEAR(v, want[k], std::ldexp(std::abs(want[k]), -11) + std::ldexp(1.0, -25)) << compiler << " half " << k;
      }
    }
    for (std::size_t k = 0; k < lookups.size(); ++k) {
      ASSERT_TRUE(std::getline(got, line)) << "fewer lookups than asked for";
      // Filament's entries are halves (relative 2^-11).
      const double tol = k + 17 >= lookups.size() ? std::ldexp(std::abs(lookups[k]), -10) : 1e-6;
      EXPECT_NEAR(std::stod(line), lookups[k], tol) << compiler << " lookup " << k;
    }
  }
  // A preset takes no model or axes; the sizes are checked.
  const CliRun both = Brdfkit("albedo --preset cycles --model ggx");
  EXPECT_EQ(both.code, 2) << both.out;
  EXPECT_NE(both.out.find("--preset excludes --model"), std::string::npos) << both.out;
  for (const auto& [args, says] : std::vector<std::pair<std::string, std::string>>{
           {"--preset filament --size 1", "--size"},
           {"--preset cycles --size 8", "preset 'cycles' has Cycles' fixed sizes"},
           {"--preset kulla_conty --size 2", "preset 'kulla_conty': size 2 is outside [3, 256]"},
           {"--preset cycles --tables table_ggx_F", "table_ggx_F"}}) {
    const CliRun bad = Brdfkit("albedo " + args);
    EXPECT_NE(bad.code, 0) << args << ": " << bad.out;
    EXPECT_NE(bad.out.find(says), std::string::npos) << args << ": " << bad.out;
  }
}

// A table that misses its 1e-6 contract (alpha down to 1e-7 at grazing) is
// not written: the entries are named, the exit code is 1. An explicit
// --accept-error writes it.
TEST(Cli, AlbedoTableAboveItsToleranceIsRefused) {
  const fs::path dir = FreshDir("albedo-contract");
  const std::string csv = (dir / "t.csv").string();
  const CliRun r = Brdfkit("albedo -m ggx --axes mu:5,alpha:4 --csv " + csv);
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_NE(r.out.find("miss the error tolerance 1e-06"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("alpha = 1e-07"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("--accept-error"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(csv));
  const CliRun ok = Brdfkit("albedo -m ggx --axes mu:5,alpha:4 --accept-error 1 --csv " + csv);
  EXPECT_EQ(ok.code, 0) << ok.out;
  EXPECT_TRUE(fs::exists(csv));
  // Within the contract: no option needed.
  EXPECT_EQ(Brdfkit("albedo -m ggx --axes mu:5,alpha:4:0.001:1 --csv " + csv).code, 0);
}

// Data measured through the default instrument's 1 degree detector, fitted
// without it: the fit warns and names the option; through the sidecar's
// instrument it recovers the truth.
TEST(Cli, PlainFitOfApertureDataWarnsAndNamesTheInstrument) {
  const fs::path dir = FreshDir("fit-apertures");
  const std::string data = (dir / "data.csv").string();
  CliRun r = Brdfkit("synth -m lambert+ggx -p lambert.albedo=0.2,ggx.alpha=0.1 --out " + data);
  ASSERT_EQ(r.code, 0) << r.out;
  r = Brdfkit("fit --data " + data + " -m lambert+ggx --no-covariance --json");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("finite apertures"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("--instrument " + data + ".json"), std::string::npos) << r.out;
  r = Brdfkit("fit --data " + data + " -m lambert+ggx --no-covariance --json --instrument " + data + ".json",
              "");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_EQ(r.out.find("finite apertures"), std::string::npos) << r.out;
  const auto j = nlohmann::json::parse(r.out.substr(r.out.find('{')));
  EXPECT_TRUE(j["warnings"].empty());
  EXPECT_NEAR(j["params"]["ggx.alpha"].get<double>(), 0.1, 2e-3);
  EXPECT_NEAR(j["params"]["lambert.albedo"][0].get<double>(), 0.2, 0.01);
  // The built-in instrument is noiseless: no sigma, so no chi-square; the
  // aperture-aware fit reproduces the data.
  EXPECT_TRUE(j["chi2_reduced"].is_null());
  EXPECT_LT(j["relative_error"]["max"].get<double>(), 1e-6);
}

// --threads means the same in every command: 0 is every core, a count
// beyond the cores is capped with a note (the result unchanged), a negative
// one is refused with the option named.
TEST(Cli, ThreadCountsAreCappedWithANote) {
  const fs::path dir = FreshDir("threads");
  const std::string data = (dir / "data.csv").string();
  ASSERT_EQ(Brdfkit("synth -m lambert+ggx -p lambert.albedo=0.2,ggx.alpha=0.2 --out " + data).code, 0);
  const std::string fit = "fit --data " + data + " -m lambert+ggx --no-covariance --json --threads ";
  const CliRun one = Brdfkit(fit + "1");
  const CliRun many = Brdfkit(fit + "100000");
  ASSERT_EQ(one.code, 0) << one.out;
  ASSERT_EQ(many.code, 0) << many.out;
  EXPECT_NE(many.out.find("--threads 100000: this machine offers"), std::string::npos) << many.out;
  const auto a = nlohmann::json::parse(one.out.substr(one.out.find('{')));
  const auto b = nlohmann::json::parse(many.out.substr(many.out.find('{')));
  EXPECT_NEAR(a["params"]["ggx.alpha"].get<double>(), 0.2, 5e-3);  // a plain fit of aperture data
  EXPECT_NEAR(b["params"]["ggx.alpha"].get<double>(), a["params"]["ggx.alpha"].get<double>(), 1e-9);
  const std::string albedo = "albedo -m ggx --axes mu:4,alpha:3:0.2:1 --csv ";
  const CliRun t1 = Brdfkit(albedo + (dir / "one.csv").string() + " --threads 1");
  const CliRun tn = Brdfkit(albedo + (dir / "many.csv").string() + " --threads 100000");
  ASSERT_EQ(t1.code, 0) << t1.out;
  ASSERT_EQ(tn.code, 0) << tn.out;
  EXPECT_NE(tn.out.find("this machine offers"), std::string::npos) << tn.out;
  EXPECT_EQ(ReadText(dir / "one.csv"), ReadText(dir / "many.csv"));
  for (const std::string& cmd : {fit + "-1", albedo + (dir / "bad.csv").string() + " --threads -1"}) {
    const CliRun r = Brdfkit(cmd);
    EXPECT_EQ(r.code, 2) << cmd;
    EXPECT_NE(r.out.find("--threads -1: expected 0 (every core) or more"), std::string::npos) << r.out;
  }
  EXPECT_FALSE(fs::exists(dir / "bad.csv"));
}

// A measured table is not reciprocal: its energy is the power reflected
// from light along each direction. An RGL file written from GGX (alpha 0.3)
// conserves energy however grazing the light (beyond its last incident slice,
// 87.5 degrees, the slice holds), and at normal light it reflects GGX's
// albedo to the reconstruction's accuracy.
TEST(Cli, MeasuredTablesConserveEnergyForLightFromEveryDirection) {
  const fs::path dir = FreshDir("measured-energy");
  const std::string file = (dir / "ggx.bsdf").string();
  ASSERT_EQ(Brdfkit("convert -m ggx -p alpha=0.3 " + file).code, 0);
  const CliRun rgl = Brdfkit("check -m rgl:" + file + " --no-sampling --json");
  const CliRun ggx = Brdfkit("check -m ggx -p alpha=0.3 --no-sampling --json");
  const auto a = nlohmann::json::parse(rgl.out.substr(rgl.out.find('{')));
  const auto b = nlohmann::json::parse(ggx.out.substr(ggx.out.find('{')));
  EXPECT_LE(a["albedo_max"].get<double>(), 1.0) << rgl.out;
  EXPECT_EQ(std::string(rgl.out).find("energy:"), std::string::npos) << rgl.out;
  EXPECT_NEAR(a["albedo_at_normal"].get<double>(), b["albedo_at_normal"].get<double>(),
              0.01 * b["albedo_at_normal"].get<double>());
  // albedo tabulates the file over mu alone: GGX's E(mu) and E_avg to the
  // reconstruction's accuracy wherever the light meets a slice (at mu = 0
  // the last slice, 87.5 degrees, holds: 0.951 against GGX's 1), at a
  // tolerance the table's interpolation lets the integrals reach.
  const CliRun e_rgl = Brdfkit("albedo -m rgl:" + file + " --axes mu:5 --tolerance 1e-3 --json");
  const CliRun e_ggx = Brdfkit("albedo -m ggx -p alpha=0.3 --axes mu:5 --json");
  ASSERT_EQ(e_rgl.code, 0) << e_rgl.out;
  ASSERT_EQ(e_ggx.code, 0) << e_ggx.out;
  // The JSON line (the summary goes to stderr, which the run merges).
  const auto json_line = [](const std::string& out) {
    const std::size_t at = out.find('{');
    return nlohmann::json::parse(out.substr(at, out.find('\n', at) - at));
  };
  const auto er = json_line(e_rgl.out), eg = json_line(e_ggx.out);
  EXPECT_TRUE(er["axes"].empty());
  for (std::size_t m = 1; m < 5; ++m)
    EXPECT_NEAR(er["E"][m].get<double>(), eg["E"][m].get<double>(), 5e-4) << "mu " << er["mu"][m];
  EXPECT_NEAR(er["E"][0].get<double>(), 0.951, 0.002);
  EXPECT_NEAR(er["E_avg"][0].get<double>(), eg["E_avg"][0].get<double>(), 5e-4);
  // At the tables' 1e-6 contract the file's integrals cannot converge: the
  // table is refused with the tolerance to ask for, and nothing is written
  // (E_avg gives up after the first pass of its rule, not minutes later).
  const std::string csv = (dir / "e.csv").string();
  const CliRun strict = Brdfkit("albedo -m rgl:" + file + " --axes mu:3 --csv " + csv);
  EXPECT_EQ(strict.code, 1) << strict.out;
  EXPECT_NE(strict.out.find("E_avg: error estimate"), std::string::npos) << strict.out;
  EXPECT_NE(strict.out.find("--tolerance 1e-3"), std::string::npos) << strict.out;
  EXPECT_FALSE(fs::exists(csv));
}

// albedo over mu alone: a lambert table read back through UTIA is its
// albedo at the tables' own tolerance (bilinear cells of a constant), and
// the header of such a table (E over mu, one E_avg) compiles as C89 and
// C++ and holds the CSV's values.
TEST(Cli, AlbedoOverMuAloneOfATableAndItsHeader) {
  const fs::path dir = FreshDir("albedo-mu-alone");
  const std::string utia = (dir / "l.utia").string(), stem = (dir / "l").string();
  ASSERT_EQ(Brdfkit("convert -m lambert -p albedo=0.4 --no-sidecar " + utia).code, 0);
  const CliRun r = Brdfkit("albedo -m utia:" + utia + " --axes mu:6 --csv " + stem + ".csv --header " + stem +
                           ".h --header-prefix tab");
  ASSERT_EQ(r.code, 0) << r.out;
  std::istringstream csv(ReadText(stem + ".csv"));
  std::string line, expected;
  std::getline(csv, line);
  EXPECT_EQ(line, "mu,E");
  while (std::getline(csv, line)) {
    EXPECT_NEAR(std::stod(line.substr(line.find(',') + 1)), 0.4, 1e-6) << line;
    expected += line.substr(line.find(',') + 1) + "\n";
  }
  const std::string prog = "#include <math.h>\n#include <stdio.h>\n#include \"" + stem +
                           ".h\"\nint main(void) {\n  int m, bad = 0;\n"
                           "  for (m = 0; m < tab_n_mu; ++m) {\n    printf(\"%.9g\\n\", (double)tab_E[m]);\n"
                           "    if (tab_E_lookup(tab_mu_nodes[m]) != tab_E[m]) ++bad;\n  }\n"
                           "  if (fabs(tab_E_avg[0] - 0.4) > 1e-6 || fabs(tab_ms_norm[0] * 3.14159265 * 0.6 - 1) > 1e-5) ++bad;\n"
                           "  return bad;\n}\n";
  EXPECT_EQ(ExpectHeaderProgramPrints(stem, prog, expected, {"gcc -x c -std=c89", "g++ -x c++ -std=c++11"}, "mu:6"),
            6u);
}

// stress takes a measured table as every other command does (-m rgl:FILE)
// and sweeps it exactly as with its option (--rgl FILE); a file that does
// not open is named, exit 2.
TEST(Cli, StressTakesMeasuredTablesByTheirModelText) {
  const fs::path dir = FreshDir("stress-measured");
  const std::string rgl = (dir / "ggx.bsdf").string(), utia = (dir / "lambert.utia").string();
  ASSERT_EQ(Brdfkit("convert -m ggx -p alpha=0.3 --rgl-theta-i 6 --rgl-samples 16 --rgl-vndf 16 --rgl-ndf 32 "
                    "--no-sidecar " + rgl).code, 0);
  ASSERT_EQ(Brdfkit("convert -m lambert --no-sidecar " + utia).code, 0);
  const CliRun by_text = Brdfkit("stress -m rgl:" + rgl + " -m utia:" + utia + " --sweep-only --json");
  const CliRun by_option = Brdfkit("stress -m rgl -m utia --rgl " + rgl + " --utia " + utia + " --sweep-only --json");
  ASSERT_EQ(by_text.code, 0) << by_text.out;
  ASSERT_EQ(by_option.code, 0) << by_option.out;
  const auto a = nlohmann::json::parse(by_text.out), b = nlohmann::json::parse(by_option.out);
  ASSERT_EQ(a["models"].size(), 6u);  // two tables x float, double, Jet
  for (std::size_t k = 0; k < a["models"].size(); ++k) {
    const auto& row = a["models"][k];
    EXPECT_EQ(row["model"], b["models"][k]["model"]);
    EXPECT_EQ(row["evaluations"], b["models"][k]["evaluations"]);
    EXPECT_EQ(row["reciprocity_max_rel_error"], b["models"][k]["reciprocity_max_rel_error"]);
    if (row["type"] != "jet") {
      EXPECT_GT(row["evaluations"].get<long long>(), 1000) << row.dump();
    }
  }
  const CliRun missing = Brdfkit("stress -m rgl:" + (dir / "none.bsdf").string());
  EXPECT_EQ(missing.code, 2);
  EXPECT_NE(missing.out.find("none.bsdf"), std::string::npos) << missing.out;
  const CliRun no_file = Brdfkit("stress -m ggx:" + rgl);
  EXPECT_EQ(no_file.code, 2);
  EXPECT_NE(no_file.out.find("model 'ggx' takes no ':' argument"), std::string::npos) << no_file.out;
}

// Scene messages: a misspelt top-level key is named as such (with the
// nearest known key), and a relative path is shown as resolved.
TEST(Cli, SceneMessagesNameTheKeyAndTheResolvedPath) {
  const fs::path dir = FreshDir("scene-messages");
  WriteText(dir / "typo.json", R"({"material": {"a": {"model": "lambert"}},
    "tasks": [{"name": "c", "type": "check", "materials": ["a"]}]})");
  CliRun r = Brdfkit("run " + (dir / "typo.json").string() + " --dry-run");
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_NE(r.out.find("material: unknown key"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("did you mean materials?"), std::string::npos) << r.out;
  WriteText(dir / "missing.json", R"({"materials": {"m": {"merl": "data/none.binary"}},
    "tasks": [{"name": "c", "type": "check", "materials": ["m"]}]})");
  r = Brdfkit("run missing.json --dry-run", "cd " + dir.string() + " && ");
  EXPECT_EQ(r.code, 2) << r.out;
  const std::string resolved = fs::weakly_canonical(dir).string() + "/data/none.binary";
  EXPECT_NE(r.out.find("'data/none.binary' (resolved to '" + resolved + "')"), std::string::npos) << r.out;
}

}  // namespace
