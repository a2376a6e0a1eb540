#include "validate/integrators.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "brdf/model.h"
#include "brdf/params.h"
#include "validate/plot.h"
#include "validate/references.h"
#include "validate/sobol.h"
#include "tests/scratch.h"

namespace brdfkit::validate {
namespace {

Eigen::Vector3d View(double mu) { return Eigen::Vector3d(std::sqrt(std::max(0.0, 1.0 - mu * mu)), 0.0, mu); }

// --- power scattered over the sphere ----------------------------------------

// Nearly smooth glass (alpha = 0.01): light along w is reflected in the
// Fresnel fraction and refracted in the rest, from outside and from inside
// (all reflected past the critical angle, 0.7297 rad for eta = 1.5; nearer
// to it the roughness averages F over a steep slope and the split departs
// from the smooth one: 0.1194 against 0.1141 at mu = -0.8). Either part
// computed alone is the same as in the pair.
TEST(ScatteredPower, NearlySmoothGlassSplitsByFresnel) {
  const Model m = Model::Parse("ggx_glass");
  const std::vector<double> p = ParseParams(m.Info(), "alpha=0.01,eta=1.5");
  const auto b = m.Make<double>();
  IntegrateOptions o;
  o.budget = 400000;
  o.abs_tolerance = 1e-8;
  for (double mu : {1.0, 0.8, 0.3, -1.0, -0.95, -0.6}) {
    SCOPED_TRACE("mu " + std::to_string(mu));
    const ScatteredEstimate e = ScatteredPower(*b, p.data(), View(mu), o);
    const double f = FresnelDielectric(mu > 0 ? 1.5 : 1 / 1.5, std::abs(mu));
    EXPECT_NEAR(e.reflected.value[0], f, 1e-3 + e.reflected.error[0]);
    EXPECT_NEAR(e.transmitted.value[0], 1 - f, 1e-3 + e.transmitted.error[0]);
    EXPECT_LE(e.Total().value[0], 1.0 + e.Total().error[0]);
    EXPECT_GT(e.Total().value[0], 0.999);  // the Smith terms lose little at alpha = 0.01
    // Either part alone is the same estimate, the other one zero.
    const ScatteredEstimate r = ScatteredPower(*b, p.data(), View(mu), o, ScatteredParts::kReflected);
    const ScatteredEstimate t = ScatteredPower(*b, p.data(), View(mu), o, ScatteredParts::kTransmitted);
    EXPECT_EQ(r.reflected.value[0], e.reflected.value[0]);
    EXPECT_EQ(r.reflected.error[0], e.reflected.error[0]);
    EXPECT_EQ(r.transmitted.evals, 0);
    EXPECT_EQ(t.transmitted.value[0], e.transmitted.value[0]);
    EXPECT_EQ(t.transmitted.error[0], e.transmitted.error[0]);
    EXPECT_EQ(t.reflected.evals, 0);
  }
}

// The refracted power over the microfacet normal agrees with 2^20 Sobol'
// points over the other side (the generic rule's reference) within the
// Monte Carlo error and its own estimate, for rough and narrow glass, both
// sides of the interface, normal and grazing light, in a fraction of the
// evaluations; and the evaluations stay within the budget.
TEST(ScatteredPower, RefractedPowerOverTheNormalAgreesWithSobol) {
  const Model m = Model::Parse("ggx_glass");
  const auto b = m.Make<double>();
  IntegrateOptions o;
  o.abs_tolerance = 1e-7;
  o.budget = 1000000;  // the albedo tables' budget
  IntegrateOptions mc;
  mc.budget = 1 << 20;
  for (const char* params : {"alpha=0.3,eta=1.5", "alpha=0.05,eta=1.33", "alpha=0.5,eta=2.4"})
    for (double mu : {0.95, 0.5, 0.1, -0.9, -0.5}) {
      SCOPED_TRACE(std::string(params) + " mu " + std::to_string(mu));
      const std::vector<double> p = ParseParams(m.Info(), params);
      const Eigen::Vector3d w = View(mu);
      const ScatteredEstimate e = ScatteredPower(*b, p.data(), w, o);
      const auto other = [&](const Eigen::Vector3d& u) { return Eigen::Vector3d(u.x(), u.y(), mu < 0 ? u.z() : -u.z()); };
      // Sobol' points drawn about the smooth refraction direction.
      const double k = b->RelativeIndex(p.data(), w, other(Eigen::Vector3d::UnitZ()));
      const double s2 = k * k * (1 - mu * mu);
      const Eigen::Vector3d peak = s2 < 1 ? Eigen::Vector3d(-k * w.x(), -k * w.y(), std::sqrt(1 - s2))
                                          : Eigen::Vector3d::UnitZ();
      const Estimate ref = IntegrateHemisphere(
          [&](const Eigen::Vector3d& u) -> Eigen::Array3d { return b->Eval(p.data(), w, other(u)) * u.z(); },
          Method::kSobol, mc, peak, p[0]);
      EXPECT_NEAR(e.transmitted.value[0], ref.value[0], 4 * ref.error[0] + e.transmitted.error[0] + 1e-7);
      EXPECT_LE(e.transmitted.error[0], 1e-6);
      EXPECT_LE(e.transmitted.evals, o.budget);
      EXPECT_LE(e.Total().value[0], 1.0 + e.Total().error[0]);
    }
}

// A reflection model: the reflected power is E(w) (it is reciprocal), the
// transmitted power 0, and nothing comes from below.
TEST(ScatteredPower, ReflectionModelGivesItsAlbedo) {
  const Model m = Model::Parse("ggx");
  const std::vector<double> p = ParseParams(m.Info(), "alpha=0.4");
  const auto b = m.Make<double>();
  const IntegrateOptions o;
  for (double mu : {1.0, 0.5, 0.1}) {
    const ScatteredEstimate e = ScatteredPower(*b, p.data(), View(mu), o);
    const Estimate d = DirectionalAlbedo(*b, p.data(), View(mu), Method::kAdaptive, o);
    EXPECT_NEAR(e.reflected.value[0], d.value[0], 1e-12) << mu;
    EXPECT_EQ(e.transmitted.value[0], 0.0);
    EXPECT_EQ(ScatteredPower(*b, p.data(), View(-mu), o).Total().value[0], 0.0);
  }
  EXPECT_THROW(ScatteredPower(*b, p.data(), Eigen::Vector3d::Zero(), o), std::invalid_argument);
}

// --- Sobol' points ------------------------------------------------------------

TEST(Sobol, FirstPointsMatchTheSequence) {
  // Natural (non-Gray) order: dimension 1 is van der Corput, dimension 2 has
  // direction numbers 1/2, 3/4, 5/8 (Joe & Kuo m = 1, 3, 5).
  const Sobol2D s;
  const double kExpected[5][2] = {{0, 0}, {0.5, 0.5}, {0.25, 0.75}, {0.75, 0.25}, {0.125, 0.625}};
  for (std::uint32_t i = 0; i < 5; ++i) {
    const auto r = s.Raw(i);
    EXPECT_EQ(r[0] / 4294967296.0, kExpected[i][0]) << i;
    EXPECT_EQ(r[1] / 4294967296.0, kExpected[i][1]) << i;
  }
}

// Every elementary interval [a 2^-k, (a+1) 2^-k) x [b 2^-(m-k), ...) holds
// exactly one of the first 2^m points: the (0, m, 2)-net property, which
// Owen scrambling preserves.
void ExpectNet(const std::vector<std::array<double, 2>>& pts, int m) {
  const std::size_t n = std::size_t(1) << m;
  for (int k = 0; k <= m; ++k) {
    std::vector<int> count(n, 0);
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t a = std::size_t(pts[i][0] * double(std::size_t(1) << k));
      const std::size_t b = std::size_t(pts[i][1] * double(std::size_t(1) << (m - k)));
      ++count[(a << (m - k)) | b];
    }
    for (std::size_t c = 0; c < n; ++c) ASSERT_EQ(count[c], 1) << "m=" << m << " k=" << k << " cell " << c;
  }
}

TEST(Sobol, UnscrambledAndScrambledPointsAreNets) {
  const Sobol2D s;
  for (int m : {4, 8, 10}) {
    std::vector<std::array<double, 2>> raw, scrambled;
    for (std::uint32_t i = 0; i < (1u << m); ++i) {
      const auto r = s.Raw(i);
      raw.push_back({r[0] / 4294967296.0, r[1] / 4294967296.0});
      scrambled.push_back(s.Point(i, 12345));
    }
    ExpectNet(raw, m);
    ExpectNet(scrambled, m);
  }
}

TEST(Sobol, ScramblingRandomisesEachPoint) {
  // Over many seeds a scrambled point is uniform: mean 1/2, variance 1/12.
  const Sobol2D s;
  double sum = 0, sum2 = 0;
  const int seeds = 20000;
  for (int seed = 0; seed < seeds; ++seed) {
    const double u = s.Point(3, std::uint64_t(seed))[1];
    ASSERT_GT(u, 0.0);
    ASSERT_LT(u, 1.0);
    sum += u;
    sum2 += u * u;
  }
  const double mean = sum / seeds, var = sum2 / seeds - mean * mean;
  EXPECT_NEAR(mean, 0.5, 5 * std::sqrt(1.0 / 12 / seeds));
  EXPECT_NEAR(var, 1.0 / 12, 0.004);
}

// --- API ----------------------------------------------------------------------

TEST(Integrators, MethodNamesRoundTrip) {
  std::set<std::string> names;
  for (Method m : AllMethods()) {
    EXPECT_EQ(ParseMethod(MethodName(m)), m);
    names.insert(MethodName(m));
  }
  EXPECT_EQ(names.size(), 6u);
  try {
    ParseMethod("simpson");
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("'simpson'"), std::string::npos) << e.what();
  }
}

