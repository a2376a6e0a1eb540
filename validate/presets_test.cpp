#include "validate/presets.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <tuple>

#include "brdf/microfacet.h"
#include "brdf/model.h"
#include "validate/albedo.h"
#include "tests/test_util.h"
#include "tests/scratch.h"

namespace brdfkit::validate {
namespace {

using test::GgxAlbedoAlpha1;

const PresetTable& Find(const Preset& p, const std::string& name) {
  for (const PresetTable& t : p.tables)
    if (t.name == name) return t;
  throw std::runtime_error("no table " + name);
}

// Cycles' shipped entries (src/scene/shader.tables, byte-identical since
// 2023): Monte Carlo with N samples of weights in [0, 1], printed to 6
// decimals; a standard error of at most 0.5 / sqrt(N), so 4 of them plus the
// rounding bound the difference to the exact value.
double ShippedBound(double samples) { return 4 * 0.5 / std::sqrt(samples) + 5e-7; }

struct Shipped {
  std::string table;
  std::size_t index;
  double value, samples;
};

TEST(CyclesPreset, GgxTablesHoldTheClosedFormsAndAgreeWithTheShippedOnes) {
  PresetOptions o;
  o.tables = {"table_ggx_E", "table_ggx_Eavg"};
  const Preset p = BuildPreset("cycles", o);
  ASSERT_EQ(p.tables.size(), 2u);
  const PresetTable& e = Find(p, "table_ggx_E");
  const PresetTable& avg = Find(p, "table_ggx_Eavg");
  ASSERT_EQ(e.value.size(), 1024u);
  ASSERT_EQ(avg.value.size(), 32u);
  EXPECT_LE(p.max_error, 1e-7);
  for (std::size_t y = 0; y < 32; ++y) {
    // Roughness 0 (x = 0): a mirror with F = 1 reflects everything.
    EXPECT_EQ(e.value[y * 32], 1.0);
    // Roughness 1 (x = 31, alpha = 1), at the mu Cycles evaluates (>= 1e-4).
    const double mu = std::max(1e-4, y / 31.0);
    EXPECT_NEAR(e.value[y * 32 + 31], GgxAlbedoAlpha1(mu), e.error[y * 32 + 31] + 1e-13) << "y " << y;
  }
  // E_avg at alpha = 1: 1 - 2 int_0^1 mu^2 ln(1 + 1/mu) dmu, by parts
  // ln(2) / 3 + (1/3) int_0^1 mu^2 / (1 + mu) dmu = (2 ln 2 - 1/2) / 3, so
  // E_avg = 4 (1 - ln 2) / 3.
  EXPECT_NEAR(avg.value[31], 4 * (1 - std::log(2.0)) / 3, avg.error[31] + 1e-13);
  EXPECT_EQ(avg.value[0], 1.0);
  const std::vector<Shipped> shipped = {
      {"table_ggx_E", 16 * 32 + 16, 0.847421, 1 << 23}, {"table_ggx_E", 4 * 32 + 8, 0.907414, 1 << 23},
      {"table_ggx_E", 0 * 32 + 1, 0.980405, 1 << 23},   {"table_ggx_E", 1 * 32 + 3, 0.954714, 1 << 23},
      {"table_ggx_E", 31 * 32 + 31, 0.306853, 1 << 23}, {"table_ggx_Eavg", 16, 0.870874, 1 << 26},
      {"table_ggx_Eavg", 31, 0.409137, 1 << 26},        {"table_ggx_Eavg", 4, 0.998729, 1 << 26}};
  for (const Shipped& s : shipped)
    EXPECT_NEAR(Find(p, s.table).value[s.index], s.value, ShippedBound(s.samples)) << s.table << "[" << s.index << "]";
}

TEST(CyclesPreset, GlassTableHoldsTheLimitsAndAgreesWithTheShippedOne) {
  PresetOptions o;
  o.tables = {"table_ggx_glass_E"};
  const Preset p = BuildPreset("cycles", o);
  const PresetTable& t = p.tables.at(0);
  ASSERT_EQ(t.value.size(), 4096u);
  EXPECT_LE(p.max_error, 1e-7);
  for (std::size_t k = 0; k < 16 * 16; ++k) {
    EXPECT_EQ(t.value[k], 1.0) << "z = 0 (matched index) entry " << k;
    EXPECT_EQ(t.value[k * 16], 1.0) << "roughness 0 (smooth glass: F + 1 - F) entry " << k * 16;
  }
  for (double v : t.value) EXPECT_LE(v, 1 + 1e-7);  // the power scattered by a passive interface
  // Index (z 16 + y) 16 + x.
  const std::vector<Shipped> shipped = {{"", (4 * 16 + 8) * 16 + 8, 0.960250, 1 << 23},
                                        {"", (8 * 16 + 10) * 16 + 5, 0.994643, 1 << 23},
                                        {"", (1 * 16 + 1) * 16 + 7, 0.732387, 1 << 23},
                                        {"", (8 * 16 + 8) * 16 + 7, 0.969068, 1 << 23}};
  for (const Shipped& s : shipped) EXPECT_NEAR(t.value[s.index], s.value, ShippedBound(s.samples)) << s.index;
  // Seen from inside (Cycles' table_ggx_glass_inv_E (8, 8, 4)), through the
  // same model: eta = 1 / ior(z = 4/15).
  const Model m = Model::Parse("ggx_glass_correlated");
  const auto b = m.Make<double>();
  const double z = 4 / 15.0, ior = (1 + z * z) / (1 - z * z), r = 8 / 15.0;
  const std::vector<double> params = {r * r, 1 / ior};
  LobeShape shape;
  shape.width = r * r;
  AlbedoQuadratureOptions q;
  q.abs_tolerance = 1e-7;
  const AlbedoValue inv = AlbedoAtMu(*b, params.data(), 8 / 15.0, shape, q);
  EXPECT_NEAR(inv.value[0], 0.813348, ShippedBound(1 << 23));
}

TEST(CyclesPreset, GeneralisedSchlickTablesHoldTheLimitsAndAgreeWithTheShippedOnes) {
  PresetOptions o;
  o.tables = {"table_ggx_gen_schlick_ior_s", "table_ggx_gen_schlick_s"};
  const Preset p = BuildPreset("cycles", o);
  const PresetTable& ior_s = Find(p, "table_ggx_gen_schlick_ior_s");
  const PresetTable& s = Find(p, "table_ggx_gen_schlick_s");
  EXPECT_LE(p.max_error, 1e-7);
  for (std::size_t z = 0; z < 16; ++z)
    for (std::size_t y = 0; y < 16; ++y) {
      const double mu = std::max(1e-4, y / 15.0), zz = std::clamp(z / 15.0, 1e-4, 0.99);
      // Roughness 0: every visible normal is n, so s_bar = s(mu).
      EXPECT_DOUBLE_EQ(s.value[(z * 16 + y) * 16], std::pow(1 - mu, 5 * (1 - zz) / zz));
      const double ior = (1 + zz * zz) / (1 - zz * zz), f0 = std::pow((ior - 1) / (ior + 1), 2);
      if (z > 0) {
        // Clamped to [0, 1] as Cycles' saturate: past ior ~ 2 the Brewster dip takes F below F0.
        EXPECT_NEAR(ior_s.value[(z * 16 + y) * 16], std::clamp((FresnelDielectric(ior, mu) - f0) / (1 - f0), 0.0, 1.0),
                    1e-15);
      } else {
        EXPECT_EQ(ior_s.value[y * 16], 0.0);  // matched index: F = F0 = 0
      }
    }
  const std::vector<Shipped> shipped = {{"table_ggx_gen_schlick_ior_s", (4 * 16 + 8) * 16 + 8, 0.013158, 1 << 20},
                                        {"table_ggx_gen_schlick_ior_s", (1 * 16 + 1) * 16 + 1, 0.142998, 1 << 20},
                                        {"table_ggx_gen_schlick_ior_s", (8 * 16 + 10) * 16 + 5, 0.019858, 1 << 20},
                                        {"table_ggx_gen_schlick_s", (8 * 16 + 10) * 16 + 5, 0.011236, 1 << 20},
                                        {"table_ggx_gen_schlick_s", 4095, 0.445448, 1 << 20},
                                        {"table_ggx_gen_schlick_s", (8 * 16 + 8) * 16 + 4, 0.037694, 1 << 20}};
  for (const Shipped& e : shipped)
    EXPECT_NEAR(Find(p, e.table).value[e.index], e.value, ShippedBound(e.samples)) << e.table << "[" << e.index << "]";
}

// The error estimates are never below the true error: the entries against
// the same tables at a tolerance a hundred or a thousand times tighter.
TEST(Presets, ErrorEstimatesBoundTheDifferenceToATighterTable) {
  for (const std::string name : {"filament", "cycles", "kulla_conty"}) {
    PresetOptions loose, tight;
    loose.size = tight.size = name == "filament" ? 8 : name == "kulla_conty" ? 3 : 0;
    if (name == "cycles") loose.tables = tight.tables = {"table_ggx_E", "table_ggx_gen_schlick_s"};
    if (name == "kulla_conty") loose.tables = tight.tables = {"kc_x", "kc_inv_Favg"};
    if (name == "kulla_conty") loose.abs_tolerance = 1e-6;
    tight.abs_tolerance = name == "kulla_conty" ? 1e-8 : 1e-10;
    const Preset a = BuildPreset(name, loose), b = BuildPreset(name, tight);
    ASSERT_EQ(a.tables.size(), b.tables.size());
    EXPECT_LE(b.max_error, tight.abs_tolerance);
    for (std::size_t t = 0; t < a.tables.size(); ++t)
      for (std::size_t k = 0; k < a.tables[t].value.size(); ++k)
        EXPECT_LE(std::abs(a.tables[t].value[k] - b.tables[t].value[k]), a.tables[t].error[k] + b.tables[t].error[k])
            << name << " " << a.tables[t].name << "[" << k << "]";
  }
}

// Filament's DFG channels against independent midpoint sums over the half
// vector h = (theta, phi): l = 2 (v.h) h - v, dl = 4 (v.h) dh.
TEST(FilamentPreset, ChannelsAreTheSplitSumAndClothIntegrals) {
  PresetOptions o;
  o.size = 8;
  const Preset p = BuildPreset("filament", o);
  ASSERT_EQ(p.tables.size(), 1u);
  const PresetTable& t = p.tables[0];
  ASSERT_EQ(t.value.size(), 8u * 8u * 3u);
  EXPECT_LE(p.max_error, 1e-7);
  // Row 7: roughness min(1, 8.5 / 8) = 1, G = E of GGX alpha = 1.
  for (int i = 0; i < 8; ++i) EXPECT_NEAR(t.value[3 * (7 * 8 + i) + 1], GgxAlbedoAlpha1((i + 0.5) / 8), 1e-7);
  for (const auto& [i, j] : std::vector<std::pair<int, int>>{{1, 3}, {5, 2}, {2, 6}}) {
    const double nov = (i + 0.5) / 8, r = (j + 1.5) / 8, a = r * r, a2 = a * a;
    const Eigen::Vector3d v(std::sqrt(1 - nov * nov), 0, nov);
    double sr = 0, sg = 0, sb = 0;
    const int n = 1500;
    for (int u = 0; u < n; ++u) {
      const double th = 0.5 * kPi * (u + 0.5) / n;
      for (int w = 0; w < 2 * n; ++w) {
        const double ph = kPi * (w + 0.5) / (2 * n);
        const Eigen::Vector3d h(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th));
        const double voh = v.dot(h);
        if (voh <= 0) continue;
        const Eigen::Vector3d l = 2 * voh * h - v;
        if (l.z() <= 0) continue;
        const double noh = h.z(), nol = l.z();
        const double dg = a2 / (kPi * std::pow(noh * noh * (a2 - 1) + 1, 2));
        const double vis = 0.5 / (nol * std::sqrt(nov * nov * (1 - a2) + a2) + nov * std::sqrt(nol * nol * (1 - a2) + a2));
        const double dc = (2 + 1 / a) * std::pow(1 - noh * noh, 0.5 / a) / (2 * kPi);
        const double vn = 1 / (4 * (nol + nov - nol * nov));
        const double jac = 4 * voh * std::sin(th) * (0.5 * kPi / n) * (kPi / (2 * n)) * 2;  // both halves of phi
        sg += dg * vis * nol * jac;
        sr += dg * vis * nol * std::pow(1 - voh, 5) * jac;
        sb += dc * vn * nol * jac;
      }
    }
    const std::size_t at = 3 * (std::size_t(j) * 8 + i);
    EXPECT_NEAR(t.value[at], sr, 2e-5) << "R at " << i << ", " << j;
    EXPECT_NEAR(t.value[at + 1], sg, 2e-5) << "G at " << i << ", " << j;
    EXPECT_NEAR(t.value[at + 2], sb, 2e-5) << "B at " << i << ", " << j;
  }
}

TEST(FilamentPreset, IncFileIsCmgensLayoutOfHalfFloats) {
  PresetOptions o;
  o.size = 8;
  const Preset p = BuildPreset("filament", o);
  const std::filesystem::path dir = test::FreshDir("presets");
  const std::string path = (dir / "dfg.inc").string();
  WritePresetHeader(p, path);
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line.rfind("// generated with: ", 0), 0u);
  std::getline(in, line);
  EXPECT_EQ(line, "// DFG LUT stored as an RGB16F texture, in GL order");
  std::getline(in, line);
  EXPECT_EQ(line, "");
  std::vector<unsigned> halves;
  while (std::getline(in, line)) {
    EXPECT_EQ(line.rfind("    0x", 0), 0u) << line;
    std::istringstream s(line);
    std::string item;
    int count = 0;
    while (s >> item) {
      ASSERT_EQ(item.size(), 7u) << item;  // 0x%04x,
      halves.push_back(std::stoul(item.substr(2, 4), nullptr, 16));
      ++count;
    }
    EXPECT_EQ(count, 12);  // four texels a line
  }
  ASSERT_EQ(halves.size(), p.tables[0].value.size());
  for (std::size_t k = 0; k < halves.size(); ++k) EXPECT_EQ(halves[k], HalfBits(p.tables[0].value[k]));
  std::filesystem::remove_all(dir);
}

