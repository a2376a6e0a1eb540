// MERL binary format: layout, Rusinkiewicz coordinates, lookups, file errors
// and the [merl] model. Tables come from analytic models (the public database
// cannot be downloaded here), so every expected value is known exactly.
#include "brdf/merl.h"

#include <gtest/gtest.h>

#include <array>
#include <bit>
#include <cstring>
#include <functional>
#include <filesystem>
#include <fstream>
#include <random>

#include "brdf/model.h"
#include "brdf/params.h"
#include "validate/jet_models.h"
#include "tests/scratch.h"

namespace brdfkit {
namespace {

namespace fs = std::filesystem;
using Table = MerlTable;

Eigen::Vector3d RandomUpper(std::mt19937_64& rng, double max_theta = kPi / 2) {
  std::uniform_real_distribution<double> u(0, 1);
  const double z = 1 - (1 - std::cos(max_theta)) * u(rng);  // uniform on the spherical cap
  const double phi = 2 * kPi * u(rng), s = std::sqrt(std::max(0.0, 1 - z * z));
  return Eigen::Vector3d(s * std::cos(phi), s * std::sin(phi), z);
}

Eigen::Vector3d RotateZ(const Eigen::Vector3d& v, double angle) {
  return Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()) * v;
}

void ExpectThrowNaming(const std::function<void()>& f, const std::string& path, const std::string& words) {
  try {
    f();
    ADD_FAILURE() << "no exception for " << path << " (" << words << ")";
  } catch (const std::runtime_error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(path), std::string::npos) << "message does not name the file: " << msg;
    EXPECT_NE(msg.find(words), std::string::npos) << "message does not say '" << words << "': " << msg;
  }
}

// One lambert+ggx table written once and shared by the tests.
class MerlFile : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new fs::path(test::FreshDir("merl"));
    model_ = new Model(Model::Parse("lambert+ggx"));
    params_ = new std::vector<double>(
        ParseParams(model_->Info(), "lambert.albedo=0.3:0.4:0.5,ggx.alpha=0.2,ggx.f0=0.9:0.7:0.5"));
    const auto b = model_->Make<double>();
    table_ = new Table(Table::FromFunction(
        [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return b->Eval(params_->data(), wi, wo); }));
    path_ = new std::string((*dir_ / "lambert_ggx.binary").string());
    table_->Write(*path_);
  }
  static void TearDownTestSuite() {
    std::error_code ec;
    fs::remove_all(*dir_, ec);
    delete dir_;
    delete model_;
    delete params_;
    delete table_;
    delete path_;
  }

  static fs::path* dir_;
  static Model* model_;
  static std::vector<double>* params_;
  static Table* table_;
  static std::string* path_;
};
fs::path* MerlFile::dir_ = nullptr;
Model* MerlFile::model_ = nullptr;
std::vector<double>* MerlFile::params_ = nullptr;
Table* MerlFile::table_ = nullptr;
std::string* MerlFile::path_ = nullptr;

// REFERENCE.md: theta_h bin = floor(sqrt(theta_h / (pi/2)) 90), theta_d bin =
// floor(theta_d / (pi/2) 90), phi_d bin = floor(phi_d / pi 180), clamped;
// linear index phi_d + 180 (theta_d + 90 theta_h).
// BinDirections (sines and cosines from tables of the centres' angles) is
// HalfDiffToDirections of BinCentre (computed per bin), bit for bit, at
// every bin.
TEST(MerlIndex, BinDirectionsAreTheBinCentres) {
  std::size_t wrong = 0;
  for (int i = 0; i < Table::kThetaH; ++i)
    for (int j = 0; j < Table::kThetaD; ++j)
      for (int k = 0; k < Table::kPhiD; ++k) {
        double th, td, pd;
        Table::BinCentre(i, j, k, th, td, pd);
        Eigen::Vector3d wi, wo, ti, to;
        Table::HalfDiffToDirections(th, td, pd, wi, wo);
        Table::BinDirections(i, j, k, ti, to);
        wrong += ti != wi || to != wo;
      }
  EXPECT_EQ(wrong, 0u);
}