TEST(Integrators, RejectsBadBudgetAndDirection) {
  const Model m = Model::Parse("lambert");
  const auto b = m.Make<double>();
  const std::vector<double> p = m.Info().Defaults();
  IntegrateOptions o;
  o.budget = 0;
  EXPECT_THROW(DirectionalAlbedo(*b, p.data(), View(0.5), Method::kCosine, o), std::invalid_argument);
  EXPECT_THROW(DirectionalAlbedo(*b, p.data(), Eigen::Vector3d::Zero(), Method::kCosine), std::invalid_argument);
  // Below the horizon f = 0, so E = 0 exactly.
  const Estimate e = DirectionalAlbedo(*b, p.data(), Eigen::Vector3d(0.6, 0, -0.8), Method::kAdaptive);
  EXPECT_EQ(e.value.maxCoeff(), 0.0);
}

TEST(Integrators, MonteCarloIsDeterministicPerSeed) {
  const Model m = Model::Parse("ggx");
  const auto b = m.Make<double>();
  const std::vector<double> p = ParseParams(m.Info(), "alpha=0.3");
  for (Method method : {Method::kUniform, Method::kImportance, Method::kSobol}) {
    IntegrateOptions o;
    o.budget = 5000;
    const Estimate a = DirectionalAlbedo(*b, p.data(), View(0.4), method, o);
    const Estimate c = DirectionalAlbedo(*b, p.data(), View(0.4), method, o);
    o.seed = 2;
    const Estimate d = DirectionalAlbedo(*b, p.data(), View(0.4), method, o);
    EXPECT_EQ(a.value[0], c.value[0]) << MethodName(method);
    EXPECT_NE(a.value[0], d.value[0]) << MethodName(method);
  }
}