// The classical closed form of the cosine-weighted hemispherical average of
// the unpolarised dielectric Fresnel reflectance, light arriving from the
// rarer side (relative index n > 1).
double FresnelAverageClosedForm(long double n) {
  const long double n2 = n * n, n4 = n2 * n2;
  return double(0.5L + (n - 1) * (3 * n + 1) / (6 * (n + 1) * (n + 1)) +
                n2 * (n2 - 1) * (n2 - 1) / ((n2 + 1) * (n2 + 1) * (n2 + 1)) * std::log((n - 1) / (n + 1)) -
                2 * n2 * n * (n2 + 2 * n - 1) / ((n2 + 1) * (n4 - 1)) +
                8 * n4 * (n4 + 1) / ((n2 + 1) * (n4 - 1) * (n4 - 1)) * std::log(n));
}

TEST(KullaContyPreset, FresnelAveragesAreTheClosedFormAndTheInsideIntegral) {
  PresetOptions o;
  o.size = 6;
  o.tables = {"kc_Favg", "kc_inv_Favg"};
  const Preset p = BuildPreset("kulla_conty", o);
  const PresetTable& out = Find(p, "kc_Favg");
  const PresetTable& in = Find(p, "kc_inv_Favg");
  ASSERT_EQ(out.value.size(), 6u);
  EXPECT_EQ(out.value[0], 0.0);  // z = 0: a matched index reflects nothing
  EXPECT_EQ(in.value[0], 0.0);
  for (std::size_t z = 1; z < 6; ++z) {
    const double zz = std::min(0.99, z / 5.0), ior = (1 + zz * zz) / (1 - zz * zz);
    EXPECT_NEAR(out.value[z], FresnelAverageClosedForm(ior), 1e-11 + out.error[z]) << "ior " << ior;
    // From inside, 2 int F(mu, 1 / ior) mu dmu: F = 1 below the critical
    // cosine mu_c; above it, mu = mu_c + s^2 makes the integrand smooth in s.
    const double eta = 1 / ior, mu_c = std::sqrt(1 - eta * eta), s1 = std::sqrt(1 - mu_c);
    double sum = mu_c * mu_c;
    const int n = 200000;
    for (int k = 0; k < n; ++k) {
      const double s = s1 * (k + 0.5) / n, mu = mu_c + s * s;
      sum += 2 * mu * FresnelDielectric(eta, mu) * 2 * s * s1 / n;
    }
    EXPECT_NEAR(in.value[z], sum, 1e-9 + in.error[z]) << "ior " << ior;
  }
  // Glass, ior 1.5: 0.0918 outside, 0.596 inside (the classic values).
  EXPECT_NEAR(FresnelAverageClosedForm(1.5), 0.09178, 1e-5);
}