TEST(MerlIndex, MatchesReferenceFormulas) {
  EXPECT_EQ(Table::Index(0, 0, 1), 1u);
  EXPECT_EQ(Table::Index(0, 1, 0), 180u);
  EXPECT_EQ(Table::Index(1, 0, 0), 180u * 90u);
  EXPECT_EQ(Table::Index(89, 89, 179), Table::kCells - 1);
  EXPECT_EQ(Table::kFileSize, 12u + 3u * 1458000u * 8u);

  // Non-linear theta_h: 45 deg is at sqrt(1/2) 90 = 63.6, not at bin 45.
  EXPECT_EQ(Table::ThetaHalfIndex(kPi / 4), 63);
  EXPECT_EQ(Table::ThetaHalfIndex(kPi / 180), 9);  // sqrt(1/90) 90 = 9.49
  EXPECT_EQ(Table::ThetaHalfIndex(0.0), 0);
  EXPECT_EQ(Table::ThetaHalfIndex(-0.1), 0);
  EXPECT_EQ(Table::ThetaHalfIndex(kPi / 2), 89);
  EXPECT_EQ(Table::ThetaHalfIndex(2.0), 89);
  EXPECT_EQ(Table::ThetaDiffIndex(kPi / 4 + 1e-9), 45);
  EXPECT_EQ(Table::ThetaDiffIndex(kPi / 2), 89);
  EXPECT_EQ(Table::PhiDiffIndex(kPi / 2 + 1e-9), 90);
  EXPECT_EQ(Table::PhiDiffIndex(kPi), 179);

  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(0, 1);
  int checked = 0;
  for (int n = 0; n < 20000; ++n) {
    const double th = u(rng) * kPi / 2, td = u(rng) * kPi / 2, pd = (2 * u(rng) - 1) * kPi;
    const double xh = std::sqrt(th / (kPi / 2)) * 90, xd = td / (kPi / 2) * 90;
    const double xp = (pd < 0 ? pd + kPi : pd) / kPi * 180;
    // Points within rounding of a bin edge may fall either way.
    auto near_edge = [](double x) { return std::abs(x - std::round(x)) < 1e-9; };
    if (near_edge(xh) || near_edge(xd) || near_edge(xp)) continue;
    ++checked;
    ASSERT_EQ(Table::ThetaHalfIndex(th), std::min(int(std::floor(xh)), 89)) << th;
    ASSERT_EQ(Table::ThetaDiffIndex(td), std::min(int(std::floor(xd)), 89)) << td;
    ASSERT_EQ(Table::PhiDiffIndex(pd), std::min(int(std::floor(xp)), 179)) << pd;
  }
  EXPECT_GT(checked, 19900);

  // Bin centres: the midpoint between centres i and i+1 is in bin i.
  for (int i = 0; i < 89; ++i) {
    double th0, td0, pd0, th1, td1, pd1;
    Table::BinCentre(i, i, 2 * i, th0, td0, pd0);
    Table::BinCentre(i + 1, i + 1, 2 * i + 1, th1, td1, pd1);
    EXPECT_NEAR(th0, std::pow(i / 90.0, 2) * kPi / 2, 1e-15);
    EXPECT_EQ(Table::ThetaHalfIndex(0.5 * (th0 + th1)), i);
    EXPECT_EQ(Table::ThetaDiffIndex(0.5 * (td0 + td1)), i);
    EXPECT_EQ(Table::PhiDiffIndex(0.5 * (pd0 + pd1)), 2 * i);
  }
}