TEST(Integrators, AdaptiveRespectsTheBudget) {
  const Model m = Model::Parse("beckmann");
  const auto b = m.Make<double>();
  const std::vector<double> p = ParseParams(m.Info(), "alpha=0.05");
  IntegrateOptions o;
  o.budget = 5000;
  o.rel_tolerance = 1e-15;
  o.abs_tolerance = 0;
  const Estimate e = DirectionalAlbedo(*b, p.data(), View(0.3), Method::kAdaptive, o);
  EXPECT_LE(e.evals, o.budget);
  EXPECT_GT(e.evals, 0);
}

// The width the adaptive rule stretches its chart by is the models' own
// declaration (Bxdf::Width), the narrowest lobe of a sum.
TEST(Integrators, LobeWidthIsTheModelsDeclaration) {
  {
    const Model m = Model::Parse("ggx_aniso");
    const std::vector<double> p = ParseParams(m.Info(), "alpha_x=0.2,alpha_y=0.01");
    EXPECT_DOUBLE_EQ(m.Make<double>()->Width(p.data()).Min(), 0.01);
  }
  {
    const Model m = Model::Parse("lambert+ggx");
    const std::vector<double> p = ParseParams(m.Info(), "ggx.alpha=0.07");
    EXPECT_DOUBLE_EQ(m.Make<double>()->Width(p.data()).Min(), 0.07);
  }
  {
    const Model m = Model::Parse("phong");
    const std::vector<double> p = ParseParams(m.Info(), "n=198");
    EXPECT_DOUBLE_EQ(m.Make<double>()->Width(p.data()).Min(), 0.1);  // sqrt(2 / (n + 2))
  }
  {
    const Model m = Model::Parse("lambert");
    EXPECT_EQ(m.Make<double>()->Width(m.Info().Defaults().data()).Min(), 0.0);
  }
}

