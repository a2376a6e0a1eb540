#include "validate/albedo.h"

#include <gtest/gtest.h>

#include <ImfFloatVectorAttribute.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfChannelList.h>
#include <ImfInputPart.h>
#include <ImfMultiPartInputFile.h>
#include <ImfStringAttribute.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "brdf/model.h"
#include "brdf/params.h"
#include "brdf/quadrature.h"
#include "tests/test_util.h"
#include "tests/scratch.h"
#include "tests/known_merl.h"

namespace brdfkit::validate {
namespace {

using test::GgxAlbedoAlpha1;
double GgxSeparableAlpha1(double mu) { return 2 * (1 - std::log(2.0)) / (1 + mu); }

AlbedoTable Table(const std::string& model, const std::string& params, const std::string& axes,
                  NodeRule rule = NodeRule::kUniform, double tolerance = AlbedoQuadratureOptions{}.abs_tolerance) {
  const Model m = Model::Parse(model);
  AlbedoTableRequest req;
  req.axes = ParseAxes(axes);
  req.rule = rule;
  req.quadrature.abs_tolerance = tolerance;
  return BuildAlbedoTable(m, ParseParams(m.Info(), params), req);
}

std::filesystem::path TempDir(const std::string& name) {
  return test::FreshDir("albedo_" + name);
}

// Brute-force reference in a different parameterisation: wi in (cos theta_i,
// phi_i) around the normal, composite 24-point Gauss-Legendre panels refined
// geometrically towards the mirror direction (no adaptivity).
double BruteForceAlbedo(const Bxdf<double>& b, const double* p, double mu_o, double width) {
  const GaussLegendre gl(24);
  const double sin_o = std::sqrt(1 - mu_o * mu_o);
  const Eigen::Vector3d wo(sin_o, 0, mu_o);
  // The mirror direction has mu_i = mu_o, phi_i = pi.
  std::vector<double> mu_breaks{0, 1}, phi_breaks{0, kPi};
  const double theta_o = std::acos(mu_o);
  for (double d = width / 64; d < 2; d *= 2) {
    for (double s : {-1.0, 1.0}) {
      const double m = std::cos(std::clamp(theta_o + s * d, 0.0, kPi / 2));
      if (m > 0 && m < 1) mu_breaks.push_back(m);
    }
    const double ph = kPi - d / std::max(sin_o, 1e-3);
    if (ph > 0) phi_breaks.push_back(ph);
  }
  std::sort(mu_breaks.begin(), mu_breaks.end());
  std::sort(phi_breaks.begin(), phi_breaks.end());
  double sum = 0;
  for (std::size_t a = 0; a + 1 < mu_breaks.size(); ++a)
    for (int i = 0; i < gl.size(); ++i) {
      const double h = mu_breaks[a + 1] - mu_breaks[a];
      const double mu = mu_breaks[a] + h * gl.node01(i);
      const double s = std::sqrt(1 - mu * mu);
      for (std::size_t c = 0; c + 1 < phi_breaks.size(); ++c)
        for (int j = 0; j < gl.size(); ++j) {
          const double k = phi_breaks[c + 1] - phi_breaks[c];
          const double phi = phi_breaks[c] + k * gl.node01(j);
          const Eigen::Vector3d wi(s * std::cos(phi), s * std::sin(phi), mu);
          sum += h * gl.weight01(i) * k * gl.weight01(j) * b.Eval(p, wi, wo)[0] * mu;
        }
    }
  return 2 * sum;  // phi in [0, pi] by symmetry
}

TEST(AlbedoTable, GgxAlphaOneMatchesClosedFormIncludingGrazingLimit) {
  const AlbedoTable t = Table("ggx", "f0=1", "mu:17,alpha:1:1:1");
  ASSERT_EQ(t.n_mu(), 17u);
  EXPECT_EQ(t.mu.nodes.front(), 0.0);
  EXPECT_EQ(t.mu.nodes.back(), 1.0);
  for (std::size_t m = 0; m < t.n_mu(); ++m)
    EXPECT_NEAR(t.at(m, 0), GgxAlbedoAlpha1(t.mu.nodes[m]), 1e-7) << "mu = " << t.mu.nodes[m];
  EXPECT_NEAR(t.at(t.n_mu() - 1, 0), 1 - std::log(2.0), 1e-8);
  // E_avg = 2 int_0^1 (1 - mu ln(1 + 1/mu)) mu dmu = 4/3 (1 - ln 2).
  EXPECT_NEAR(t.E_avg[0], 4.0 / 3.0 * (1 - std::log(2.0)), 1e-8);
  EXPECT_LE(t.max_error, AlbedoQuadratureOptions{}.abs_tolerance);
  EXPECT_LT(t.limit_error, 1e-7);
}

// Every entry within the tolerance of the closed form, and no error estimate
// below a tenth of the true error, from the default (the 1e-6 contract of
// the tables) down to 1e-9.
TEST(AlbedoTable, ErrorEstimatesAreHonestAtEveryTolerance) {
  for (double tol : {1e-6, 1e-9}) {
    const AlbedoTable t = Table("ggx", "f0=1", "mu:9,alpha:1:1:1", NodeRule::kUniform, tol);
    EXPECT_LE(t.max_error, tol);
    for (std::size_t m = 0; m < t.n_mu(); ++m) {
      const double err = std::abs(t.at(m, 0) - GgxAlbedoAlpha1(t.mu.nodes[m]));
      EXPECT_LE(err, tol) << "mu = " << t.mu.nodes[m];
      // At mu = 0 the entry also differs from the limit by limit_error.
      const double estimate = t.E_error[m] + (t.mu.nodes[m] == 0 ? t.limit_error : 0.0);
      EXPECT_GE(estimate, 0.1 * err) << "mu = " << t.mu.nodes[m];
    }
    const double err_avg = std::abs(t.E_avg[0] - 4.0 / 3.0 * (1 - std::log(2.0)));
    EXPECT_LE(err_avg, tol);
    EXPECT_GE(t.E_avg_error[0], 0.1 * err_avg);
  }
}

TEST(AlbedoTable, GgxSeparableAlphaOneMatchesClosedForm) {
  const AlbedoTable t = Table("ggx_separable", "f0=1", "mu:9,alpha:1:1:1");
  for (std::size_t m = 0; m < t.n_mu(); ++m)
    EXPECT_NEAR(t.at(m, 0), GgxSeparableAlpha1(t.mu.nodes[m]), 1e-7) << "mu = " << t.mu.nodes[m];
  // 2 int 2 (1 - ln 2) mu / (1 + mu) dmu = 4 (1 - ln 2)^2.
  EXPECT_NEAR(t.E_avg[0], 4 * std::pow(1 - std::log(2.0), 2), 1e-8);
}

// A transmitting model's entries are the power scattered from light along
// wo: E_R + E_T = the total; nearly smooth glass (alpha = 0.02) refracts
// almost nothing past the critical angle of the inside (eta = 1/1.5 seen
// from outside: sin theta > 1/1.5 at mu = 0.5; GGX puts 3.7e-3 of its
// normals more than 18 degrees off), and at normal incidence on eta = 1.5
// reflects F = 0.04 and refracts 0.96.
TEST(AlbedoTable, GlassEntriesSplitIntoReflectedAndTransmitted) {
  const Model m = Model::Parse("ggx_glass");
  const auto b = m.Make<double>();
  using Part = AlbedoQuadratureOptions::Part;
  for (double eta : {1.5, 1 / 1.5})
    for (double mu : {1.0, 0.5}) {
      SCOPED_TRACE("eta " + std::to_string(eta) + " mu " + std::to_string(mu));
      const std::vector<double> p = ParseParams(m.Info(), "alpha=0.02,eta=" + std::to_string(eta));
      const LobeShape shape = EstimateLobeShape(*b, p.data());
      AlbedoValue e[3];
      int k = 0;
      for (Part part : {Part::kReflected, Part::kTransmitted, Part::kTotal}) {
        AlbedoQuadratureOptions o;
        o.part = part;
        e[k++] = AlbedoAtMu(*b, p.data(), mu, shape, o);
      }
      EXPECT_NEAR(e[0].value[0] + e[1].value[0], e[2].value[0], e[0].error[0] + e[1].error[0] + e[2].error[0] + 1e-12);
      EXPECT_LE(e[2].value[0], 1 + e[2].error[0]);
      if (eta < 1 && mu == 0.5) {
        EXPECT_LT(e[1].value[0], 6e-3);  // those normals, weighted by visibility (<= 1.5 at 60 degrees)
      }
      if (eta > 1 && mu == 1.0) {
        EXPECT_NEAR(e[0].value[0], 0.04, 1e-3);
        EXPECT_NEAR(e[1].value[0], 0.96, 2e-3);
      }
    }
}

// Generalised reciprocity, f(wi, wo) / eta_wo^2 = f(wo, wi) / eta_wi^2: the
// hemispherical transmittance from inside (relative index 1 / eta) is that
// from outside divided by eta^2. Both averages computed independently, each
// over its own side's lobe (the inside one through total internal reflection).
TEST(AverageAlbedo, TransmittedAveragesOfTheTwoSidesDifferByEtaSquared) {
  const Model m = Model::Parse("ggx_glass_correlated");
  const auto b = m.Make<double>();
  AlbedoQuadratureOptions o;
  o.abs_tolerance = 1e-7;
  o.part = AlbedoQuadratureOptions::Part::kTransmitted;
  for (const auto& [alpha, eta] : {std::pair{0.16, 1.5}, std::pair{0.8, 2.125}}) {
    SCOPED_TRACE("alpha " + std::to_string(alpha) + " eta " + std::to_string(eta));
    const std::vector<double> out = ParseParams(m.Info(), "alpha=" + FormatDouble(alpha) + ",eta=" + FormatDouble(eta));
    const std::vector<double> in =
        ParseParams(m.Info(), "alpha=" + FormatDouble(alpha) + ",eta=" + FormatDouble(1 / eta));
    LobeShape shape;
    shape.width = alpha;
    const AlbedoValue t_out = AverageAlbedo(*b, out.data(), shape, o), t_in = AverageAlbedo(*b, in.data(), shape, o);
    EXPECT_GT(t_in.value[0], 0.1);  // not the trivial identity 0 = 0
    EXPECT_NEAR(t_in.value[0], t_out.value[0] / (eta * eta), t_in.error[0] + t_out.error[0] / (eta * eta));
  }
}

// Light from inside glass of relative index 1 / 99.5 (Cycles' densest
// glass node) escapes only within theta_c = 0.01 rad of the normal: E_R
// dips from 1 to 0.965 over mu in [1 - 3e-4, 1], 5e-6 of E_avg. The average
// against an independent sum: adaptive Gauss-Kronrod in ln(mu) below mu =
// 0.99 and composite Gauss-Legendre in theta above (8 panels of 20 nodes).
TEST(AverageAlbedo, ResolvesTheEscapeConeOfDenseGlassSeenFromInside) {
  const Model m = Model::Parse("ggx_glass_correlated");
  const auto b = m.Make<double>();
  const double alpha = 1.0 / 225, m1 = 0.99;
  // eta below the parameter's range [0.2, 5] (which ParseParams enforces), as the preset sets it.
  std::vector<double> p = m.Info().Defaults();
  p[m.Info().Offset(AxisParameter(m.Info(), "alpha"))] = alpha;
  p[m.Info().Offset(AxisParameter(m.Info(), "eta"))] = 1 / 99.5;
  LobeShape shape;
  shape.width = alpha;
  AlbedoQuadratureOptions o;
  o.abs_tolerance = 1e-7;
  o.part = AlbedoQuadratureOptions::Part::kReflected;
  const AlbedoValue avg = AverageAlbedo(*b, p.data(), shape, o);
  AlbedoQuadratureOptions fine = o;
  fine.abs_tolerance = 1e-11;
  const auto e = [&](double mu) { return AlbedoAtMu(*b, p.data(), mu, shape, fine).value[0]; };
  double err = 0;
  std::int64_t n = 0;
  const double mu_min = 1e-4 * alpha, sw = std::log(alpha);
  const auto g = [&](double s) -> Eigen::Array3d { return Eigen::Array3d::Constant(2 * std::exp(2 * s) * e(std::exp(s))); };
  double ref = AdaptiveGaussKronrod(g, std::log(mu_min), std::log(m1), {sw - 2, sw + 2}, 1e-10, 400, &err, &n)[0];
  ref += mu_min * mu_min * e(mu_min);
  const double t1 = std::acos(m1);
  const GaussLegendre gl(20);
  for (int k = 0; k < 8; ++k)
    for (int i = 0; i < 20; ++i) {
      const double t = t1 * (k + gl.node01(i)) / 8;
      ref += t1 / 8 * gl.weight01(i) * 2 * std::cos(t) * std::sin(t) * e(std::cos(t));
    }
  EXPECT_NEAR(avg.value[0], ref, avg.error[0] + err + 1e-10);
}

// E_avg gives up once its error estimate is sure to end above the accepted
// error: on a measured table (MERL's nearest bin: E converges slowly at
// every node) after the first pass of its rule instead of every split it
// may make, refused either way; an average within the accepted error (GGX)
// is computed as before, to the bit.
TEST(AverageAlbedo, GivesUpOnceTheAcceptedErrorIsOutOfReach) {
  const Model merl = Model::Parse("merl", {{"path", test::KnownMerlFile()}});
  const auto b = merl.Make<double>();
  const std::vector<double> none;
  const LobeShape shape = EstimateLobeShape(*b, none.data());
  AlbedoQuadratureOptions o;
  o.max_evals = 2000;
  o.max_subdivisions = 20;
  const AlbedoValue full = AverageAlbedo(*b, none.data(), shape, o);
  AlbedoQuadratureOptions strict = o;
  strict.accepted_error = o.abs_tolerance;
  const AlbedoValue early = AverageAlbedo(*b, none.data(), shape, strict);
  EXPECT_GT(full.error[0], strict.accepted_error);  // both are refused
  EXPECT_GT(early.error[0], strict.accepted_error);
  EXPECT_GT(full.evals, 5 * early.evals);  // 12 times at these settings
  // An accepted error the average meets never stops it.
  AlbedoQuadratureOptions loose = o;
  loose.accepted_error = 2 * full.error[0];
  const AlbedoValue same = AverageAlbedo(*b, none.data(), shape, loose);
  EXPECT_EQ(same.value[0], full.value[0]);
  EXPECT_EQ(same.error[0], full.error[0]);
  const Model ggx = Model::Parse("ggx");
  const auto g = ggx.Make<double>();
  const std::vector<double> p = ParseParams(ggx.Info(), "alpha=0.05,f0=1");
  const LobeShape g_shape = EstimateLobeShape(*g, p.data());
  AlbedoQuadratureOptions fed, fed_strict;
  fed_strict.accepted_error = fed.abs_tolerance;
  const AlbedoValue a = AverageAlbedo(*g, p.data(), g_shape, fed), c = AverageAlbedo(*g, p.data(), g_shape, fed_strict);
  EXPECT_LT(a.error[0], fed.abs_tolerance);
  EXPECT_EQ(a.value[0], c.value[0]);
  EXPECT_EQ(a.evals, c.evals);
}

// A roughness axis (renderers' convention, alpha = roughness^2) holds the
// same entries as the alpha axis spaced in sqrt(alpha) over the squared
// range; roughness 0 is the smoothest alpha the model takes (1e-7 for GGX),
// where E at normal incidence is F = 1.
TEST(AlbedoTable, RoughnessAxisIsAlphaSquared) {
  const AlbedoTable r = Table("ggx", "f0=1", "mu:5,roughness:3:0.5:1");
  const AlbedoTable a = Table("ggx", "f0=1", "mu:5,alpha:3:0.25:1");
  EXPECT_EQ(r.params[0].name, "roughness");
  EXPECT_EQ(r.params[0].nodes, (std::vector<double>{0.5, 0.75, 1.0}));
  ASSERT_EQ(r.E.size(), a.E.size());
  for (std::size_t k = 0; k < r.E.size(); ++k) EXPECT_NEAR(r.E[k], a.E[k], 1e-12) << k;
  for (std::size_t k = 0; k < r.E_avg.size(); ++k) EXPECT_NEAR(r.E_avg[k], a.E_avg[k], 1e-12) << k;
  EXPECT_EQ(r.params_text, "f0=1:1:1");
  // The compensation lookup takes alpha and finds it on the roughness nodes.
  const AlbedoLookup lr(r), la(a);
  for (double alpha : {0.3, 0.5625, 0.8}) EXPECT_NEAR(lr.EAvg(alpha), la.EAvg(alpha), 1e-12) << alpha;
  const AlbedoTable s = Table("ggx", "f0=1", "mu:3:0.5:1,roughness:2:0:0.1");
  EXPECT_EQ(s.params[0].nodes[0], 0.0);
  EXPECT_NEAR(s.at(2, 0), 1.0, 1e-6);
  EXPECT_THROW(Table("lambert", "", "mu:3,roughness:2"), ModelError);
  EXPECT_THROW(Table("ggx", "", "mu:3,roughness:2:0:1.5"), ModelError);
  EXPECT_THROW(Table("ggx", "", "mu:3,roughness:2,alpha:2"), ModelError);
}

TEST(AlbedoTable, LambertIsItsAlbedoEverywhere) {
  const AlbedoTable t = Table("lambert", "", "mu:5,albedo:3");
  ASSERT_EQ(t.n1(), 3u);
  EXPECT_EQ(t.params[0].nodes.front(), 0.0);
  EXPECT_EQ(t.params[0].nodes.back(), 1.0);
  for (std::size_t i = 0; i < 3; ++i) {
    for (std::size_t m = 0; m < t.n_mu(); ++m) EXPECT_NEAR(t.at(m, i), t.params[0].nodes[i], 1e-9);
    EXPECT_NEAR(t.E_avg[i], t.params[0].nodes[i], 1e-9);
  }
}

TEST(AlbedoTable, MatchesIndependentBruteForceQuadrature) {
  const Model m = Model::Parse("ggx");
  const auto b = m.Make<double>();
  // Narrow, medium and wide lobes, near-normal and grazing views.
  for (double alpha : {1e-3, 0.02, 0.3}) {
    const AlbedoTable t = Table("ggx", "f0=1", "mu:6:0.1:1,alpha:1:" + FormatDouble(alpha) + ":" + FormatDouble(alpha));
    std::vector<double> p = ParseParams(m.Info(), "f0=1,alpha=" + FormatDouble(alpha));
    for (std::size_t i : {0u, 2u, 5u}) {
      const double mu = t.mu.nodes[i];
      const double ref = BruteForceAlbedo(*b, p.data(), mu, alpha);
      EXPECT_NEAR(t.at(i, 0), ref, 2e-8) << "alpha " << alpha << " mu " << mu;
      EXPECT_GE(t.E_error[t.Index(i, 0)], 0.1 * std::abs(t.at(i, 0) - ref)) << "alpha " << alpha << " mu " << mu;
    }
  }
}

TEST(AlbedoTable, UniformNodesAreUniformInSqrtRoughness) {
  const AlbedoTable t = Table("ggx", "", "mu:3,alpha:5:0.01:1");
  const auto& a = t.params[0].nodes;
  ASSERT_EQ(a.size(), 5u);
  EXPECT_DOUBLE_EQ(a.front(), 0.01);
  EXPECT_DOUBLE_EQ(a.back(), 1.0);
  for (std::size_t i = 0; i < 5; ++i) EXPECT_NEAR(std::sqrt(a[i]), 0.1 + 0.9 * i / 4.0, 1e-15);
  // Default range: the parameter's bounds.
  const AlbedoTable d = Table("ggx", "", "mu:2,alpha:2");
  EXPECT_DOUBLE_EQ(d.params[0].nodes.front(), 1e-7);
  EXPECT_DOUBLE_EQ(d.params[0].nodes.back(), 1.0);
}

TEST(AlbedoTable, GaussNodesIntegrateTheTableToEAvg) {
  const AlbedoTable t = Table("ggx", "f0=1", "mu:24,alpha:1:0.5:0.5", NodeRule::kGauss);
  EXPECT_GT(t.mu.nodes.front(), 0.0);
  double sum = 0, wsum = 0;
  for (std::size_t m = 0; m < t.n_mu(); ++m) {
    sum += 2 * t.mu.weights[m] * t.mu.nodes[m] * t.at(m, 0);
    wsum += t.mu.weights[m];
  }
  EXPECT_NEAR(wsum, 1.0, 1e-14);
  // The table's own Gauss sum approximates the separately computed E_avg.
  EXPECT_NEAR(sum, t.E_avg[0], 1e-6);
}

TEST(AlbedoTable, FresnelAxisGivesKullaContyTerms) {
  const AlbedoTable t = Table("ggx", "", "mu:5,alpha:2:0.2:0.8,f0:3");
  ASSERT_EQ(t.f0_axis, 1);
  ASSERT_EQ(t.F_avg.size(), 3u);
  // F_avg from a quadrature of Schlick's formula.
  const GaussLegendre gl(40);
  for (std::size_t k = 0; k < 3; ++k) {
    const double f0 = t.params[1].nodes[k];
    double q = 0;
    for (int i = 0; i < gl.size(); ++i) q += 2 * gl.weight01(i) * gl.node01(i) * FresnelSchlick(f0, gl.node01(i));
    EXPECT_NEAR(t.F_avg[k], q, 1e-14);
  }
  for (std::size_t i1 = 0; i1 < 2; ++i1) {
    // At f0 = 1 the table equals the F = 1 table and F_ms = 1.
    for (std::size_t m = 0; m < t.n_mu(); ++m) EXPECT_NEAR(t.at(m, i1, 2), t.E1[i1 * t.n_mu() + m], 1e-12);
    EXPECT_NEAR(t.F_ms[i1 * 3 + 2], 1.0, 1e-12);
    // Schlick is linear in f0, so is E.
    for (std::size_t m = 0; m < t.n_mu(); ++m)
      EXPECT_NEAR(t.at(m, i1, 1), 0.5 * (t.at(m, i1, 0) + t.at(m, i1, 2)), 2e-9);
    // F_ms = F_avg^2 E_avg / (1 - F_avg (1 - E_avg)) < F_avg at f0 = 0.
    const double fa = t.F_avg[0], e = t.E1_avg[i1];
    EXPECT_NEAR(t.F_ms[i1 * 3], fa * fa * e / (1 - fa * (1 - e)), 1e-15);
  }
}

TEST(EnergyCompensation, WhiteFurnaceWithCompensationLobe) {
  const Model m = Model::Parse("ggx");
  const auto b = m.Make<double>();
  const AlbedoTable t = Table("ggx", "f0=1", "mu:129,alpha:3:0.25:1");
  const CompensatedBxdf comp(*b, t);
  for (std::size_t i = 0; i < t.n1(); ++i) {
    const double alpha = t.params[0].nodes[i];
    const std::vector<double> p = ParseParams(m.Info(), "f0=1,alpha=" + FormatDouble(alpha));
    const LobeShape shape = EstimateLobeShape(comp, p.data());
    for (double mu : {0.05, 0.3, 0.7, 1.0}) {
      const double single = AlbedoAtMu(*b, p.data(), mu, EstimateLobeShape(*b, p.data())).value[0];
      EXPECT_LT(single, 0.999) << "alpha " << alpha;  // energy is lost without compensation
      const AlbedoValue e = AlbedoAtMu(comp, p.data(), mu, shape);
      EXPECT_NEAR(e.value[0], 1.0, 2e-6) << "alpha " << alpha << " mu " << mu;
    }
  }
}

// mu:N alone tabulates E(mu) of the model as given: lambert's is its
// albedo, and GGX's is the row of a table with an alpha axis through the
// same alpha (ends included), entry for entry.
TEST(AlbedoTable, MuAloneTabulatesTheModelAsGiven) {
  const AlbedoTable l = Table("lambert", "albedo=0.3", "mu:5");
  EXPECT_TRUE(l.params.empty());
  ASSERT_EQ(l.E.size(), 5u);
  ASSERT_EQ(l.E_avg.size(), 1u);
  for (double e : l.E) EXPECT_NEAR(e, 0.3, 1e-9);
  EXPECT_NEAR(l.E_avg[0], 0.3, 1e-9);
  EXPECT_NEAR(l.ms_norm[0], 1 / (kPi * 0.7), 1e-8);
  EXPECT_EQ(l.params_text, "albedo=0.3:0.3:0.3");  // every parameter is held fixed
  const AlbedoTable g = Table("ggx", "alpha=0.3,f0=1", "mu:6");
  const AlbedoTable row = Table("ggx", "f0=1", "mu:6,alpha:2:0.3:0.5");
  ASSERT_EQ(row.params[0].nodes[0], 0.3);
  for (std::size_t m = 0; m < 6; ++m) EXPECT_NEAR(g.E[m], row.at(m, 0), 1e-12) << m;
  EXPECT_NEAR(g.E_avg[0], row.E_avg[0], 1e-12);
  EXPECT_LT(g.max_error, 1e-6);
  // A slice is taken along a parameter axis: none here.
  const Model m = Model::Parse("ggx");
  AlbedoTableRequest req;
  req.axes = ParseAxes("mu:4");
  req.slice_begin = 0;
  req.slice_end = 2;
  EXPECT_THROW(BuildAlbedoTable(m, m.Info().Defaults(), req), ModelError);
  // What to change when entries miss: the tolerance without parameter axes.
  EXPECT_NE(MissAdvice(g).find("--tolerance 1e-3"), std::string::npos);
  EXPECT_NE(MissAdvice(row).find("Narrow the parameter range"), std::string::npos);
  EXPECT_EQ(DescribeMisses({{"E_avg", -1, {}, 0.5}, {"E", 0.25, {}, 0.25}}, 1e-6),
            "2 table entries miss the error tolerance 1e-06:\n  E_avg: error estimate 0.5\n  E at mu = 0.25: error "
            "estimate 0.25");
}

// Without parameter axes the files carry mu and the values alone.
TEST(AlbedoOutput, MuAloneWritesMuAndTheValues) {
  const AlbedoTable t = Table("lambert", "albedo=0.5", "mu:3");
  const auto dir = TempDir("mu_alone");
  WriteAlbedoCsv(t, (dir / "l.csv").string());
  const auto rows = [&](const std::string& name) {
    std::ifstream in(dir / name);
    std::vector<std::string> out;
    for (std::string line; std::getline(in, line);) out.push_back(line);
    return out;
  };
  const std::vector<std::string> e = rows("l.csv"), avg = rows("l_avg.csv"), ms = rows("l_ms.csv");
  ASSERT_EQ(e.size(), 4u);
  EXPECT_EQ(e[0], "mu,E");
  for (std::size_t m = 0; m < 3; ++m) {
    const std::string& line = e[m + 1];
    double mu = -1, value = -1;
    ASSERT_TRUE(ParseDouble(line.substr(0, line.find(',')), mu) && ParseDouble(line.substr(line.find(',') + 1), value))
        << line;
    EXPECT_EQ(mu, 0.5 * double(m));
    EXPECT_NEAR(value, 0.5, 1e-9);
  }
  ASSERT_EQ(avg.size(), 2u);
  EXPECT_EQ(avg[0], "E_avg");
  double e_avg = -1;
  ASSERT_TRUE(ParseDouble(avg[1], e_avg)) << avg[1];
  EXPECT_NEAR(e_avg, 0.5, 1e-9);
  ASSERT_EQ(ms.size(), 2u);
  EXPECT_EQ(ms[0], "E_avg,ms_norm");
}

TEST(AlbedoOutput, CsvHasHeaderRowsAndAverageFile) {
  const AlbedoTable t = Table("ggx", "f0=1", "mu:3,alpha:2:0.5:1");
  const auto dir = TempDir("csv");
  const std::string path = (dir / "ggx.csv").string();
  WriteAlbedoCsv(t, path);
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line, "mu,alpha,E");
  int rows = 0;
  while (std::getline(in, line)) {
    std::stringstream ss(line);
    std::string a, b, c;
    std::getline(ss, a, ',');
    std::getline(ss, b, ',');
    std::getline(ss, c, ',');
    double mu, alpha, e;
    ASSERT_TRUE(ParseDouble(a, mu) && ParseDouble(b, alpha) && ParseDouble(c, e)) << line;
    if (alpha == 1.0) {
      EXPECT_NEAR(e, GgxAlbedoAlpha1(mu), 1e-7);
    }
    ++rows;
  }
  EXPECT_EQ(rows, 6);
  EXPECT_EQ(AverageCsvPath(path), (dir / "ggx_avg.csv").string());
  std::ifstream avg(AverageCsvPath(path));
  std::getline(avg, line);
  EXPECT_EQ(line, "alpha,E_avg");
  std::getline(avg, line);
  std::getline(avg, line);
  EXPECT_EQ(line.substr(0, 2), "1,");
  double e_avg;
  ASSERT_TRUE(ParseDouble(line.substr(2), e_avg));
  EXPECT_NEAR(e_avg, 4.0 / 3.0 * (1 - std::log(2.0)), 1e-8);
  EXPECT_TRUE(std::filesystem::exists(dir / "ggx_ms.csv"));
  // Only the finished files are left.
  int files = 0;
  for ([[maybe_unused]] const auto& f : std::filesystem::directory_iterator(dir)) ++files;
  EXPECT_EQ(files, 3);
}

TEST(AlbedoOutput, ExrStoresFloatImagesAndNodeAttributes) {
  const AlbedoTable t = Table("ggx", "f0=1", "mu:4,alpha:3:0.25:1");
  const auto dir = TempDir("exr");
  const std::string path = (dir / "ggx.exr").string();
  WriteAlbedoExr(t, path);
  Imf::MultiPartInputFile in(path.c_str());
  ASSERT_GE(in.parts(), 2);
  const Imf::Header& h = in.header(0);
  EXPECT_EQ(h.name(), "E");
  const auto* mu = h.findTypedAttribute<Imf::FloatVectorAttribute>("brdfkit.nodes.mu");
  const auto* alpha = h.findTypedAttribute<Imf::FloatVectorAttribute>("brdfkit.nodes.alpha");
  ASSERT_TRUE(mu && alpha);
  ASSERT_EQ(mu->value().size(), 4u);
  ASSERT_EQ(alpha->value().size(), 3u);
  EXPECT_EQ(h.findTypedAttribute<Imf::StringAttribute>("brdfkit.model")->value(), "ggx");
  // Only the parameters held fixed: alpha is an axis.
  EXPECT_EQ(h.findTypedAttribute<Imf::StringAttribute>("brdfkit.params")->value(), "f0=1:1:1");
  EXPECT_NE(h.channels().findChannel("Y"), nullptr);  // a grey image to texture loaders
  const auto dw = h.dataWindow();
  const int w = dw.max.x - dw.min.x + 1, hgt = dw.max.y - dw.min.y + 1;
  ASSERT_EQ(w, 4);
  ASSERT_EQ(hgt, 3);
  std::vector<float> px(w * hgt);
  Imf::InputPart part(in, 0);
  Imf::FrameBuffer fb;
  fb.insert("Y", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(px.data()), sizeof(float), sizeof(float) * w));
  part.setFrameBuffer(fb);
  part.readPixels(dw.min.y, dw.max.y);
  for (int r = 0; r < hgt; ++r)
    for (int c = 0; c < w; ++c) EXPECT_FLOAT_EQ(px[r * w + c], float(t.at(c, r)));
  // Row alpha = 1 holds the closed form.
  for (int c = 0; c < w; ++c) EXPECT_NEAR(px[2 * w + c], GgxAlbedoAlpha1(mu->value()[c]), 1e-6);
  EXPECT_EQ(in.header(1).name(), "E_avg");
}