// x = t / (1 + t) with t = eta^2 (1 - F_avg(1/eta)) (1 - E_avg(1/eta)) /
// ((1 - F_avg(eta)) (1 - E_avg(eta))); the smooth interface's reciprocity
// eta^2 (1 - F_avg(1/eta)) = 1 - F_avg(eta) reduces t to the ratio of the
// losses of the two sides, computed here from the glass averages.
TEST(KullaContyPreset, TransmittedShareIsTheRatioOfTheLossesOfBothSides) {
  PresetOptions o;
  o.size = 3;
  const Preset p = BuildPreset("kulla_conty", o);
  EXPECT_LE(p.max_error, 1e-7);
  const PresetTable& x = Find(p, "kc_x");
  EXPECT_TRUE(x.derived);
  EXPECT_EQ(DescribePresetMisses(p, 1e-7), "") << "x is not held to the tolerance";
  const PresetTable& out = Find(p, "kc_glass_Eavg");
  const PresetTable& in = Find(p, "kc_glass_inv_Eavg");
  ASSERT_EQ(x.value.size(), 9u);
  for (std::size_t z = 0; z < 3; ++z) {
    EXPECT_EQ(x.value[z * 3], x.value[z * 3 + 1]) << "roughness 0 repeats the next node";
    for (std::size_t r = 0; r < 3; ++r) {
      const std::size_t k = z * 3 + r;
      if (z == 0) {
        EXPECT_EQ(x.value[k], 0.5);  // matched index: both sides alike
        EXPECT_EQ(out.value[k], 1.0);
        continue;
      }
      if (r == 0) continue;
      const double lo = 1 - out.value[k], li = 1 - in.value[k];
      EXPECT_GT(lo, 0.01);
      EXPECT_NEAR(x.value[k], li / (li + lo), x.error[k] + 1e-12) << "node " << k;
      // The averages' errors (up to 1e-7) carried through the ratio of the losses.
      EXPECT_GT(x.error[k], 0.0);
      EXPECT_LE(x.error[k], 1.1e-7 * x.value[k] * (1 - x.value[k]) * (1 / li + 1 / lo) + 1e-14) << "node " << k;
      EXPECT_GT(x.value[k], 0.5) << "the denser side loses more: it has total internal reflection";
    }
  }
}