// --- every integrator on every reference integral --------------------------------

struct Expectation {
  std::int64_t budget;
  double bound;  // true error bound on cases the method is meant for
};

// Budgets and bounds: Monte Carlo at 2^15 samples errs by a few 1/sqrt(N)
// standard deviations; Gauss-Legendre with ~2e4 nodes and the adaptive rule
// converge on smooth or lobe-adapted integrands.
Expectation For(Method m) {
  switch (m) {
    case Method::kUniform: return {1 << 15, 0.05};
    case Method::kCosine: return {1 << 15, 0.05};
    case Method::kImportance: return {1 << 15, 0.02};
    case Method::kSobol: return {1 << 15, 0.01};
    case Method::kGaussLegendre: return {20000, 5e-3};
    case Method::kAdaptive: return {200000, 1e-7};
  }
  return {0, 0};
}

// Whether a method is expected to be accurate on a case at its test budget:
// the adaptive rule everywhere; importance sampling and QMC everywhere but the
// narrow generic lobes they sample only through a heavy-tailed lobe; uniform,
// cosine and Gauss-Legendre only on wide, non-grazing integrands.
bool Accurate(Method m, const ReferenceCase& c) {
  if (m == Method::kAdaptive) return true;
  if (m == Method::kImportance || m == Method::kSobol) return true;
  if (c.stiff) return false;
  const bool narrow = c.name.find("alpha0.01") != std::string::npos || c.name.find("n10000") != std::string::npos ||
                      c.name.find("alpha0.1_") != std::string::npos || c.group.find("aniso") != std::string::npos ||
                      c.group == "phong_original" || c.group == "cosine_power";
  return !narrow;
}

class ReferenceTest : public ::testing::TestWithParam<Method> {};

TEST_P(ReferenceTest, AccurateWhereExpectedAndAlwaysHonest) {
  const Method method = GetParam();
  const Expectation x = For(method);
  IntegrateOptions o;
  o.budget = x.budget;
  o.rel_tolerance = 1e-9;
  o.abs_tolerance = 1e-12;
  int checked = 0;
  for (const ReferenceCase& c : ReferenceCases()) {
    const Estimate e = c.integrate(method, o);
    const double err = TrueError(c, e), est = EstimatedError(e);
    // The error estimate never understates the true error by more than 10x.
    EXPECT_GE(est, err / 10) << MethodName(method) << " on " << c.name << ": estimate " << e.value[0] << " +- "
                             << est << ", exact " << c.exact[0];
    if (Accurate(method, c)) {
      const double bound = x.bound * std::max(1.0, c.exact.abs().maxCoeff());
      EXPECT_LE(err, bound) << MethodName(method) << " on " << c.name << ": " << e.value[0] << " vs "
                            << c.exact[0];
      ++checked;
    }
  }
  EXPECT_GT(checked, 10);
}