TEST(MerlCoordinates, RusinkiewiczRoundTrip) {
  std::mt19937_64 rng(2);
  double worst_unfolded = 0, worst_folded = 0, worst_independent = 0;
  for (int n = 0; n < 20000; ++n) {
    const Eigen::Vector3d wi = RandomUpper(rng), wo = RandomUpper(rng);
    const Table::HalfDiff hd = Table::ToHalfDiff(wi, wo);
    Eigen::Vector3d a, b;
    Table::FromHalfDiff(hd, a, b);
    worst_unfolded = std::max({worst_unfolded, (a - wi).norm(), (b - wo).norm()});

    // Folded, phi_h = 0: the pair comes back rotated by -phi_h, in either order.
    double th, td, pd;
    Table::DirectionsToHalfDiff(wi, wo, th, td, pd);
    ASSERT_GE(pd, 0.0);
    ASSERT_LE(pd, kPi);
    Table::HalfDiffToDirections(th, td, pd, a, b);
    a = RotateZ(a, hd.phi_h);
    b = RotateZ(b, hd.phi_h);
    const double same = std::max((a - wi).norm(), (b - wo).norm());
    const double swapped = std::max((a - wo).norm(), (b - wi).norm());
    worst_folded = std::max(worst_folded, std::min(same, swapped));

    // Independent: theta_h from h.z, cos theta_d = wi.h, and wi.z written in
    // half/difference angles, cos th cos td - sin th sin td cos phi_d.
    const Eigen::Vector3d h = (wi + wo).normalized();
    worst_independent = std::max({worst_independent, std::abs(std::cos(hd.theta_h) - h.z()),
                                  std::abs(std::cos(hd.theta_d) - wi.dot(h)),
                                  std::abs(std::cos(hd.theta_h) * std::cos(hd.theta_d) -
                                           std::sin(hd.theta_h) * std::sin(hd.theta_d) * std::cos(hd.phi_d) -
                                           wi.z())});
  }
  EXPECT_LT(worst_unfolded, 1e-13);
  EXPECT_LT(worst_folded, 1e-13);
  EXPECT_LT(worst_independent, 1e-13);

  // Known configurations. Mirror pair in the plane of incidence: h = n,
  // theta_d = theta_i, phi_d = 0.
  const double t = 0.6;
  const Eigen::Vector3d wi(std::sin(t), 0, std::cos(t)), wo(-std::sin(t), 0, std::cos(t));
  double th, td, pd;
  Table::DirectionsToHalfDiff(wi, wo, th, td, pd);
  EXPECT_NEAR(th, 0, 1e-15);
  EXPECT_NEAR(td, t, 1e-15);
  EXPECT_NEAR(pd, 0, 1e-15);
  // Retro-reflection: theta_d = 0, theta_h = theta_i.
  Table::DirectionsToHalfDiff(wi, wi, th, td, pd);
  EXPECT_NEAR(th, t, 1e-15);
  EXPECT_NEAR(td, 0, 1e-15);
  // Mirror pair about a tilted h in the plane perpendicular to the plane of
  // incidence: wi = h rotated by theta_d about x'. d = (0, sin td, cos td): phi_d = pi/2.
  const double a_h = 0.4, a_d = 0.3;
  const Eigen::Vector3d hv(std::sin(a_h), 0, std::cos(a_h));
  const Eigen::Vector3d side(0, 1, 0);
  const Eigen::Vector3d wi2 = std::cos(a_d) * hv + std::sin(a_d) * side, wo2 = std::cos(a_d) * hv - std::sin(a_d) * side;
  Table::DirectionsToHalfDiff(wi2, wo2, th, td, pd);
  EXPECT_NEAR(th, a_h, 1e-15);
  EXPECT_NEAR(td, a_d, 1e-15);
  EXPECT_NEAR(pd, kPi / 2, 1e-15);
}

// Swapping wi and wo turns d into its mirror about h (phi_d + pi); the fold
// maps both to the same angles, bit for bit, so lookups are exactly reciprocal.
TEST_F(MerlFile, ReciprocityFolding) {
  std::mt19937_64 rng(3);
  for (int n = 0; n < 20000; ++n) {
    const Eigen::Vector3d wi = RandomUpper(rng), wo = RandomUpper(rng);
    double th1, td1, pd1, th2, td2, pd2;
    Table::DirectionsToHalfDiff(wi, wo, th1, td1, pd1);
    Table::DirectionsToHalfDiff(wo, wi, th2, td2, pd2);
    ASSERT_EQ(th1, th2);
    ASSERT_EQ(td1, td2);
    ASSERT_EQ(pd1, pd2);
    ASSERT_TRUE(pd1 >= 0 && pd1 < kPi) << pd1;
    const double u1 = Table::ToHalfDiff(wi, wo).phi_d, u2 = Table::ToHalfDiff(wo, wi).phi_d;
    // Unfolded angles differ by pi (mod 2 pi); the folded one is either mod pi.
    EXPECT_NEAR(std::abs(std::remainder(u1 - u2, 2 * kPi)), kPi, 1e-12);
    EXPECT_NEAR(std::abs(std::remainder(pd1 - u1, kPi)), 0, 1e-12);
    for (bool tri : {false, true}) {
      const Rgb<double> f = table_->Lookup(wi, wo, tri), g = table_->Lookup(wo, wi, tri);
      ASSERT_TRUE((f == g).all()) << f.transpose() << " vs " << g.transpose();
    }
  }
}

