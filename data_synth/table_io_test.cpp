#include "data_synth/table_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include "tests/scratch.h"

namespace brdfkit::synth {
namespace {

namespace fs = std::filesystem;

class TableIoTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = test::FreshDir(std::string("table_io_") + ::testing::UnitTest::GetInstance()->current_test_info()->name());
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string Write(const std::string& name, const std::string& text) {
    const std::string p = (dir_ / name).string();
    std::ofstream(p, std::ios::binary) << text;
    return p;
  }

  // Expects ReadTableCsv to throw with a message containing every needle.
  void ExpectError(const std::string& path, std::initializer_list<std::string> needles) {
    try {
      ReadTableCsv(path);
      FAIL() << "no error for " << path;
    } catch (const std::runtime_error& e) {
      const std::string msg = e.what();
      for (const std::string& n : needles) EXPECT_NE(msg.find(n), std::string::npos) << msg << " lacks " << n;
    }
  }

  fs::path dir_;
};

TEST_F(TableIoTest, RoundTripIsBitExact) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (bool sigma : {false, true}) {
    BrdfTable t;
    t.has_sigma = sigma;
    for (int k = 0; k < 200; ++k) {
      BrdfSample s;
      s.theta_i = u(rng) * 1.5;
      s.phi_i = u(rng) * 6.2;
      s.theta_o = u(rng) * 1.5;
      s.phi_o = -u(rng) * 3.1;
      const double f_b = u(rng) * 1e5, f_g = u(rng) * 1e-7, f_r = u(rng);  // one draw at a time
      s.f = Eigen::Array3d(f_r, f_g, f_b);
      s.sigma = sigma ? Eigen::Array3d(u(rng) + 1e-3, 0.1, 1e-300) : Eigen::Array3d::Zero();
      t.rows.push_back(s);
    }
    const std::string p = (dir_ / "rt.csv").string();
    WriteTableCsv(p, t);
    const BrdfTable r = ReadTableCsv(p);
    ASSERT_EQ(r.rows.size(), t.rows.size());
    EXPECT_EQ(r.has_sigma, sigma);
    EXPECT_EQ(r.missing, 0u);
    for (std::size_t k = 0; k < t.rows.size(); ++k) {
      EXPECT_EQ(r.rows[k].theta_i, t.rows[k].theta_i);
      EXPECT_EQ(r.rows[k].phi_i, t.rows[k].phi_i);
      EXPECT_EQ(r.rows[k].theta_o, t.rows[k].theta_o);
      EXPECT_EQ(r.rows[k].phi_o, t.rows[k].phi_o);
      EXPECT_TRUE((r.rows[k].f == t.rows[k].f).all());
      if (sigma) {
        EXPECT_TRUE((r.rows[k].sigma == t.rows[k].sigma).all());
      }
    }
  }
}

TEST_F(TableIoTest, WriterLeavesNoFileWhenTargetIsADirectory) {
  BrdfTable t;
  EXPECT_THROW(WriteTableCsv(dir_.string(), t), std::runtime_error);
  EXPECT_TRUE(fs::is_directory(dir_));
}

TEST_F(TableIoTest, GreyColumnAnyOrderCrlfAndMissing) {
  const std::string p = Write("grey.csv",
                              "# comment\r\n"
                              "f, theta_o ,phi_o,theta_i,phi_i,sigma\r\n"
                              "0.25,0.5,1,0.1,0,0.01\r\n"
                              ",0.5,1,0.1,0,0.01\r\n"
                              "nan,0.5,1,0.1,0,0.01\r\n"
                              "0.5,NaN,1,0.1,0,0.01\r\n"
                              "\r\n"
                              "+0.75,0.25,2,0.2,3,1e-2\r\n");
  const BrdfTable t = ReadTableCsv(p);
  ASSERT_EQ(t.rows.size(), 2u);
  EXPECT_EQ(t.missing, 3u);
  EXPECT_TRUE(t.has_sigma);
  EXPECT_EQ(t.rows[0].theta_i, 0.1);
  EXPECT_EQ(t.rows[0].theta_o, 0.5);
  EXPECT_EQ(t.rows[0].phi_o, 1.0);
  EXPECT_TRUE((t.rows[0].f == 0.25).all());
  EXPECT_TRUE((t.rows[1].f == 0.75).all());
  EXPECT_TRUE((t.rows[1].sigma == 0.01).all());
}