INSTANTIATE_TEST_SUITE_P(AllMethods, ReferenceTest, ::testing::ValuesIn(AllMethods()),
                         [](const ::testing::TestParamInfo<Method>& i) { return std::string(MethodName(i.param)); });

TEST(Integrators, ErrorShrinksWithBudget) {
  // Quadrupling the Monte Carlo budget roughly halves the reported error.
  const Model m = Model::Parse("ggx");
  const auto b = m.Make<double>();
  const std::vector<double> p = ParseParams(m.Info(), "alpha=0.5");
  IntegrateOptions o;
  o.budget = 4096;
  const Estimate small = DirectionalAlbedo(*b, p.data(), View(0.5), Method::kCosine, o);
  o.budget = 4096 * 16;
  const Estimate large = DirectionalAlbedo(*b, p.data(), View(0.5), Method::kCosine, o);
  EXPECT_NEAR(small.error[0] / large.error[0], 4.0, 1.0);
}

// --- the adaptive rule on stiff cases: 1e-6 relative ------------------------------

// Independent check of E(wo): the same integral written over microfacet
// normals m, D G2 (wo.m) / mu_o with wi = reflect(wo, m) above the horizon,
// integrated with the generic peak chart (which knows nothing of the
// horizon ellipse) instead of the half-vector chart of DirectionalAlbedo.
double AlbedoOverNormals(const Bxdf<double>& b, const double* p, const Eigen::Vector3d& wo, double ax, double ay) {
  auto g = [&](const Eigen::Vector3d& m) -> Eigen::Array3d {
    const double wo_m = wo.dot(m);
    const Eigen::Vector3d wi = 2 * wo_m * m - wo;
    if (!(wi.z() > 0)) return Eigen::Array3d::Zero();  // reflected below the horizon
    return b.Eval(p, wi, wo) * (wi.z() * 4 * wo_m);
  };
  IntegrateOptions o;
  o.budget = 3000000;
  o.rel_tolerance = 1e-9;
  return IntegrateHemisphere(g, Method::kAdaptive, o, Eigen::Vector3d::UnitZ(), ax, ay, wo).value[0];
}

TEST(Adaptive, StiffMicrofacetAlbedosAgreeWithAnIndependentChart) {
  struct Case {
    const char* model;
    const char* params;
    double ax, ay, mu;
  };
  const Case cases[] = {
      {"ggx", "alpha=1e-4", 1e-4, 1e-4, 1e-6},       {"beckmann", "alpha=1e-4", 1e-4, 1e-4, 1e-6},
      {"ggx", "alpha=1e-4", 1e-4, 1e-4, 1e-4},       {"beckmann", "alpha=1e-3", 1e-3, 1e-3, 1e-2},
      {"ggx", "alpha=0.3", 0.3, 0.3, 1e-6},          {"ggx_aniso", "alpha_x=0.3,alpha_y=3e-4", 0.3, 3e-4, 0.05},
      {"beckmann_aniso", "alpha_x=1e-4,alpha_y=0.1", 1e-4, 0.1, 0.2},
  };
  for (const Case& c : cases) {
    const Model m = Model::Parse(c.model);
    const auto b = m.Make<double>();
    const std::vector<double> p = ParseParams(m.Info(), c.params);
    // Anisotropic cases look along a diagonal azimuth.
    const double s = std::sqrt(1 - c.mu * c.mu);
    const Eigen::Vector3d wo(s * std::cos(0.7), s * std::sin(0.7), c.mu);
    IntegrateOptions o;
    o.budget = 2000000;
    o.rel_tolerance = 1e-8;
    const Estimate e = DirectionalAlbedo(*b, p.data(), wo, Method::kAdaptive, o);
    const double other = AlbedoOverNormals(*b, p.data(), wo, c.ax, c.ay);
    SCOPED_TRACE(std::string(c.model) + " " + c.params + " mu=" + std::to_string(c.mu));
    EXPECT_GT(e.value[0], 0.5);
    EXPECT_LE(e.value[0], 1.0 + 1e-9);  // F = 1: energy conserving
    EXPECT_NEAR(e.value[0], other, 1e-6 * other);
    EXPECT_LT(e.error[0], 1e-6 * e.value[0]);
  }
}