TEST(Presets, HalfBitsRoundToNearestEven) {
  EXPECT_EQ(HalfBits(1.0), 0x3c00);
  EXPECT_EQ(HalfBits(0.5), 0x3800);
  EXPECT_EQ(HalfBits(0.0), 0x0000);
  EXPECT_EQ(HalfBits(65504.0), 0x7bff);
  EXPECT_EQ(HalfBits(1.0 / 3.0), 0x3555);
  EXPECT_EQ(HalfBits(1 + std::ldexp(1.0, -11)), 0x3c00);      // a tie: to the even neighbour
  EXPECT_EQ(HalfBits(1 + 3 * std::ldexp(1.0, -11)), 0x3c02);  // a tie: to the even neighbour
  EXPECT_EQ(HalfBits(std::ldexp(1.0, -24)), 0x0001);           // the smallest subnormal
}

TEST(Presets, UnknownNamesAreRefusedWithTheChoices) {
  try {
    BuildPreset("unreal");
    FAIL();
  } catch (const ModelError& e) {
    EXPECT_NE(std::string(e.what()).find("cycles, filament"), std::string::npos) << e.what();
  }
  PresetOptions o;
  o.tables = {"table_ggx_F"};
  try {
    BuildPreset("cycles", o);
    FAIL();
  } catch (const ModelError& e) {
    EXPECT_NE(std::string(e.what()).find("table_ggx_F"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("table_ggx_glass_inv_Eavg"), std::string::npos) << e.what();
  }
  EXPECT_EQ(PresetSize("kulla_conty", 0), 16);
  EXPECT_EQ(PresetSize("filament", 0), 128);
  EXPECT_EQ(PresetSize("filament", 64), 64);
  for (const auto& [name, size, says] : std::vector<std::tuple<std::string, int, std::string>>{
           {"kulla_conty", 2, "size 2 is outside [3, 256]"},
           {"filament", 5000, "size 5000 is outside [2, 4096]"},
           {"cycles", 16, "fixed sizes"}}) {
    try {
      PresetSize(name, size);
      ADD_FAILURE() << name << " took size " << size;
    } catch (const ModelError& e) {
      EXPECT_NE(std::string(e.what()).find(says), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace brdfkit::validate