TEST_F(TableIoTest, Errors) {
  ExpectError((dir_ / "absent.csv").string(), {"absent.csv", "no such file"});
  ExpectError(dir_.string(), {"directory"});
  ExpectError(Write("empty.csv", ""), {"empty.csv", "empty file"});
  ExpectError(Write("blank.csv", "\n\n# only a comment\n"), {"blank.csv", "empty file"});
  ExpectError(Write("nocol.csv", "theta_i,phi_i,theta_o,f_r,f_g,f_b\n0,0,0,1,1,1\n"),
              {"nocol.csv:1", "missing column 'phi_o'"});
  ExpectError(Write("nof.csv", "theta_i,phi_i,theta_o,phi_o\n0,0,0,0\n"), {"nof.csv:1", "missing column 'f_r'"});
  ExpectError(Write("partrgb.csv", "theta_i,phi_i,theta_o,phi_o,f_r,f_g\n0,0,0,0,1,1\n"),
              {"partrgb.csv:1", "missing column 'f_b'"});
  ExpectError(Write("unknown.csv", "theta_i,phi_i,theta_o,phi_o,f,colour\n0,0,0,0,1,1\n"),
              {"unknown.csv:1", "unknown column 'colour'"});
  ExpectError(Write("text.csv", "theta_i,phi_i,theta_o,phi_o,f\n0,0,0,0,1\n0.1,0,0.2,0,abc\n"),
              {"text.csv:3", "'abc' is not a number"});
  ExpectError(Write("trail.csv", "theta_i,phi_i,theta_o,phi_o,f\n0,0,0,0,1.5x\n"), {"trail.csv:2", "not a number"});
  ExpectError(Write("inf.csv", "theta_i,phi_i,theta_o,phi_o,f\n0,0,0,0,inf\n"), {"inf.csv:2", "not finite"});
  ExpectError(Write("huge.csv", "theta_i,phi_i,theta_o,phi_o,f\n0,0,0,0," + std::string(100000, '1') + "\n"),
              {"huge.csv:2", "longer than"});
  ExpectError(Write("few.csv", "theta_i,phi_i,theta_o,phi_o,f\n0,0,0,0,1\n0,0,0,1\n"),
              {"few.csv:3", "expected 5 fields, found 4"});
  ExpectError(Write("many.csv", "theta_i,phi_i,theta_o,phi_o,f\n0,0,0,0,1,2\n"), {"many.csv:2", "found 6"});
  ExpectError(Write("deg.csv", "theta_i,phi_i,theta_o,phi_o,f\n45,0,30,0,1\n"), {"deg.csv:2", "radians"});
  ExpectError(Write("sig0.csv", "theta_i,phi_i,theta_o,phi_o,f,sigma\n0,0,0,0,1,0.1\n0,0,0,0,1,0\n"),
              {"sig0.csv:3", "sigma is 0 here but positive elsewhere"});
  ExpectError(Write("signeg.csv", "theta_i,phi_i,theta_o,phi_o,f,sigma\n0,0,0,0,1,-0.1\n"),
              {"signeg.csv:2", "sigma must be positive"});
}

// A noiseless table carries sigma = 0 in every row: read as unweighted data.
TEST_F(TableIoTest, AllZeroSigmaIsANoiselessTable) {
  const BrdfTable t = ReadTableCsv(Write("noiseless.csv", "theta_i,phi_i,theta_o,phi_o,f_r,f_g,f_b,sigma_r,sigma_g,sigma_b\n"
                                                          "0.1,0,0.2,3,0.5,0.25,0.125,0,0,0\n0.3,1,0.4,2,1,2,3,0,0,0\n"));
  EXPECT_FALSE(t.has_sigma);
  ASSERT_EQ(t.rows.size(), 2u);
  EXPECT_EQ(t.rows[1].f[2], 3.0);
}

// A table with sigma columns but no rows reads as unweighted, so it
// round-trips through the writer (which always writes sigma columns).
TEST_F(TableIoTest, EmptyTableRoundTrips) {
  const BrdfTable t = ReadTableCsv(Write("empty.csv", "theta_i,phi_i,theta_o,phi_o,f\n# no rows\n"));
  EXPECT_TRUE(t.rows.empty());
  EXPECT_FALSE(t.has_sigma);
  const std::string back = (dir_ / "back.csv").string();
  WriteTableCsv(back, t);
  const BrdfTable u = ReadTableCsv(back);
  EXPECT_TRUE(u.rows.empty());
  EXPECT_FALSE(u.has_sigma);
}

}  // namespace
}  // namespace brdfkit::synth