TEST(Adaptive, GgxAlphaOneClosedFormDownToGrazing) {
  const Model m = Model::Parse("ggx");
  const auto b = m.Make<double>();
  const std::vector<double> p = ParseParams(m.Info(), "alpha=1");
  IntegrateOptions o;
  o.budget = 200000;
  o.rel_tolerance = 1e-10;
  for (double mu : {1e-6, 3e-5, 1e-3, 0.2, 0.77}) {
    const Estimate e = DirectionalAlbedo(*b, p.data(), View(mu), Method::kAdaptive, o);
    const double exact = 1 - mu * std::log1p(1 / mu);
    EXPECT_NEAR(e.value[0], exact, 1e-9) << mu;
    EXPECT_GE(e.error[0], std::abs(e.value[0] - exact) / 10) << mu;
  }
}

TEST(Adaptive, FewThousandEvaluationsPerTableCellAt1e7) {
  // An albedo table cell (GGX, alpha in [1e-3, 1]) at 1e-7 absolute.
  const Model m = Model::Parse("ggx");
  const auto b = m.Make<double>();
  std::int64_t total = 0;
  int cells = 0;
  for (double alpha : {1e-3, 1e-2, 0.1, 0.5, 1.0}) {
    const std::vector<double> p = ParseParams(m.Info(), "alpha=" + std::to_string(alpha));
    for (double mu : {1.0 / 64, 0.25, 0.6, 1.0}) {
      IntegrateOptions o;
      o.budget = 1000000;
      o.abs_tolerance = 1e-7;
      o.rel_tolerance = 0;
      const Estimate e = DirectionalAlbedo(*b, p.data(), View(mu), Method::kAdaptive, o);
      EXPECT_LE(e.error[0], 1e-7) << alpha << " " << mu;
      total += e.evals;
      ++cells;
    }
  }
  EXPECT_LT(total / cells, 20000);
}

// --- plots ------------------------------------------------------------------------

TEST(Plot, WritesSvgFilesAtomically) {
  namespace fs = std::filesystem;
  const fs::path dir = test::FreshDir("plot");
  Series a{"a", {1e-3, 1e-2, 1e-1}, {1e-2, 1e-4, 1e-8}}, b{"b", {1e-3, 1e-1}, {0.5, 0.0}};
  LinePlot((dir / "line.svg").string(), "errors", "time", "error", {a, b}, true, true);
  HeatMap((dir / "heat.svg").string(), "table", "mu", "alpha", {0, 0.5, 1}, {0, 0.1, 0.4, 1},
          {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11});
  for (const char* name : {"line.svg", "heat.svg"}) {
    std::ifstream in(dir / name);
    std::stringstream ss;
    ss << in.rdbuf();
    EXPECT_NE(ss.str().find("<svg"), std::string::npos) << name;
    EXPECT_NE(ss.str().find("</svg>"), std::string::npos) << name;
  }
  // Nothing but the two plots is left behind.
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 2);
  // Bad input: clear errors, no file.
  EXPECT_THROW(LinePlot((dir / "bad.svg").string(), "t", "x", "y", {Series{"s", {1, 2}, {1}}}, false, false),
               std::invalid_argument);
  EXPECT_THROW(HeatMap((dir / "bad.svg").string(), "t", "x", "y", {0, 1}, {0, 1}, {1, 2, 3}), std::invalid_argument);
  EXPECT_THROW(LinePlot((dir / "no_such_dir" / "x.svg").string(), "t", "x", "y", {a}, false, false),
               std::runtime_error);
  EXPECT_FALSE(fs::exists(dir / "bad.svg"));
  fs::remove_all(dir);
}

