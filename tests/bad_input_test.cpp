// Bad input as users bring it, through the built tool: every case gets a
// message naming the file and line (or the key, or the parameter), a
// non-zero exit, and leaves an existing output file untouched with no
// temporary file behind. Missing samples (negative MERL values, empty or NaN
// CSV fields) are counted and skipped, not errors.
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <array>
#include <cstring>
#include <limits>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <sys/wait.h>
#include <unistd.h>
#include <vector>

#include "brdf/merl.h"
#include "brdf/model.h"
#include "brdf/params.h"
#include "fit/fit.h"

#include "tests/cli_util.h"

namespace brdfkit {
namespace {

namespace fs = std::filesystem;

using ToolRun = test::CliRun;

// Single-quotes an argument for sh (paths may hold any byte but NUL).
std::string Quote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

ToolRun Brdfkit(const std::vector<std::string>& args) {
  std::string cmd = Quote(BRDFKIT_EXE);
  for (const std::string& a : args) cmd += " " + Quote(a);
  return test::Shell(cmd);
}

std::string Slurp(const fs::path& p) { return test::ReadText(p); }

void Write(const fs::path& p, const std::string& text) {
  std::ofstream(p, std::ios::binary) << text;
}

class BadInput : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = test::FreshDir(std::string("bad_input_") + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    good_ = dir_ / "good.csv";
    Write(good_, kGood);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Runs the tool, which must fail naming every needle, keep good_ as it was
  // and leave no temporary file in the folder.
  void ExpectRejected(const std::vector<std::string>& args, const std::vector<std::string>& needles) {
    const ToolRun r = Brdfkit(args);
    std::string cmd;
    for (const auto& a : args) cmd += a + " ";
    SCOPED_TRACE(cmd);
    EXPECT_NE(r.code, 0) << r.out;
    EXPECT_NE(r.out.find("brdfkit: error:"), std::string::npos) << r.out;
    for (const std::string& n : needles) EXPECT_NE(r.out.find(n), std::string::npos) << "'" << n << "' not in: " << r.out;
    EXPECT_EQ(Slurp(good_), kGood);
    for (const auto& e : fs::directory_iterator(dir_))
      EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << "left behind: " << e.path();
  }

  std::string P(const std::string& name) const { return (dir_ / name).string(); }

  // `fit` reading a data file, with the result going over good_.
  std::vector<std::string> FitArgs(const std::string& data) const {
    return {"fit", "--data", data, "--model", "lambert", "--no-covariance", "--out", good_.string()};
  }

  // A MERL header with the given dimensions.
  static std::string MerlHeader(std::int32_t a, std::int32_t b, std::int32_t c) {
    std::string h(12, '\0');
    const std::int32_t d[3] = {a, b, c};
    for (int k = 0; k < 3; ++k)
      for (int byte = 0; byte < 4; ++byte) h[4 * k + byte] = static_cast<char>((std::uint32_t(d[k]) >> (8 * byte)) & 0xff);
    return h;
  }
  // A file of `size` bytes starting with `head`, the rest zeros (sparse).
  static void WriteSized(const fs::path& p, const std::string& head, std::uintmax_t size) {
    Write(p, head);
    fs::resize_file(p, size);
  }

  static constexpr const char* kGood = "a good result from an earlier run\n";
  static constexpr const char* kCsvHeader = "theta_i,phi_i,theta_o,phi_o,f_r,f_g,f_b\n";
  fs::path dir_, good_;
};

TEST_F(BadInput, MerlFilesTruncatedOverLongWrongDimensionsOrNonFinite) {
  const std::uintmax_t full = MerlTable::kFileSize;
  WriteSized(P("truncated.binary"), MerlHeader(90, 90, 180), full - 8);
  ExpectRejected(FitArgs(P("truncated.binary")), {P("truncated.binary"), "truncated", std::to_string(full - 8) + " bytes"});
  WriteSized(P("long.binary"), MerlHeader(90, 90, 180), full + 8);
  ExpectRejected(FitArgs(P("long.binary")), {P("long.binary"), "over-long"});
  WriteSized(P("dims.binary"), MerlHeader(90, 90, 360), full);
  ExpectRejected(FitArgs(P("dims.binary")), {P("dims.binary"), "header dimensions 90 x 90 x 360"});
  // +Inf in the green channel at theta_h bin 2, theta_d bin 3, phi_d bin 4.
  std::string head = MerlHeader(90, 90, 180);
  const std::size_t index = MerlTable::kCells + MerlTable::Index(2, 3, 4);
  head.resize(12 + 8 * (index + 1), '\0');
  const double inf = std::numeric_limits<double>::infinity();
  std::memcpy(head.data() + 12 + 8 * index, &inf, 8);
  WriteSized(P("inf.binary"), head, full);
  ExpectRejected(FitArgs(P("inf.binary")), {P("inf.binary"), "non-finite", "green", "theta_h bin 2", "theta_d bin 3",
                                           "phi_d bin 4"});
}

TEST_F(BadInput, CsvFilesNameTheFileAndLine) {
  Write(P("empty.csv"), "");
  ExpectRejected(FitArgs(P("empty.csv")), {P("empty.csv"), "empty"});
  Write(P("nocol.csv"), "theta_i,phi_i,theta_o,f_r,f_g,f_b\n0.1,0,0.2,0.3,0.3,0.3\n");
  ExpectRejected(FitArgs(P("nocol.csv")), {P("nocol.csv") + ":1", "missing column 'phi_o'"});
  Write(P("text.csv"), std::string(kCsvHeader) + "0.1,0,0.2,3.1,0.3,0.3,0.3\n0.1,0,abc,3.1,0.3,0.3,0.3\n");
  ExpectRejected(FitArgs(P("text.csv")), {P("text.csv") + ":3", "theta_o", "'abc'", "not a number"});
  Write(P("huge.csv"), std::string(kCsvHeader) + std::string(200000, '1') + "\n");
  ExpectRejected(FitArgs(P("huge.csv")), {P("huge.csv") + ":2", "longer than"});
  Write(P("fields.csv"), std::string(kCsvHeader) + "0.1,0,0.2,3.1,0.3,0.3\n");
  ExpectRejected(FitArgs(P("fields.csv")), {P("fields.csv") + ":2", "expected 7 fields, found 6"});
  Write(P("inf.csv"), std::string(kCsvHeader) + "0.1,0,0.2,3.1,inf,0.3,0.3\n");
  ExpectRejected(FitArgs(P("inf.csv")), {P("inf.csv") + ":2", "f_r", "not finite"});
  fs::create_directories(P("folder.csv"));
  ExpectRejected(FitArgs(P("folder.csv")), {P("folder.csv"), "directory"});
  ExpectRejected(FitArgs(P("absent.csv")), {P("absent.csv"), "no such file"});
}

// A path that is not UTF-8 (Latin-1 bytes) is named byte for byte in the
// message; a good file there is read and its result written as valid JSON.
TEST_F(BadInput, NonUtf8PathsAreNamedAndWork) {
  const std::string bad = P("mes\xe9sure\xff.csv");
  Write(bad, std::string(kCsvHeader) + "0.1,0,0.2,3.1,0.3,0.3,0.3\n0.1,0,x,3.1,0.3,0.3,0.3\n");
  ExpectRejected(FitArgs(bad), {bad + ":3", "'x'"});
  std::string rows = kCsvHeader;
  for (int k = 1; k < 20; ++k) rows += "0.2,0," + FormatDouble(0.07 * k) + ",3.1,0.159,0.159,0.159\n";
  Write(bad, rows);
  const fs::path out = dir_ / "fit\xe9.json";
  const ToolRun r = Brdfkit({"fit", "--data", bad, "--model", "lambert", "--no-covariance", "--json", "--out", out.string()});
  ASSERT_EQ(r.code, 0) << r.out;
  const nlohmann::json j = nlohmann::json::parse(Slurp(out));
  EXPECT_NEAR(j["params"]["albedo"][0].get<double>(), 0.159 * kPi, 1e-6) << j.dump();
}

// Fixed, tied and bounded parameters that do not apply: exit 2 naming the
// option and the parameter, before any data are read; the output stays.
TEST_F(BadInput, FitConstraintsNameTheParameter) {
  std::string rows = kCsvHeader;
  for (int k = 1; k < 20; ++k) rows += "0.2,0," + FormatDouble(0.07 * k) + ",3.1,0.159,0.159,0.159\n";
  Write(P("ok.csv"), rows);
  const auto args = [&](const std::string& option, const std::string& value) {
    return std::vector<std::string>{"fit", "--data", P("ok.csv"), "--model", "lambert+ggx+ggx", "--no-covariance",
                                    "--out", good_.string(), option, value};
  };
  const auto rejected = [&](const std::string& option, const std::string& value, const std::vector<std::string>& needles) {
    ExpectRejected(args(option, value), needles);
    EXPECT_EQ(Brdfkit(args(option, value)).code, 2);
  };
  rejected("--fix", "ggx.alhpa=0.1", {"--fix: unknown parameter 'ggx.alhpa'", "did you mean ggx.alpha"});
  rejected("--fix", "ggx.f0=2", {"--fix", "'ggx.f0' (r) = 2 is outside its range [0, 1]"});
  rejected("--bounds", "ggx.alpha=0.5:0.01", {"--bounds: 'ggx.alpha' = [0.5, 0.01] is inverted"});
  rejected("--bounds", "ggx.weight=0:20", {"--bounds: 'ggx.weight' = [0, 20] reaches outside its range [0, 10]"});
  rejected("--tie", "ggx#2.f0=ggx.alpha", {"--tie: 'ggx#2.f0'", "'ggx.alpha'", "different kinds"});
  rejected("--tie", "ggx#2.alpha=ggx.alpha,ggx.alpha=ggx#2.alpha", {"--tie: the ties form a cycle", "ggx.alpha"});
  rejected("--fix", "lambert.albedo=0.1,ggx.alpha=0.1,ggx.f0=0.1,ggx.weight=1,ggx#2.alpha=0.2,ggx#2.f0=0.1,ggx#2.weight=0",
           {"lambert+ggx+ggx", "nothing left to fit"});
  rejected("--random-starts", "-1", {"--random-starts must be in [0, 100000]"});
  rejected("--random-starts", "1000000", {"--random-starts must be in [0, 100000]"});
  rejected("--random-starts", "many", {"--random-starts"});
}

// Missing samples are not errors: counted, reported, skipped.
TEST_F(BadInput, MissingCsvSamplesAreCountedAndSkipped) {
  std::string rows = kCsvHeader;
  for (int k = 1; k < 20; ++k) rows += "0.2,0," + FormatDouble(0.07 * k) + ",3.1,0.159,0.159,0.159\n";
  rows += "0.2,0,0.5,3.1,,0.2,0.2\n";     // empty field
  rows += "0.2,0,0.6,3.1,nan,0.2,0.2\n";  // NaN field
  rows += "0.2,0,0.7,3.1,0.2,NaN,0.2\n";
  Write(P("gaps.csv"), rows);
  const ToolRun r = Brdfkit({"fit", "--data", P("gaps.csv"), "--model", "lambert", "--no-covariance", "--json"});
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("3 missing sample(s) in '" + P("gaps.csv") + "' skipped"), std::string::npos) << r.out;
  const nlohmann::json j = nlohmann::json::parse(r.out.substr(r.out.find('{')));
  EXPECT_EQ(j["missing"].get<int>(), 3);
  EXPECT_NEAR(j["params"]["albedo"][1].get<double>(), 0.159 * kPi, 1e-6);
}

// Negative MERL values mark missing cells: the fit counts them (with the
// cells whose centre is at the horizon) and fits the rest.
TEST_F(BadInput, NegativeMerlValuesAreCountedAndSkipped) {
  const Model lambert = Model::Parse("lambert");
  const std::vector<double> p = ParseParams(lambert.Info(), "albedo=0.4");
  const auto b = lambert.Make<double>();
  MerlTable t = MerlTable::FromFunction(
      [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return b->Eval(p.data(), wi, wo); });
  const std::size_t horizon = fit::FromMerl(t).missing;
  std::size_t marked = 0;
  for (std::size_t n = 1000; n < MerlTable::kCells; n += 977)
    if (t.values[MerlTable::kCells + n] >= 0) {
      t.values[MerlTable::kCells + n] = -1;  // green only: the cell is missing
      ++marked;
    }
  ASSERT_GT(marked, 1000u);
  t.Write(P("holes.binary"));
  const ToolRun r = Brdfkit({"fit", "--data", P("holes.binary"), "--model", "lambert", "--init", "albedo=0.4",
                         "--no-covariance", "--max-iterations", "2", "--json"});
  ASSERT_EQ(r.code, 0) << r.out;
  const nlohmann::json j = nlohmann::json::parse(r.out.substr(r.out.find('{')));
  EXPECT_EQ(j["missing"].get<std::size_t>(), horizon + marked);
  EXPECT_NE(r.out.find(std::to_string(horizon + marked) + " missing sample(s)"), std::string::npos) << r.out;
  EXPECT_NEAR(j["params"]["albedo"][1].get<double>(), 0.4, 1e-9);
}

// Instrument files: unknown key, wrong type, missing field, not JSON. The
// message names the file and the key path.
TEST_F(BadInput, InstrumentFilesNameTheKey) {
  const ToolRun def = Brdfkit({"synth", "--print-instrument"});
  ASSERT_EQ(def.code, 0) << def.out;
  const nlohmann::json base = nlohmann::json::parse(def.out);
  auto synth = [&](const std::string& file) {
    return std::vector<std::string>{"synth", "--model", "lambert", "--instrument", file, "--out", good_.string(), "-q"};
  };
  nlohmann::json j = base;
  j["detector"]["exposure_tme"] = 1e-3;
  Write(P("unknown.json"), j.dump());
  ExpectRejected(synth(P("unknown.json")), {P("unknown.json"), "detector.exposure_tme"});
  j = base;
  j["detector"]["exposure_time"] = "fast";
  Write(P("type.json"), j.dump());
  ExpectRejected(synth(P("type.json")), {P("type.json"), "detector.exposure_time"});
  j = base;
  j.erase("sample");
  Write(P("missing.json"), j.dump());
  ExpectRejected(synth(P("missing.json")), {P("missing.json"), "sample"});
  Write(P("broken.json"), "{\n  \"source\": {\n    \"type\": \"disc\",\n");
  ExpectRejected(synth(P("broken.json")), {P("broken.json")});
  ExpectRejected(synth(P("absent.json")), {P("absent.json")});
  // A number beyond a double (nlohmann throws out_of_range, not a parse error).
  std::string huge = base.dump();
  huge.replace(huge.find("\"exposure_time\":") + 16, 5, "1e400");
  Write(P("huge.json"), huge);
  ExpectRejected(synth(P("huge.json")), {P("huge.json"), "1e400"});
  fs::create_directories(P("folder.json"));
  ExpectRejected(synth(P("folder.json")), {P("folder.json")});
}

// Model parameters: each message names the parameter (or the model name).
TEST_F(BadInput, ParametersNameTheParameter) {
  auto albedo = [&](const std::string& model, const std::string& params) {
    return std::vector<std::string>{"synth", "--model", model, "--params", params, "--out", good_.string(), "-q"};
  };
  ExpectRejected(albedo("ggx", "alpha=-0.1"), {"'alpha'", "outside its range"});
  ExpectRejected(albedo("ggx", "alpha=0"), {"'alpha'", "outside its range"});
  ExpectRejected(albedo("ggx", "alpha=nan"), {"'alpha'"});
  ExpectRejected(albedo("ggx", "alpha=2"), {"'alpha'", "outside its range"});
  ExpectRejected(albedo("ggx", "alpha=0.1x"), {"'alpha'", "'0.1x' is not a number"});
  ExpectRejected(albedo("ggx", "beta=0.1"), {"unknown parameter 'beta'", "alpha"});
  ExpectRejected(albedo("ggxx", "alpha=0.1"), {"unknown model 'ggxx'"});
  ExpectRejected(albedo("lambert+gxx", "alpha=0.1"), {"unknown model 'gxx'", "lambert+gxx"});
  ExpectRejected(albedo("lambert+ggx", "ggx.alpah=0.1"), {"unknown parameter 'ggx.alpah'"});
  ExpectRejected({"eval", "--model", "phong", "--params", "n=1e9", "--wi", "0,0,1", "--wo", "0,0,1"},
                 {"'n'", "outside its range"});
  ExpectRejected({"stress", "--model", "gxx", "-o", good_.string()}, {"unknown model 'gxx'"});
}

// A run stopped by a signal part-way through writing leaves the earlier
// good table where it was (the data goes to a temporary name first).
TEST_F(BadInput, InterruptedRunKeepsTheEarlierTable) {
  const std::string cmd = Quote(BRDFKIT_EXE) + " albedo --model ggx --axes mu:64,alpha:64 --tolerance 1e-12 --csv " +
                          Quote(good_.string()) + " >/dev/null 2>&1 & pid=$!; sleep 1; kill -TERM $pid; wait $pid; exit $?";
  const int status = std::system(cmd.c_str());
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 128 + SIGTERM) << "the run ended before the signal";
  EXPECT_EQ(Slurp(good_), kGood);
}

}  // namespace
}  // namespace brdfkit
