// Oren-Nayar (qualitative and Fujii), Phong (original and modified),
// Blinn-Phong and Lafortune: closed forms, published values, equalities
// between models, the documented failures of phong_original and sampling.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "brdf/model.h"
#include "brdf/params.h"
#include "brdf/quadrature.h"
#include "tests/test_util.h"
#include "validate/jet_models.h"
#include "validate/sampling_check.h"

namespace brdfkit {
namespace {

using test::DirectionFromAngles;

// cos(theta) uniform; one draw per statement (the order of a call's
// arguments is unspecified), phi first.
template <class U, class R>
Eigen::Vector3d RandomDir(U& u, R& rng) {
  const double phi = 2 * kPi * u(rng);
  return DirectionFromAngles(std::acos(u(rng)), phi);
}

// Composite Gauss-Legendre over the pieces between consecutive breaks.
double Integrate(const GaussLegendre& gl, const std::vector<double>& breaks, const std::function<double(double)>& g) {
  double sum = 0;
  for (std::size_t k = 0; k + 1 < breaks.size(); ++k) {
    const double a = breaks[k], b = breaks[k + 1];
    if (b <= a) continue;
    for (int i = 0; i < gl.size(); ++i) sum += (b - a) * gl.weight01(i) * g(a + (b - a) * gl.node01(i));
  }
  return sum;
}

// Breaks on [a, b] that include `at` and refine geometrically towards it, the
// finest piece `finest` wide: resolves a lobe or kink centred there.
std::vector<double> GradedBreaks(double a, double b, double at, double finest) {
  std::vector<double> out = {a, b};
  if (at > a && at < b) out.push_back(at);
  for (double w = finest; w < b - a; w *= 2) {
    if (at - w > a) out.push_back(at - w);
    if (at + w < b) out.push_back(at + w);
  }
  std::sort(out.begin(), out.end());
  return out;
}

// Breaks on [0, pi/2] refined towards the normal (narrow lobes) and towards
// the horizon (cos^(n+1) with non-integer n is not smooth there).
std::vector<double> BothEndsGraded(double finest) {
  std::vector<double> out = GradedBreaks(0, kPi / 4, 0, finest), top = GradedBreaks(kPi / 4, kPi / 2, kPi / 2, 1e-4);
  out.insert(out.end(), top.begin() + 1, top.end());
  return out;
}

// Directional albedo E(wo) = int f(wi, wo) cos_theta_i dwi (red channel), wo at
// polar angle theta_o and azimuth 0, in (theta_i, phi_i) with the given breaks.
double Albedo(const Bxdf<double>& b, const double* p, double theta_o, const std::vector<double>& theta_breaks,
              const std::vector<double>& phi_breaks, int nodes) {
  const GaussLegendre gl(nodes);
  const Eigen::Vector3d wo = DirectionFromAngles(theta_o, 0);
  return Integrate(gl, theta_breaks, [&](double t) {
    const double inner =
        Integrate(gl, phi_breaks, [&](double phi) { return b.Eval(p, DirectionFromAngles(t, phi), wo)[0]; });
    return inner * std::cos(t) * std::sin(t);
  });
}

// Kinks of the Oren-Nayar forms: theta_i = theta_o (max of the cosines) and
// phi_i = +-pi/2 (sign of cos(phi_i - phi_o)); smooth between them.
double OrenNayarAlbedo(const Bxdf<double>& b, const double* p, double theta_o, int nodes = 24) {
  return Albedo(b, p, theta_o, {0.0, theta_o, kPi / 2}, {-kPi / 2, kPi / 2, 3 * kPi / 2}, nodes);
}

// E_avg = 2 int_0^1 E(mu) mu dmu, in theta_o so that E is smooth.
double AverageAlbedo(const std::function<double(double)>& albedo_at_theta, int nodes = 24) {
  const GaussLegendre gl(nodes);
  return 2 * Integrate(gl, {0.0, kPi / 2},
                       [&](double t) { return albedo_at_theta(t) * std::cos(t) * std::sin(t); });
}

std::vector<double> Params(const Model& m, const std::string& text) { return ParseParams(m.Info(), text); }

// 1 - (1 - mu^2)^(3/2) without cancellation at small mu.
double OneMinusSin3(double mu) {
  const double s = std::sqrt(1 - mu * mu);
  return mu * mu / (1 + s) * (1 + s + s * s);
}

// Closed forms of the directional albedo, derived by integrating the models
// over phi_i (int max(0, cos) = 2) and then over mu_i, split at mu_i = mu_o.
double OrenNayarAlbedoClosedForm(double rho, double sigma, double mu) {
  const double s2 = sigma * sigma, a = 1 - 0.5 * s2 / (s2 + 0.33), b = 0.45 * s2 / (s2 + 0.09);
  const double so = std::sqrt(1 - mu * mu);
  return rho * (a + 2 * b / kPi * so * (OneMinusSin3(mu) / (3 * mu) + (std::acos(mu) - mu * so) / 2));
}

double FujiiAlbedoClosedForm(double rho, double sigma, double mu) {
  const double a = 1 / (kPi + sigma * (kPi / 2 - 2.0 / 3.0)), b = sigma * a;
  const double so = std::sqrt(1 - mu * mu);
  const double i = 2 * OneMinusSin3(mu) / (3 * mu) + std::acos(mu) - mu * so - 2.0 / 3.0;
  return rho * (kPi * a + b * so * i);
}

// --- Oren-Nayar ----------------------------------------------------------------

TEST(OrenNayar, SigmaZeroIsLambertExactly) {
  const Model on = Model::Parse("oren_nayar"), lambert = Model::Parse("lambert");
  const auto b = on.Make<double>();
  const auto bl = lambert.Make<double>();
  const auto bf = on.Make<float>();
  const auto blf = lambert.Make<float>();
  const std::vector<double> p = Params(on, "albedo=0.2:0.5:0.9,sigma=0");
  const std::vector<float> pf(p.begin(), p.end());
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(0, 1);
  for (int k = 0; k < 2000; ++k) {
    const Eigen::Vector3d wi = RandomDir(u, rng), wo = RandomDir(u, rng);
    const Rgb<double> f = b->Eval(p.data(), wi, wo), fl = bl->Eval(p.data(), wi, wo);
    const Rgb<float> ff = bf->Eval(pf.data(), wi.cast<float>(), wo.cast<float>());
    const Rgb<float> flf = blf->Eval(pf.data(), wi.cast<float>(), wo.cast<float>());
    for (int c = 0; c < 3; ++c) {
      ASSERT_EQ(f[c], fl[c]);
      ASSERT_EQ(ff[c], flf[c]);
    }
  }
}

TEST(OrenNayar, AlbedoMatchesClosedFormAndExceedsRhoAtGrazingForSmallSigma) {
  const Model on = Model::Parse("oren_nayar");
  const auto b = on.Make<double>();
  for (double sigma : {0.1, 0.2, 0.5, 1.0, kPi / 2}) {
    const std::vector<double> p = Params(on, "albedo=0.8,sigma=" + FormatDouble(sigma));
    for (double theta_o : {0.0, 0.3, 0.8, 1.2, 1.5, kPi / 2 - 1e-3}) {
      const double e = OrenNayarAlbedo(*b, p.data(), theta_o);
      const double expected = theta_o == 0.0 ? 0.8 * (1 - 0.5 * sigma * sigma / (sigma * sigma + 0.33))
                                             : OrenNayarAlbedoClosedForm(0.8, sigma, std::cos(theta_o));
      EXPECT_NEAR(e, expected, 1e-10) << "sigma " << sigma << " theta_o " << theta_o;
    }
  }
  // rho (A + B/2) at grazing view: 1.0151767 for rho = 1, sigma = 0.2.
  const std::vector<double> p = Params(on, "albedo=1,sigma=0.2");
  const double a = 1 - 0.5 * 0.04 / 0.37, bb = 0.45 * 0.04 / 0.13;
  EXPECT_NEAR(a + bb / 2, 1.0151767, 1e-7);
  const double grazing = OrenNayarAlbedo(*b, p.data(), kPi / 2 - 1e-5);
  EXPECT_NEAR(grazing, a + bb / 2, 2e-5);
  EXPECT_GT(grazing, 1.015);
  EXPECT_FALSE(on.Info().energy_conserving);
}

TEST(OrenNayar, DoubleGrazingGuardKeepsValuesAndDerivativesFinite) {
  using J = JetN<4>;
  const Model on = Model::Parse("oren_nayar");
  const std::vector<double> p = Params(on, "albedo=0.5,sigma=0.5");
  const double mu = 1e-12, s = std::sqrt(1 - mu * mu);
  const Eigen::Vector3d wi(s, 0, mu), wo(s, 0, mu);
  // Same azimuth: the eq. 30 term is s^2 / mu, held at s^2 / 1e-6.
  const double a = 1 - 0.5 * 0.25 / 0.58, bb = 0.45 * 0.25 / 0.34;
  const double expected = 0.5 / kPi * (a + bb * s * s / kOrenNayarMinCos);
  EXPECT_NEAR(on.Make<double>()->Eval(p.data(), wi, wo)[0], expected, 1e-12 * expected);
  const std::vector<float> pf(p.begin(), p.end());
  const float ff = on.Make<float>()->Eval(pf.data(), wi.cast<float>(), wo.cast<float>())[0];
  EXPECT_NEAR(ff, expected, 1e-5 * expected);
  std::vector<J> pj(p.size());
  for (std::size_t k = 0; k < p.size(); ++k) pj[k] = J(p[k], static_cast<int>(k));
  const Rgb<J> fj = on.Make<J>()->Eval(pj.data(), wi.cast<J>(), wo.cast<J>());
  EXPECT_TRUE(std::isfinite(fj[0].a));
  EXPECT_TRUE(fj[0].v.allFinite());
}

// --- Fujii ------------------------------------------------------------------

TEST(OrenNayarFujii, PublishedAlbedos) {
  const Model m = Model::Parse("oren_nayar_fujii");
  const auto b = m.Make<double>();
  const std::vector<double> p = Params(m, "albedo=1,sigma=1");
  // REFERENCE: E(mu = 1) = 0.776522..., E_avg = 0.832811... (Fujii 2012).
  const double e1 = OrenNayarAlbedo(*b, p.data(), 0.0);
  EXPECT_NEAR(e1, 0.776522, 1e-6);
  EXPECT_NEAR(e1, kPi / (kPi + kPi / 2 - 2.0 / 3.0), 1e-12);
  const double avg = AverageAlbedo([&](double t) { return OrenNayarAlbedo(*b, p.data(), t); });
  EXPECT_NEAR(avg, 0.832811, 1e-6);
}

TEST(OrenNayarFujii, AverageAlbedoFormulaForEverySigma) {
  const Model m = Model::Parse("oren_nayar_fujii");
  const auto b = m.Make<double>();
  for (double sigma : {0.0, 0.1, 0.37, 0.5, 0.8, 1.0}) {
    const std::vector<double> p = Params(m, "albedo=1,sigma=" + FormatDouble(sigma));
    const double a = 1 / (kPi + sigma * (kPi / 2 - 2.0 / 3.0)), bb = sigma * a;
    const double avg = AverageAlbedo([&](double t) { return OrenNayarAlbedo(*b, p.data(), t); });
    EXPECT_NEAR(avg, kPi * a + (2 * kPi - 5.6) / 3 * bb, 1e-9) << "sigma " << sigma;
  }
}

TEST(OrenNayarFujii, AlbedoClosedFormPeaksAtRhoAtGrazingView) {
  const Model m = Model::Parse("oren_nayar_fujii");
  const auto b = m.Make<double>();
  for (double sigma : {0.25, 1.0}) {
    const std::vector<double> p = Params(m, "albedo=0.7,sigma=" + FormatDouble(sigma));
    for (double theta_o : {0.2, 0.7, 1.1, 1.5}) {
      EXPECT_NEAR(OrenNayarAlbedo(*b, p.data(), theta_o), FujiiAlbedoClosedForm(0.7, sigma, std::cos(theta_o)), 1e-10)
          << "sigma " << sigma << " theta_o " << theta_o;
    }
    // Energy normalisation: E -> rho at grazing view, and stays below it.
    EXPECT_NEAR(OrenNayarAlbedo(*b, p.data(), kPi / 2 - 1e-6), 0.7, 1e-5);
    double worst = 0;
    for (int k = 1; k < 2000; ++k) worst = std::max(worst, FujiiAlbedoClosedForm(0.7, sigma, k / 2000.0));
    EXPECT_LT(worst, 0.7);
  }
  EXPECT_TRUE(m.Info().energy_conserving);
}

TEST(OrenNayarFujii, NonNegativeOverTheWholeRange) {
  const Model m = Model::Parse("oren_nayar_fujii");
  const auto b = m.Make<double>();
  const std::vector<double> p = Params(m, "albedo=1,sigma=1");
  // s = -1 (both grazing, opposite azimuths) is the minimum, rho A (1 - sigma) = 0.
  const double mu = 1e-9, s = std::sqrt(1 - mu * mu);
  const double f = b->Eval(p.data(), Eigen::Vector3d(s, 0, mu), Eigen::Vector3d(-s, 0, mu))[0];
  EXPECT_GE(f, 0.0);
  EXPECT_LT(f, 1e-8);
  EXPECT_THROW(Params(m, "sigma=1.01"), ModelError);
}

// --- Phong family -------------------------------------------------------------

// Lobe-frame reference for the modified Phong albedo:
// E = ks (n+2)/(2 pi) int_0^1 c^n J(c) dc, c the cosine to the mirror axis
// and J(c) = int_0^2pi max(0, c mu_o + sqrt(1 - c^2) sin_o cos b) db in closed
// form. J has a (c_k - c)^(3/2) point at c_k = sin_o, removed by
// c = c_k (1 - v^2).
double PhongAlbedoLobeFrame(double ks, double n, double mu) {
  const double so = std::sqrt(1 - mu * mu);
  auto J = [&](double c) {
    const double pp = c * mu, q = std::sqrt(std::max(0.0, 1 - c * c)) * so;
    if (q <= pp) return 2 * kPi * pp;
    const double beta = std::acos(-pp / q);
    return 2 * (pp * beta + q * std::sin(beta));
  };
  const GaussLegendre gl(200);
  const double upper = Integrate(gl, {so, 1.0}, [&](double c) { return std::pow(c, n) * J(c); });
  const double lower = Integrate(gl, {0.0, 1.0}, [&](double v) {
    const double c = so * (1 - v * v);
    return std::pow(c, n) * J(c) * 2 * so * v;
  });
  return ks * (n + 2) / (2 * kPi) * (upper + lower);
}

// Albedo of a lobe around the mirror direction: theta graded towards theta_o,
// phi towards pi (the lobe centre).
double MirrorLobeAlbedo(const Bxdf<double>& b, const double* p, double theta_o, int nodes = 32) {
  return Albedo(b, p, theta_o, GradedBreaks(0, kPi / 2, theta_o, 1e-3), GradedBreaks(0, 2 * kPi, kPi, 1e-3), nodes);
}

TEST(Phong, AlbedoAtNormalViewIsKsForEveryExponent) {
  const Model m = Model::Parse("phong");
  const auto b = m.Make<double>();
  for (double n : {1e-3, 0.5, 1.0, 7.3, 100.0, 1e4, 1e6}) {
    const std::vector<double> p = Params(m, "ks=0.63,n=" + FormatDouble(n));
    const double e = Albedo(*b, p.data(), 0.0, BothEndsGraded(1e-5), {0.0, kPi, 2 * kPi}, 24);
    EXPECT_NEAR(e, 0.63, 1e-10) << "n " << n;
  }
}

TEST(Phong, AlbedoAgreesWithLobeFrameIntegral) {
  const Model m = Model::Parse("phong");
  const auto b = m.Make<double>();
  for (double n : {3.0, 20.0, 250.0}) {
    const std::vector<double> p = Params(m, "ks=1,n=" + FormatDouble(n));
    double previous = 1;
    for (double theta_o : {0.1, 0.5, 1.0, 1.3, 1.55}) {
      const double reference = PhongAlbedoLobeFrame(1, n, std::cos(theta_o));
      EXPECT_NEAR(MirrorLobeAlbedo(*b, p.data(), theta_o), reference, 1e-8) << "n " << n << " theta_o " << theta_o;
      // The lobe loses more of itself below the horizon as wo tilts.
      EXPECT_LT(reference, previous);
      previous = reference;
    }
  }
  // One value: n = 1, theta_o = 60 deg.
  EXPECT_NEAR(PhongAlbedoLobeFrame(1, 1, 0.5), MirrorLobeAlbedo(*b, Params(m, "ks=1,n=1").data(), kPi / 3, 64), 1e-7);
}

TEST(Phong, EqualsLafortuneWithMirrorCoefficients) {
  const Model phong = Model::Parse("phong"), laf = Model::Parse("lafortune");
  const auto bp = phong.Make<double>();
  const auto bl = laf.Make<double>();
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0, 1);
  for (double n : {1e-3, 2.0, 45.0, 3e3}) {
    const std::string ns = FormatDouble(n);
    const std::vector<double> pp = Params(phong, "ks=0.1:0.4:0.9,n=" + ns);
    const std::vector<double> pl = Params(laf, "rho=0.1:0.4:0.9,cx=-1,cy=-1,cz=1,n=" + ns);
    for (int k = 0; k < 500; ++k) {
      const Eigen::Vector3d wo = RandomDir(u, rng);
      // Half the wi near the mirror direction, where the lobe is large.
      Eigen::Vector3d wi = RandomDir(u, rng);
      if (k % 2) wi = (Reflect(wo) + 0.05 * RandomDir(u, rng)).normalized();
      const Rgb<double> fp = bp->Eval(pp.data(), wi, wo), fl = bl->Eval(pl.data(), wi, wo);
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(fp[c], fl[c], 1e-13 * std::max(1.0, fp[c]));
      const double pdf_p = bp->Pdf(pp.data(), wo, wi), pdf_l = bl->Pdf(pl.data(), wo, wi);
      EXPECT_NEAR(pdf_p, pdf_l, 1e-9 * std::max(1.0, pdf_p));
      const double u1 = u(rng), u2 = u(rng);
      const BsdfSample<double> sp = bp->Sample(pp.data(), wo, u1, u2), sl = bl->Sample(pl.data(), wo, u1, u2);
      ASSERT_EQ(sp.valid, sl.valid);
      if (sp.valid) {
        EXPECT_LT((sp.wi - sl.wi).norm(), 1e-12);
      }
    }
  }
}

TEST(PhongOriginal, IsNotReciprocalAndReflectsMoreThanItReceives) {
  const Model m = Model::Parse("phong_original");
  const auto b = m.Make<double>();
  EXPECT_FALSE(m.Info().reciprocal);
  EXPECT_FALSE(m.Info().energy_conserving);
  // theta_i = 60 deg, theta_o = 30 deg in the plane of incidence, opposite
  // sides: cos(alpha) = cos 30 deg, so cos^10 = 0.75^5.
  const std::vector<double> p = Params(m, "ks=0.5,n=10");
  const Eigen::Vector3d wi = DirectionFromAngles(kPi / 3, 0), wo = DirectionFromAngles(kPi / 6, kPi);
  const double forward = b->Eval(p.data(), wi, wo)[0], backward = b->Eval(p.data(), wo, wi)[0];
  EXPECT_NEAR(forward, 0.5 * 0.2373046875 / 0.5, 1e-14);
  EXPECT_NEAR(backward, 0.5 * 0.2373046875 / (std::sqrt(3.0) / 2), 1e-14);
  EXPECT_NEAR(forward / backward, std::sqrt(3.0), 1e-13);  // cos_theta_o / cos_theta_i

  // Albedo at normal view ks 2 pi / (n + 1): pi for ks = 1, n = 1.
  for (double n : {1.0, 10.0}) {
    const std::vector<double> q = Params(m, "ks=1,n=" + FormatDouble(n));
    const double e = Albedo(*b, q.data(), 0.0, GradedBreaks(0, kPi / 2, 0, 1e-4), {0.0, kPi, 2 * kPi}, 32);
    EXPECT_NEAR(e, 2 * kPi / (n + 1), 1e-9) << "n " << n;
  }
  const double e1 = Albedo(*b, Params(m, "ks=1,n=1").data(), 0.0, {0.0, kPi / 2}, {0.0, 2 * kPi}, 32);
  EXPECT_GT(e1, 3.14159);
}

// Blinn-Phong at normal view: wi = 2 c h - z with c = cos(theta_h), so
// E = ks (n + 8) int_{1/sqrt 2}^1 c^(n+1) (2 c^2 - 1) dc.
double BlinnPhongNormalAlbedo(double ks, double n) {
  return ks * (n + 8) *
         (2 * (1 - std::pow(2.0, -(n + 4) / 2)) / (n + 4) - (1 - std::pow(2.0, -(n + 2) / 2)) / (n + 2));
}

TEST(BlinnPhong, NormalViewAlbedoClosedFormAndItsExcessOverOne) {
  const Model m = Model::Parse("blinn_phong");
  const auto b = m.Make<double>();
  for (double n : {0.0, 1.0, 8.764, 20.0, 500.0}) {
    const std::vector<double> p = Params(m, "ks=1,n=" + FormatDouble(std::max(n, 1e-3)));
    const double e = Albedo(*b, p.data(), 0.0, GradedBreaks(0, kPi / 2, 0, 1e-4), {0.0, kPi, 2 * kPi}, 32);
    EXPECT_NEAR(e, BlinnPhongNormalAlbedo(1, std::max(n, 1e-3)), 1e-9) << "n " << n;
  }
  EXPECT_NEAR(BlinnPhongNormalAlbedo(1, 0), 1.0, 1e-15);
  EXPECT_NEAR(BlinnPhongNormalAlbedo(1, 8.764), 1.0752012, 1e-7);
  EXPECT_NEAR(BlinnPhongNormalAlbedo(1, 20), 1.0606578, 1e-7);
  EXPECT_FALSE(m.Info().energy_conserving);
}

// --- Lafortune ---------------------------------------------------------------

TEST(Lafortune, UniformCoefficientsDimTheLobeByCToTheN) {
  // cx = cy = cz = c0 at normal view: the lobe is (c0 cos theta_i)^n, albedo rho c0^n.
  const Model m = Model::Parse("lafortune");
  const auto b = m.Make<double>();
  const std::vector<double> p = Params(m, "rho=0.9,cx=0.8,cy=0.8,cz=0.8,n=5");
  const double e = Albedo(*b, p.data(), 0.0, GradedBreaks(0, kPi / 2, 0, 1e-3), {0.0, kPi, 2 * kPi}, 32);
  EXPECT_NEAR(e, 0.9 * std::pow(0.8, 5), 1e-12);
}

TEST(ClassicModels, ReciprocalOnesAreSymmetricBitForBit) {
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> u(0, 1);
  for (const char* spec : {"oren_nayar", "oren_nayar_fujii", "phong", "blinn_phong", "lafortune"}) {
    const Model m = Model::Parse(spec);
    const auto b = m.Make<double>();
    for (int k = 0; k < 300; ++k) {
      std::vector<double> p = m.Info().Defaults();
      if (std::string(spec) == "lafortune") p = Params(m, "cx=0.37,cy=-0.81,cz=0.53,n=7");
      const Eigen::Vector3d wi = RandomDir(u, rng), wo = RandomDir(u, rng);
      ASSERT_TRUE((b->Eval(p.data(), wi, wo) == b->Eval(p.data(), wo, wi)).all()) << spec;
    }
  }
}

TEST(Lafortune, PaperParameterisationMapsAsDocumented) {
  // Paper lobe [C o wi . wo]^n with C = (-0.9, -0.9, 0.7), n = 3:
  // c = C / 0.9, rho = 2 pi / 5 * 0.9^3.
  const Model m = Model::Parse("lafortune");
  const auto b = m.Make<double>();
  const double rho = 2 * kPi / 5 * std::pow(0.9, 3);
  const std::vector<double> p = Params(m, "rho=" + FormatDouble(rho) + ",cx=-1,cy=-1,cz=" + FormatDouble(0.7 / 0.9) + ",n=3");
  for (const auto& [wi, wo] : {std::pair{DirectionFromAngles(0.3, 0.1), DirectionFromAngles(0.5, 3.0)},
                               std::pair{DirectionFromAngles(1.2, 2.0), DirectionFromAngles(0.1, -1.0)},
                               std::pair{DirectionFromAngles(0.9, 0.0), DirectionFromAngles(0.9, kPi)}}) {
    const double base = -0.9 * wi.x() * wo.x() - 0.9 * wi.y() * wo.y() + 0.7 * wi.z() * wo.z();
    EXPECT_NEAR(b->Eval(p.data(), wi, wo)[0], std::pow(std::max(base, 0.0), 3), 1e-14);
  }
}

TEST(Lafortune, AlbedoStaysBelowRhoForGeneralLobes) {
  const Model m = Model::Parse("lafortune");
  const auto b = m.Make<double>();
  for (const char* c : {"cx=1,cy=1,cz=1", "cx=-1,cy=-0.2,cz=0.5", "cx=0.9,cy=-1,cz=0.3", "cx=-1,cy=-1,cz=0.2",
                        "cx=0,cy=0,cz=1"}) {
    const std::vector<double> p = Params(m, std::string("rho=1,n=6,") + c);
    for (double theta_o : {0.0, 0.6, 1.2, 1.5}) {
      const double e = Albedo(*b, p.data(), theta_o, GradedBreaks(0, kPi / 2, theta_o, 1e-3),
                              GradedBreaks(0, 2 * kPi, kPi, 1e-3), 32);
      EXPECT_LE(e, 1.0 + 1e-12) << c << " theta_o " << theta_o;
      EXPECT_GT(e, 0.0) << c << " theta_o " << theta_o;
    }
  }
}

TEST(Lafortune, SumOfLobesIsTheSumWithNumberedNames) {
  const Model sum = Model::Parse("lafortune+lafortune"), one = Model::Parse("lafortune");
  std::vector<std::string> names;
  for (const ParamInfo& q : sum.Info().params) names.push_back(q.name);
  EXPECT_EQ(names, (std::vector<std::string>{"lafortune.rho", "lafortune.cx", "lafortune.cy", "lafortune.cz",
                                             "lafortune.n", "lafortune#2.rho", "lafortune#2.cx", "lafortune#2.cy",
                                             "lafortune#2.cz", "lafortune#2.n"}));
  const std::vector<double> p =
      Params(sum, "lafortune.rho=0.3,lafortune.n=40,lafortune#2.cx=0.7,lafortune#2.cy=0.7,lafortune#2.cz=0.7,"
                  "lafortune#2.n=2,lafortune#2.rho=0.2:0.3:0.4");
  const Eigen::Vector3d wi = DirectionFromAngles(0.5, 0.2), wo = DirectionFromAngles(0.6, 3.0);
  const Rgb<double> expected =
      one.Make<double>()->Eval(p.data(), wi, wo) + one.Make<double>()->Eval(p.data() + 7, wi, wo);
  const Rgb<double> got = sum.Make<double>()->Eval(p.data(), wi, wo);
  for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(got[c], expected[c]);
  // A retro-reflective lobe (c = 1, 1, 1) peaks at wi = wo.
  const auto b = one.Make<double>();
  const std::vector<double> retro = Params(one, "rho=1,cx=1,cy=1,cz=1,n=10");
  EXPECT_NEAR(b->Eval(retro.data(), wo, wo)[0], 12 / (2 * kPi), 1e-14);
  EXPECT_LT(b->Eval(retro.data(), Reflect(wo), wo)[0], 12 / (2 * kPi) * 0.5);
}

// --- all six ---------------------------------------------------------------------

TEST(ClassicModels, InfoFlagsAndExtremesStayFinite) {
  using J = JetN<8>;
  struct Case {
    std::string name;
    bool reciprocal, energy_conserving;
  };
  for (const Case& c : {Case{"oren_nayar", true, false}, Case{"oren_nayar_fujii", true, true},
                        Case{"phong_original", false, false}, Case{"phong", true, true},
                        Case{"blinn_phong", true, false}, Case{"lafortune", true, true}}) {
    SCOPED_TRACE(c.name);
    const Model m = Model::Parse(c.name);
    EXPECT_EQ(m.Info().reciprocal, c.reciprocal);
    EXPECT_EQ(m.Info().energy_conserving, c.energy_conserving);
    ASSERT_LE(m.Info().PackedSize(), 8u);
    const auto bd = m.Make<double>();
    const auto bf = m.Make<float>();
    const auto bj = m.Make<J>();
    std::vector<std::vector<double>> sets = {m.Info().Defaults()};
    for (const char* text : {"n=1e8", "n=1e-3", "sigma=0", "sigma=1", "cx=0,cy=0,cz=0", "cx=1,cy=-1,cz=0.001"}) {
      try {
        sets.push_back(Params(m, text));
      } catch (const ModelError&) {
        // the model has no such parameter
      }
    }
    const double g = 1e-12, s = std::sqrt(1 - g * g);
    const std::vector<Eigen::Vector3d> dirs = {{0, 0, 1}, {s, 0, g}, {-s, 0, g}, {0, s, g},
                                               DirectionFromAngles(0.7, 2.0), DirectionFromAngles(1e-9, 0)};
    for (const auto& p : sets) {
      const std::vector<float> pf(p.begin(), p.end());
      std::vector<J> pj(p.size());
      for (std::size_t k = 0; k < p.size(); ++k) pj[k] = J(p[k], static_cast<int>(k));
      for (const auto& wi : dirs)
        for (const auto& wo : dirs) {
          const Rgb<double> fd = bd->Eval(p.data(), wi, wo);
          const Rgb<float> ff = bf->Eval(pf.data(), wi.cast<float>(), wo.cast<float>());
          const Rgb<J> fj = bj->Eval(pj.data(), wi.cast<J>(), wo.cast<J>());
          for (int ch = 0; ch < 3; ++ch) {
            ASSERT_TRUE(std::isfinite(fd[ch]) && fd[ch] >= 0) << FormatParams(m.Info(), p) << " " << fd[ch];
            ASSERT_TRUE(std::isfinite(ff[ch]) && ff[ch] >= 0) << FormatParams(m.Info(), p) << " " << ff[ch];
            ASSERT_TRUE(std::isfinite(fj[ch].a) && fj[ch].v.allFinite()) << FormatParams(m.Info(), p) << fj[ch];
          }
          const double pdf = bd->Pdf(p.data(), wo, wi);
          ASSERT_TRUE(std::isfinite(pdf) && pdf >= 0);
        }
      for (const auto& wo : dirs) {
        const BsdfSample<double> smp = bd->Sample(p.data(), wo, 0.3, 0.7);
        if (smp.valid) {
          ASSERT_TRUE(std::isfinite(smp.pdf) && smp.pdf > 0 && smp.wi.allFinite());
        }
      }
    }
  }
}

TEST(ClassicModels, SamplingMatchesPdf) {
  struct Case {
    std::string model, params;
  };
  const std::vector<Case> cases = {
      {"oren_nayar", "sigma=0.6"},          {"oren_nayar_fujii", "sigma=0.9"},
      {"phong_original", "n=4"},            {"phong", "n=1.5"},
      {"phong", "n=60"},                    {"blinn_phong", "n=3"},
      {"blinn_phong", "n=80"},              {"lafortune", "cx=-1,cy=-1,cz=1,n=12"},
      {"lafortune", "cx=0.3,cy=-0.9,cz=0.6,n=8"}, {"lafortune", "cx=0.8,cy=0.8,cz=0.4,n=30"},
  };
  const std::vector<double> thetas = {0.0, 45.0, 80.0};
  const double level = 1 - std::pow(1 - 0.01, 1.0 / double(cases.size() * thetas.size()));  // Sidak, 1 %
  for (const Case& c : cases) {
    const Model m = Model::Parse(c.model);
    const auto b = m.Make<double>();
    const std::vector<double> p = Params(m, c.params);
    for (double theta_deg : thetas) {
      SCOPED_TRACE(c.model + " " + c.params + " theta_o " + FormatDouble(theta_deg));
      validate::SamplingCheckOptions opt;
      opt.samples = 100000;
      opt.quadrature = 10;
      opt.seed = 23;
      const auto r = validate::CheckSampling(*b, p.data(), DirectionFromAngles(theta_deg * kPi / 180, 0.9), opt);
      EXPECT_EQ(r.nonfinite, 0);
      EXPECT_EQ(r.pdf_mismatch, 0);
      EXPECT_GT(r.valid_fraction, 0.05);
      EXPECT_NEAR(r.pdf_integral, r.valid_fraction, 5 * std::sqrt(r.valid_fraction / opt.samples) + 1e-3);
      EXPECT_GT(r.p_value, level) << "chi2 " << r.chi2 << " dof " << r.dof;
    }
  }
}

}  // namespace
}  // namespace brdfkit