// Values equal to rounding (a lambert table's E, 0.4 within 4e-16) get an
// axis half a unit either side, labelled 0.0 .. 0.8, not ticks that all
// read 4.000 over a span of 1e-16.
TEST(Plot, FlatDataGetsAReadableAxis) {
  namespace fs = std::filesystem;
  const fs::path dir = test::FreshDir("plot-flat");
  LinePlot((dir / "flat.svg").string(), "E", "mu", "E", {Series{"E", {0, 0.5, 1}, {0.4, 0.4 + 4e-16, 0.4 - 5e-17}}},
           false, false);
  std::ifstream in(dir / "flat.svg");
  std::stringstream ss;
  ss << in.rdbuf();
  // PLplot writes each label's characters as entities: "0.4" and "4.000".
  EXPECT_NE(ss.str().find("&#x30;&#x2e;&#x34;</tspan>"), std::string::npos);
  EXPECT_EQ(ss.str().find("&#x34;&#x2e;&#x30;&#x30;&#x30;"), std::string::npos);
  fs::remove_all(dir);
}

// --- the convergence command --------------------------------------------------------

TEST(ConvergenceCommand, QuickRunWritesCsvPlotAndSummary) {
  namespace fs = std::filesystem;
  const fs::path dir = test::ScratchPath("conv");
  const std::string cmd = std::string(BRDFKIT_EXE) + " convergence --quick --methods importance,adaptive --out " +
                          dir.string() + " > " + (dir.string() + ".log") + " 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0);
  std::ifstream csv(dir / "convergence.csv");
  std::string header, line;
  std::getline(csv, header);
  EXPECT_EQ(header, "integrator,case,budget,evals,seconds,abs_error,est_error");
  int rows = 0;
  bool adaptive_exact = false;
  while (std::getline(csv, line)) {
    ++rows;
    // The adaptive rule reaches 1e-9 on the quick cases at its larger budgets.
    if (line.rfind("adaptive,", 0) == 0) {
      const double abs_error = std::stod(line.substr(line.rfind(',', line.rfind(',') - 1) + 1));
      adaptive_exact = adaptive_exact || abs_error < 1e-9;
    }
  }
  EXPECT_EQ(rows, 2 * 3 * 4);  // methods x cases x budgets
  EXPECT_TRUE(adaptive_exact);
  EXPECT_TRUE(fs::exists(dir / "convergence.svg"));
  std::ifstream md(dir / "convergence_summary.md");
  std::stringstream ss;
  ss << md.rdbuf();
  EXPECT_NE(ss.str().find("| adaptive |"), std::string::npos);
  // Bad method name: exit 2, message names it.
  const std::string bad = std::string(BRDFKIT_EXE) + " convergence --methods simpson --out " + dir.string() +
                          " > " + (dir.string() + ".err") + " 2>&1";
  EXPECT_NE(std::system(bad.c_str()), 0);
  std::ifstream err(dir.string() + ".err");
  std::stringstream es;
  es << err.rdbuf();
  EXPECT_NE(es.str().find("simpson"), std::string::npos) << es.str();
  fs::remove_all(dir);
  fs::remove(dir.string() + ".log");
  fs::remove(dir.string() + ".err");
}

// Near grazing the horizon reshapes the inner range on both sides of
// phi_m = pi/2; a rule that samples only one side misses a 1e-5 share of
// Ashikhmin-Shirley's albedo at mu = 0.01 while claiming 1e-9. Against
// scrambled Sobol' points through the model's own sampling.
TEST(Adaptive, GrazingAlbedoAgreesWithSobolOnBothSidesOfTheHorizonCut) {
  const Model m = Model::Parse("ashikhmin_shirley");
  const auto b = m.Make<double>();
  const std::vector<double> p = m.Info().Defaults();
  IntegrateOptions a;
  a.budget = 1000000;
  a.abs_tolerance = 1e-8;
  a.rel_tolerance = 0;
  const Estimate e = DirectionalAlbedo(*b, p.data(), View(0.01), Method::kAdaptive, a);
  IntegrateOptions q;
  q.budget = 1 << 22;
  const Estimate s = DirectionalAlbedo(*b, p.data(), View(0.01), Method::kSobol, q);
  EXPECT_LT(e.error[1], 1e-8);
  EXPECT_LT(s.error[1], 1e-5);  // below the 1.1e-5 the one-sided breaks missed
  EXPECT_NEAR(e.value[1], s.value[1], e.error[1] + s.error[1]);
}

}  // namespace
}  // namespace brdfkit::validate