TEST(AlbedoOutput, HeaderHasArraysForRenderers) {
  const AlbedoTable t = Table("ggx", "f0=1", "mu:4,alpha:2:0.25:1");
  const auto dir = TempDir("header");
  const std::string path = (dir / "ggx_albedo.h").string();
  WriteAlbedoHeader(t, path, "ggx_albedo");
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string s = ss.str();
  EXPECT_NE(s.find("static const float ggx_albedo_E[2][4] GGX_ALBEDO_UNUSED = {"), std::string::npos);
  EXPECT_NE(s.find("static const float ggx_albedo_mu_nodes[4]"), std::string::npos);
  EXPECT_NE(s.find("static const float ggx_albedo_alpha_nodes[2]"), std::string::npos);
  EXPECT_NE(s.find("static const float ggx_albedo_E_avg[2]"), std::string::npos);
  EXPECT_NE(s.find("ggx_albedo_n_mu = 4"), std::string::npos);
}

TEST(AlbedoOutput, UnwritableTargetLeavesNothing) {
  const AlbedoTable t = Table("lambert", "", "mu:2,albedo:2");
  const auto dir = TempDir("bad");
  std::filesystem::create_directories(dir / "x.csv");  // a directory where the file should go
  EXPECT_ANY_THROW(WriteAlbedoCsv(t, (dir / "x.csv").string()));
  EXPECT_FALSE(std::filesystem::exists(dir / "x_avg.csv"));
  EXPECT_ANY_THROW(WriteAlbedoExr(t, (dir / "missing" / "t.exr").string()));
  EXPECT_FALSE(std::filesystem::exists(dir / "missing"));
}

TEST(AlbedoTable, RejectsBadAxes) {
  EXPECT_THROW(ParseAxes("mu:x"), ModelError);
  EXPECT_THROW(ParseAxes("mu:0"), ModelError);
  EXPECT_THROW(ParseAxes("mu:4:1"), ModelError);
  EXPECT_THROW(ParseAxes("alpha:4:1:0.5"), ModelError);
  EXPECT_THROW(Table("ggx", "", "mu:4,sigma:4"), ModelError);
  EXPECT_THROW(Table("ggx", "", "alpha:4,mu:4"), ModelError);
  EXPECT_THROW(Table("ggx", "", "mu:4,alpha:4:0:1"), ModelError);  // alpha below its bound
  EXPECT_THROW(Table("ggx", "", "mu:4,alpha:4,alpha:3"), ModelError);
}

}  // namespace
}  // namespace brdfkit::validate