// Write, read back: the same values to float64 precision, the documented
// layout byte for byte, and the cells below the horizon missing.
TEST_F(MerlFile, RoundTripOfAnalyticModel) {
  EXPECT_EQ(fs::file_size(*path_), 34992012u);
  const Table back = Table::Read(*path_);
  ASSERT_EQ(back.values.size(), 3 * Table::kCells);
  double worst = 0;
  std::size_t missing_mismatch = 0;
  for (std::size_t n = 0; n < back.values.size(); ++n) {
    const double a = table_->values[n], b = back.values[n];
    if ((a < 0) != (b < 0)) ++missing_mismatch;
    if (a > 0) worst = std::max(worst, std::abs(a - b) / a);
  }
  EXPECT_EQ(missing_mismatch, 0u);
  EXPECT_LE(worst, 1e-15);  // divided by the scale on writing, multiplied on reading

  // Values at bin centres are the model at directions built here from the
  // half-vector frame (h, its tangent t in the plane of h and n, binormal y).
  const auto b = model_->Make<double>();
  std::size_t below = 0, ambiguous = 0;
  double worst_model = 0;
  for (int i = 0; i < 90; ++i)
    for (int j = 0; j < 90; ++j)
      for (int k = 0; k < 180; ++k) {
        const double th = std::pow(i / 90.0, 2) * kPi / 2, td = j * kPi / 180, pd = k * kPi / 180;
        const Eigen::Vector3d h(std::sin(th), 0, std::cos(th)), t(std::cos(th), 0, -std::sin(th)), y(0, 1, 0);
        const Eigen::Vector3d dt = std::sin(td) * (std::cos(pd) * t + std::sin(pd) * y);
        const Eigen::Vector3d wi = dt + std::cos(td) * h, wo = -dt + std::cos(td) * h;
        const double margin = std::min(wi.z(), wo.z());
        const std::size_t idx = Table::Index(i, j, k);
        if (std::abs(margin) < 1e-12) {
          ++ambiguous;  // on the horizon to rounding: either way is right
          continue;
        }
        if (margin < 0) {
          ++below;
          for (int c = 0; c < 3; ++c) ASSERT_LT(back.values[c * Table::kCells + idx], 0);
          continue;
        }
        if ((i * 90 + j) % 7 != 0) continue;  // the model check on a subset keeps the test fast
        const Rgb<double> f = b->Eval(params_->data(), wi, wo);
        for (int c = 0; c < 3; ++c)
          worst_model = std::max(worst_model, std::abs(back.values[c * Table::kCells + idx] - f[c]) / f[c]);
      }
  EXPECT_LE(worst_model, 1e-12);
  EXPECT_GT(below, 100000u);
  EXPECT_LT(ambiguous, 200u);
  EXPECT_GE(back.MissingCount(), 3 * below);
  EXPECT_LE(back.MissingCount(), 3 * (below + ambiguous));

  // The bytes: header 90, 90, 180 as little-endian int32; value (c, i, j, k)
  // at 12 + 8 (c 1458000 + k + 180 (j + 90 i)) as a little-endian float64 of
  // f_r / scale.
  std::ifstream in(*path_, std::ios::binary);
  unsigned char header[12];
  in.read(reinterpret_cast<char*>(header), 12);
  const unsigned char expect_header[12] = {90, 0, 0, 0, 90, 0, 0, 0, 180, 0, 0, 0};
  EXPECT_EQ(std::memcmp(header, expect_header, 12), 0);
  const int cells[4][3] = {{0, 0, 0}, {10, 20, 30}, {63, 5, 179}, {40, 44, 90}};
  for (const auto& cell : cells)
    for (int c = 0; c < 3; ++c) {
      const std::size_t offset = 12 + 8 * (c * 1458000 + cell[2] + 180 * (cell[1] + 90 * cell[0]));
      in.seekg(std::streamoff(offset));
      unsigned char bytes[8];
      in.read(reinterpret_cast<char*>(bytes), 8);
      std::uint64_t bits = 0;
      for (int q = 7; q >= 0; --q) bits = (bits << 8) | bytes[q];
      const double stored = std::bit_cast<double>(bits);
      const double expected = table_->values[c * Table::kCells + Table::Index(cell[0], cell[1], cell[2])];
      EXPECT_EQ(stored, expected / Table::kScale[c]) << c;
      EXPECT_GT(stored, 0);
    }
}

// On the normal the azimuth is undefined: a direction there (any phi, either
// sign of its zero components) must look up the same value. The table varies
// with the phi_d bin in every theta_d row, so a lookup that lets the azimuth
// or a signed zero pick phi_d = pi instead of 0 reads a different value.
TEST(MerlLookup, PoleIsIndependentOfAzimuthAndSignedZeros) {
  Table t;
  for (int i = 0; i < Table::kThetaH; ++i)
    for (int j = 0; j < Table::kThetaD; ++j)
      for (int k = 0; k < Table::kPhiD; ++k)
        for (int c = 0; c < 3; ++c) t.values[c * Table::kCells + Table::Index(i, j, k)] = 1 + k + 0.01 * j + c;
  std::vector<Eigen::Vector3d> poles;
  for (double phi : {0.0, kPi / 2, kPi, -kPi, 1.5 * kPi, 2 * kPi, -0.3, 2.9})
    poles.emplace_back(std::sin(0.0) * std::cos(phi), std::sin(0.0) * std::sin(phi), std::cos(0.0));
  for (double sx : {0.0, -0.0})
    for (double sy : {0.0, -0.0}) poles.emplace_back(sx, sy, 1.0);
  const Eigen::Vector3d n = Eigen::Vector3d::UnitZ();
  std::vector<Eigen::Vector3d> others = poles;
  for (double theta : {0.3, 1.1, 1.5})
    for (double phi : {0.0, 2.0, -2.5}) others.emplace_back(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
  for (bool trilinear : {false, true})
    for (const Eigen::Vector3d& wo : others) {
      // The reference: the normal with positive zeros, against wo with its own signs normalised.
      const Eigen::Vector3d wo_ref = wo.z() == 1 ? n : wo;
      const Rgb<double> ref = t.Lookup(n, wo_ref, trilinear);
      for (const Eigen::Vector3d& wi : poles) {
        const Rgb<double> a = t.Lookup(wi, wo, trilinear), b = t.Lookup(wo, wi, trilinear);
        for (int c = 0; c < 3; ++c) {
          EXPECT_EQ(a[c], ref[c]) << "wi (" << wi.transpose() << ") wo (" << wo.transpose() << ") trilinear " << trilinear;
          EXPECT_EQ(b[c], ref[c]) << "swapped, wi (" << wi.transpose() << ") wo (" << wo.transpose() << ")";
        }
      }
    }
  // wi = wo = n: theta_h = theta_d = 0 and the phi_d = 0 cell, value 1 + c.
  const Rgb<double> at_pole = t.Lookup(Eigen::Vector3d(-0.0, -0.0, 1), n, false);
  EXPECT_EQ(at_pole[0], 1.0);
  EXPECT_EQ(at_pole[2], 3.0);
}

// g(th, td, pd) = 0.5 + 0.3 cos th + 0.2 cos td + 0.2 s^2 with
// s = sin th sin td cos pd = (wo.z - wi.z) / 2: smooth, reciprocal, isotropic.
// In index units (x: theta_h = (x/90)^2 pi/2, y: theta_d = y pi/180,
// z: phi_d = z pi/180) the nearest (floor) error is at most
// sum |dg/dx| <= pi/90 (0.3 + 0.2) + pi/180 (0.2 + 0.2 + 0.2) = 1.1 pi/180,
// and the trilinear error at most (1/8) sum |d2g/dx2| with
// |g_xx| <= 0.7 (pi/90)^2 + 0.5 pi/8100, |g_yy| <= 0.6 (pi/180)^2,
// |g_zz| <= 0.4 (pi/180)^2. Directions within 80 deg of the normal keep every
// corner above the horizon (a bin moves a direction's z by < 0.07 < cos 80).
TEST(MerlLookup, TrilinearBeatsNearestOnSmoothFunction) {
  auto g_dirs = [](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
    const Eigen::Vector3d h = (wi + wo).normalized();
    const double s = 0.5 * (wo.z() - wi.z());
    return 0.5 + 0.3 * h.z() + 0.2 * wi.dot(h) + 0.2 * s * s;
  };
  const Table t = Table::FromFunction(g_dirs);
  const double nearest_bound = 1.1 * kPi / 180;
  const double p1 = kPi / 90, p2 = kPi / 180;
  const double trilinear_bound = (0.7 * p1 * p1 + 0.5 * kPi / 8100 + 0.6 * p2 * p2 + 0.4 * p2 * p2) / 8;
  std::mt19937_64 rng(4);
  double max_nearest = 0, max_tri = 0, sum2_nearest = 0, sum2_tri = 0;
  const int n = 20000;
  for (int q = 0; q < n; ++q) {
    const double max_theta = 80 * kPi / 180;
    const Eigen::Vector3d wi = RandomUpper(rng, max_theta), wo = RandomUpper(rng, max_theta);
    const double truth = g_dirs(wi, wo);
    const Rgb<double> fn = t.Lookup(wi, wo, false), ft = t.Lookup(wi, wo, true);
    ASSERT_EQ(fn[0], fn[2]);
    const double en = std::abs(fn[1] - truth), et = std::abs(ft[1] - truth);
    max_nearest = std::max(max_nearest, en);
    max_tri = std::max(max_tri, et);
    sum2_nearest += en * en;
    sum2_tri += et * et;
  }
  EXPECT_LE(max_nearest, nearest_bound);
  EXPECT_LE(max_tri, trilinear_bound);
  // The floor lookup is biased by up to a bin: its error is of the order of
  // the first-derivative bound, the trilinear one orders of magnitude less.
  EXPECT_GT(max_nearest, 0.2 * nearest_bound);
  EXPECT_LT(std::sqrt(sum2_tri / n), 0.02 * std::sqrt(sum2_nearest / n));

  // At a bin centre trilinear reproduces the stored value.
  for (const auto& c : {std::array<int, 3>{10, 20, 30}, {45, 30, 179}, {70, 10, 0}}) {
    double th, td, pd;
    Table::BinCentre(c[0], c[1], c[2], th, td, pd);
    EXPECT_NEAR(t.LookupHalfDiff(th, td, pd, true)[0], t.values[Table::Index(c[0], c[1], c[2])], 1e-12);
  }
  // phi_d wraps: halfway between the centre of bin 179 and pi (= bin 0 by the fold).
  {
    double th, td, pd;
    Table::BinCentre(40, 30, 0, th, td, pd);
    EXPECT_NEAR(t.LookupHalfDiff(th, td, kPi * 179.5 / 180, true)[0],
                0.5 * (t.values[Table::Index(40, 30, 179)] + t.values[Table::Index(40, 30, 0)]), 1e-12);
  }
}

TEST_F(MerlFile, NegativeValuesAreMissing) {
  Table t = *table_;
  const std::size_t base = t.MissingCount();
  const int i = 30, j = 20, k = 40;
  const std::size_t idx = Table::Index(i, j, k);
  t.values[0 * Table::kCells + idx] = -1.0;
  t.values[2 * Table::kCells + idx] = -1e-3;
  const std::string path = (*dir_ / "holes.binary").string();
  t.Write(path);
  const Table back = Table::Read(path);
  EXPECT_EQ(back.MissingCount(), base + 2);
  EXPECT_LT(back.values[idx], 0);
  EXPECT_LT(back.values[2 * Table::kCells + idx], 0);

  // Nearest: a point inside the cell gives 0 for the missing channels.
  double th0, td0, pd0, th1, td1, pd1;
  Table::BinCentre(i, j, k, th0, td0, pd0);
  Table::BinCentre(i + 1, j + 1, k + 1, th1, td1, pd1);
  const double th = 0.5 * (th0 + th1), td = 0.5 * (td0 + td1), pd = 0.5 * (pd0 + pd1);
  const Rgb<double> fn = back.LookupHalfDiff(th, td, pd, false);
  EXPECT_EQ(fn[0], 0.0);
  EXPECT_EQ(fn[1], back.values[Table::kCells + idx]);
  EXPECT_EQ(fn[2], 0.0);

  // Trilinear at the middle of the cell box (sqrt-mapped theta_h): the eight
  // corners weigh 1/8 each; the missing one drops out and the rest renormalise.
  const double thm = std::pow((i + 0.5) / 90, 2) * kPi / 2;
  const Rgb<double> ft = back.LookupHalfDiff(thm, td, pd, true);
  for (int c = 0; c < 3; ++c) {
    double sum = 0;
    int count = 0;
    for (int a = 0; a < 2; ++a)
      for (int b = 0; b < 2; ++b)
        for (int e = 0; e < 2; ++e) {
          const double v = back.values[c * Table::kCells + Table::Index(i + a, j + b, k + e)];
          if (v >= 0) {
            sum += v;
            ++count;
          }
        }
    EXPECT_EQ(count, c == 1 ? 8 : 7);
    EXPECT_NEAR(ft[c], sum / count, 1e-12 * sum / count) << c;
  }

  // The model evaluates missing samples to 0.
  const Model m = Model::Parse("merl:" + path);
  const auto bxdf = m.Make<double>();
  Eigen::Vector3d wi, wo;
  Table::HalfDiffToDirections(th, td, pd, wi, wo);
  const Rgb<double> f = bxdf->Eval(nullptr, wi, wo);
  EXPECT_EQ(f[0], 0.0);
  EXPECT_GT(f[1], 0.0);
  EXPECT_EQ(f[2], 0.0);
}

TEST_F(MerlFile, BadFilesNameTheFile) {
  const std::string missing = (*dir_ / "no_such.binary").string();
  ExpectThrowNaming([&] { Table::Read(missing); }, missing, "no such file");
  ExpectThrowNaming([&] { Table::Read(dir_->string()); }, dir_->string(), "directory");

  const std::string tiny = (*dir_ / "tiny.binary").string();
  WriteFileAtomic(tiny, "abc");
  ExpectThrowNaming([&] { Table::Read(tiny); }, tiny, "truncated");

  // One working copy, damaged in turn.
  const std::string work = (*dir_ / "damaged.binary").string();
  fs::copy_file(*path_, work, fs::copy_options::overwrite_existing);
  auto patch = [&](std::size_t offset, const void* data, std::size_t n) {
    std::fstream f(work, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(std::streamoff(offset));
    f.write(static_cast<const char*>(data), std::streamsize(n));
  };
  const Table good = Table::Read(work);
  EXPECT_EQ(good.values, Table::Read(*path_).values);

  const unsigned char swapped_dims[12] = {180, 0, 0, 0, 90, 0, 0, 0, 90, 0, 0, 0};  // same size, other order
  patch(0, swapped_dims, 12);
  ExpectThrowNaming([&] { Table::Read(work); }, work, "180 x 90 x 90");
  const unsigned char full_phi[12] = {90, 0, 0, 0, 90, 0, 0, 0, 104, 1, 0, 0};  // 90 x 90 x 360
  patch(0, full_phi, 12);
  ExpectThrowNaming([&] { Table::Read(work); }, work, "90 x 90 x 360");
  const unsigned char ok_dims[12] = {90, 0, 0, 0, 90, 0, 0, 0, 180, 0, 0, 0};
  patch(0, ok_dims, 12);

  const std::size_t green_cell = 12 + 8 * (Table::kCells + Table::Index(5, 6, 7));
  for (double bad : {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity(),
                     -std::numeric_limits<double>::infinity()}) {
    patch(green_cell, &bad, 8);
    ExpectThrowNaming([&] { Table::Read(work); }, work, "non-finite");
    ExpectThrowNaming([&] { Table::Read(work); }, work, "green channel at theta_h bin 5, theta_d bin 6, phi_d bin 7");
  }
  const double fine = 1.0;
  patch(green_cell, &fine, 8);
  EXPECT_NO_THROW(Table::Read(work));

  fs::resize_file(work, Table::kFileSize - 8);
  ExpectThrowNaming([&] { Table::Read(work); }, work, "truncated: 34992004 bytes, expected 34992012");
  fs::resize_file(work, Table::kFileSize + 8);
  ExpectThrowNaming([&] { Table::Read(work); }, work, "over-long: 34992020 bytes, expected 34992012");
  fs::remove(work);
}

TEST_F(MerlFile, WriteIsAtomic) {
  const std::string target = (*dir_ / "atomic.binary").string();
  table_->Write(target);
  const auto before = fs::last_write_time(target);
  Table bad = *table_;
  bad.values[12345] = std::numeric_limits<double>::quiet_NaN();
  ExpectThrowNaming([&] { bad.Write(target); }, target, "non-finite");
  EXPECT_EQ(fs::file_size(target), Table::kFileSize);
  EXPECT_EQ(fs::last_write_time(target), before);
  EXPECT_EQ(Table::Read(target).values.size(), 3 * Table::kCells);

  Table small;
  small.values.resize(10);
  ExpectThrowNaming([&] { small.Write(target); }, target, "expected 4374000");

  const std::string nowhere = (*dir_ / "no_dir" / "x.binary").string();
  ExpectThrowNaming([&] { table_->Write(nowhere); }, nowhere, "cannot");
  EXPECT_FALSE(fs::exists(nowhere));
  for (const auto& e : fs::directory_iterator(*dir_))
    EXPECT_EQ(e.path().string().find(".tmp-"), std::string::npos) << "left behind: " << e.path();
}

TEST_F(MerlFile, ModelEvaluatesTheTable) {
  const Model nearest = Model::Parse("merl:" + *path_);
  const Model tri = Model::Parse("merl", {{"path", *path_}, {"interp", "trilinear"}});
  EXPECT_EQ(nearest.Info().name, "merl");
  EXPECT_EQ(nearest.Info().PackedSize(), 0u);
  EXPECT_TRUE(nearest.Info().reciprocal);
  EXPECT_FALSE(nearest.Info().energy_conserving);
  bool registered = false;
  for (const ModelInfo& i : RegisteredModelInfos()) registered = registered || i.name == "merl";
  EXPECT_TRUE(registered);

  using Jet = JetN<4>;
  const auto bn = nearest.Make<double>();
  const auto bt = tri.Make<double>();
  const auto bf = nearest.Make<float>();
  const auto bj = tri.Make<Jet>();
  const auto analytic = model_->Make<double>();
  const Table back = Table::Read(*path_);  // the model holds the file's values, not table_'s
  std::mt19937_64 rng(6);
  double rel_tri = 0;
  for (int n = 0; n < 2000; ++n) {
    const Eigen::Vector3d wi = RandomUpper(rng, 1.3), wo = RandomUpper(rng, 1.3);
    const Rgb<double> fn = bn->Eval(nullptr, wi, wo), ft = bt->Eval(nullptr, wi, wo);
    ASSERT_TRUE((fn == back.Lookup(wi, wo, false)).all());
    ASSERT_TRUE((ft == back.Lookup(wi, wo, true)).all());
    const Rgb<float> ff = bf->Eval(nullptr, wi.cast<float>(), wo.cast<float>());
    EXPECT_NEAR(ff[1], fn[1], 1e-5 * fn[1] + 1e-6);
    const Rgb<Jet> fj = bj->Eval(nullptr, wi.cast<Jet>(), wo.cast<Jet>());
    for (int c = 0; c < 3; ++c) {
      ASSERT_EQ(fj[c].a, ft[c]);
      ASSERT_TRUE((fj[c].v.array() == 0).all());
    }
    // Trilinear lookup of the table follows the analytic model away from
    // the GGX peak (alpha = 0.2), where the table resolves it.
    const Eigen::Vector3d h = (wi + wo).normalized();
    if (h.z() < std::cos(0.5)) {
      const Rgb<double> fa = analytic->Eval(params_->data(), wi, wo);
      rel_tri = std::max(rel_tri, ((ft - fa).abs() / fa).maxCoeff());
    }
  }
  EXPECT_LT(rel_tri, 0.01);

  // Cosine-weighted sampling and its pdf.
  const Eigen::Vector3d wo(0.3, 0.2, 0.9);
  const BsdfSample<double> s = bn->Sample(nullptr, wo.normalized(), 0.3, 0.7);
  ASSERT_TRUE(s.valid);
  EXPECT_NEAR(s.pdf, s.wi.z() / kPi, 1e-15);
  EXPECT_EQ(bn->Pdf(nullptr, wo.normalized(), Eigen::Vector3d(0, 0, -1)), 0.0);

  // Lobe weight: a rough albedo. Against the analytic model's mean albedo
  // at theta_o = 0, 30, 60 deg by a midpoint rule in (cos theta_i, phi_i).
  double albedo = 0;
  for (double theta_o : {0.0, kPi / 6, kPi / 3}) {
    const Eigen::Vector3d v(std::sin(theta_o), 0, std::cos(theta_o));
    const int nm = 300, np = 600;
    for (int a = 0; a < nm; ++a)
      for (int b = 0; b < np; ++b) {
        const double mu = (a + 0.5) / nm, phi = 2 * kPi * (b + 0.5) / np, st = std::sqrt(1 - mu * mu);
        const Eigen::Vector3d wi(st * std::cos(phi), st * std::sin(phi), mu);
        albedo += analytic->Eval(params_->data(), wi, v).mean() * mu * (2 * kPi / (nm * np)) / 3;
      }
  }
  EXPECT_NEAR(bn->SampleWeight(nullptr), albedo, 0.1 * albedo);
}

TEST(MerlModel, ClearErrors) {
  auto message = [](const std::function<void()>& f) -> std::string {
    try {
      f();
    } catch (const ModelError& e) {
      return e.what();
    }
    return "(no ModelError)";
  };
  EXPECT_NE(message([] { Model::Parse("merl"); }).find("needs path"), std::string::npos);
  EXPECT_NE(message([] { Model::Parse("merl", {{"interp", "nearest"}}); }).find("needs path"), std::string::npos);
  const std::string nowhere = (fs::temp_directory_path() / "brdfkit_no_such_merl_file.binary").string();
  EXPECT_NE(message([&] { Model::Parse("merl:" + nowhere); }).find(nowhere), std::string::npos);
  EXPECT_NE(message([&] { Model::Parse("merl", {{"path", nowhere}, {"interp", "cubic"}}); }).find("cubic"),
            std::string::npos);
  EXPECT_NE(message([&] { Model::Parse("merl", {{"path", nowhere}, {"filter", "x"}}); }).find("filter"),
            std::string::npos);
}

}  // namespace
}  // namespace brdfkit
