// He et al. 1991, Kajiya 1985 and Poulin & Fournier 1990: values against
// closed forms, independent computations and the papers' qualitative results.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "brdf/he.h"
#include "brdf/kajiya.h"
#include "brdf/microfacet.h"
#include "brdf/model.h"
#include "brdf/params.h"
#include "brdf/poulin_fournier.h"
#include "tests/test_util.h"
#include "brdf/quadrature.h"

namespace brdfkit {
namespace {

using test::DirectionFromAngles;

std::vector<double> Params(const std::string& model, const std::string& text) {
  return ParseParams(Model::Parse(model).Info(), text);
}

double Deg(double d) { return d * kPi / 180; }

// --- He et al. 1991 ----------------------------------------------------------

// Brute-force log of sum_{m>=1} g^m e^-g / (m! m) exp(-c / m) in long double,
// every term up to far past the peak.
long double BruteLogSeries(long double g, long double c) {
  const long double lg = std::log(g);
  std::vector<long double> l;
  const long double top = g + 60 * std::sqrt(g) + std::sqrt(c) * 4 + 200;
  long double peak = -1e300L;
  for (long double m = 1; m <= top; m += 1) {
    l.push_back(m * lg - g - std::lgamma(m + 1) - std::log(m) - c / m);
    peak = std::max(peak, l.back());
  }
  long double s = 0;
  for (long double x : l) s += std::exp(x - peak);
  return std::log(s) + peak;
}

// The series against direct long-double sums on both sides of the switch
// between direct summation and the integral over m (peak width 4, from
// g of about 20), with and without the off-specular factor exp(-c/m).
TEST(He, SeriesMatchesBruteForceAcrossBothEvaluations) {
  double worst = 0;
  for (double g : {1e-6, 0.3, 2.0, 9.0, 15.0, 19.0, 25.0, 60.0, 150.0, 400.0, 3000.0, 2e4}) {
    for (double c : {0.0, 0.5, 5.0, 50.0, 500.0, 5e3}) {
      const double got = detail::HeLogSeries(g, c);
      const long double want = BruteLogSeries(g, c);
      // Compare the sums, relatively: log difference. Each term's exponent
      // m ln g - ln m! is formed from numbers of size g |ln g| in double, so
      // rounding alone allows about 1e-16 g (|ln g| + 1).
      const double err = std::abs(got - static_cast<double>(want));
      const double tol = std::max(1e-13, 1e-15 * g * (std::abs(std::log(g)) + 1));
      worst = std::max(worst, err / tol);
      EXPECT_LT(err, tol) << "g " << g << " c " << c << " got " << got << " want " << static_cast<double>(want);
    }
  }
  RecordProperty("worst_error_over_tolerance", std::to_string(worst));
}

// At wi = wo = n: S = 1, sigma = sigma_0, G = 4, F = F0, v_xy = 0, and
// sum_m g^m / (m! m) = int_0^g (e^t - 1) / t dt, so
// f_dd = F0 4 (pi / 4) (tau / lambda)^2 e^-g int_0^g (e^t - 1) / t dt.
TEST(He, NormalIncidenceMatchesTheExponentialIntegral) {
  const Model m = Model::Parse("he");
  const auto b = m.Make<double>();
  const GaussLegendre gl(40);
  const Eigen::Vector3d n(0, 0, 1);
  for (double sigma0 : {0.005, 0.05, 0.2, 1.0}) {
    const std::vector<double> p = ParseParams(m.Info(), "sigma_0=" + std::to_string(sigma0) +
                                                            ",tau=1.5,n=1.8:2.5:0.6,k=0:3:4,a=0");
    const Rgb<double> f = b->Eval(p.data(), n, n);
    for (int c = 0; c < 3; ++c) {
      const double lambda = p[8 + c];
      const double g = std::pow(4 * kPi * sigma0 / lambda, 2);
      // e^-g int_0^g (e^t - 1)/t dt = int_0^g (e^(t-g) - e^-g) / t dt, in
      // 64 panels graded towards t = g where the integrand peaks.
      double integral = 0;
      for (int k = 0; k < 64; ++k) {
        const double a = g * (1 - std::pow(0.5, k)), e = k == 63 ? g : g * (1 - std::pow(0.5, k + 1));
        for (int i = 0; i < gl.size(); ++i) {
          const double t = a + (e - a) * gl.node01(i);
          integral += (e - a) * gl.weight01(i) * (std::exp(t - g) - std::exp(-g)) / t;
        }
      }
      const double f0 = FresnelConductor(p[2 + c], p[5 + c], 1.0);
      const double want = f0 * 4 * (kPi / 4) * std::pow(1.5 / lambda, 2) * integral;
      EXPECT_NEAR(f[c], want, 1e-10 * want) << "sigma_0 " << sigma0 << " channel " << c;
    }
  }
}

// The delta term's strength at normal incidence is F0 exp(-(4 pi sigma_0 / lambda)^2)
// (S = 1, sigma = sigma_0 there), and falls with roughness.
TEST(He, SpecularReflectanceIsFresnelTimesDebyeWaller) {
  const ModelInfo info = Model::Parse("he").Info();
  double previous = 2;
  for (double sigma0 : {0.001, 0.01, 0.03, 0.06, 0.1}) {
    const std::vector<double> p = ParseParams(info, "sigma_0=" + std::to_string(sigma0) + ",n=1.5,k=0");
    const Rgb<double> r = He::SpecularReflectance(p.data(), Eigen::Vector3d(0, 0, 1));
    for (int c = 0; c < 3; ++c) {
      const double want = 0.04 * std::exp(-std::pow(4 * kPi * sigma0 / p[8 + c], 2));
      EXPECT_NEAR(r[c], want, 1e-15);
    }
    EXPECT_LT(r[1], previous);
    previous = r[1];
  }
  // Off normal, shadowing and the effective roughness enter; still below F.
  const std::vector<double> p = ParseParams(info, "sigma_0=0.02,tau=0.5,n=1.5,k=0");
  const Eigen::Vector3d wi = DirectionFromAngles(Deg(75), 0);
  const Rgb<double> r = He::SpecularReflectance(p.data(), wi);
  const double s = He::Shadowing(p.data(), wi, Eigen::Vector3d(Reflect(wi)));
  const double sigma = He::EffectiveRoughness(p.data(), wi, Eigen::Vector3d(Reflect(wi)));
  EXPECT_LT(sigma, 0.02);
  EXPECT_LT(s, 1);
  EXPECT_NEAR(r[1], FresnelDielectric(1.5, wi.z()) * s * std::exp(-std::pow(4 * kPi * sigma * wi.z() / 0.55, 2)), 1e-15);
}

// Power bookkeeping of the Kirchhoff series: with small slopes (tau >>
// sigma_0, so S = 1 and sigma = sigma_0 near the normal) light arriving along
// the normal leaves either coherently, F0 e^-g, or in rho_dd, F0 (1 - e^-g):
// int rho_dd cos + specular fraction = F0.
TEST(He, DirectionalDiffusePlusSpecularConservesTheFresnelPower) {
  const Model m = Model::Parse("he");
  const auto b = m.Make<double>();
  const Eigen::Vector3d n(0, 0, 1);
  const GaussLegendre gl(24);
  for (const char* text : {"sigma_0=0.02,tau=5", "sigma_0=0.05,tau=5", "sigma_0=0.1,tau=10", "sigma_0=0.05,tau=20"}) {
    const std::vector<double> p = ParseParams(m.Info(), std::string(text) + ",n=1.5:2:1.2,k=0:1:3,a=0");
    const Rgb<double> spec = He::SpecularReflectance(p.data(), n);
    // Isotropic model seen along the normal: 2 pi int f cos sin d theta, in
    // panels graded geometrically towards the normal where the lobe sits.
    Rgb<double> albedo = Rgb<double>::Zero();
    std::vector<double> breaks = {0.0};
    for (double t = 1e-5; t < kPi / 2; t *= 2) breaks.push_back(t);
    breaks.push_back(kPi / 2);
    for (std::size_t k = 0; k + 1 < breaks.size(); ++k)
      for (int i = 0; i < gl.size(); ++i) {
        const double t = breaks[k] + (breaks[k + 1] - breaks[k]) * gl.node01(i);
        const double w = 2 * kPi * (breaks[k + 1] - breaks[k]) * gl.weight01(i) * std::cos(t) * std::sin(t);
        albedo += w * b->Eval(p.data(), DirectionFromAngles(t, 0.3), n);
      }
    for (int c = 0; c < 3; ++c) {
      const double dd = albedo[c];
      const double f0 = FresnelConductor(p[2 + c], p[5 + c], 1.0);
      EXPECT_NEAR(dd + spec[c], f0, 2e-6 * f0) << text << " channel " << c << " dd " << dd << " spec " << spec[c];
      EXPECT_GT(dd, 0.1 * f0);
    }
  }
}

// Shadowing is Smith's with Gaussian slopes of Beckmann alpha = 2 sigma_0 / tau
// times the paper's factor (1 - erfc(nu) / 2); checked against microfacet.h's
// independent Beckmann Lambda.
TEST(He, ShadowingIsSmithBeckmannWithThePapersFactor) {
  const double sigma0 = 0.3, tau = 1.2, alpha = 2 * sigma0 / tau;
  const std::vector<double> p = Params("he", "sigma_0=0.3,tau=1.2");
  const Eigen::Vector3d n(0, 0, 1);
  for (double theta : {0.2, 0.8, 1.2, 1.5, 1.569}) {
    const Eigen::Vector3d w = DirectionFromAngles(theta, 0.3);
    const double nu = tau / (2 * sigma0) / std::tan(theta);
    const double want = (1 - std::erfc(nu) / 2) / (1 + LambdaBeckmann(w, alpha, alpha));
    EXPECT_NEAR(He::Shadowing(p.data(), w, n), want, 1e-12) << theta;
  }
}

// The effective roughness solves eq. 79 and equals sigma_0 with both
// directions normal; it falls towards grazing angles (the paper's Fig. 4).
TEST(He, EffectiveRoughnessSolvesItsEquation) {
  const double sigma0 = 0.4, tau = 1.0;
  const std::vector<double> p = Params("he", "sigma_0=0.4,tau=1");
  const Eigen::Vector3d n(0, 0, 1);
  EXPECT_DOUBLE_EQ(He::EffectiveRoughness(p.data(), n, n), sigma0);
  double previous = sigma0;
  for (double theta : {0.3, 0.7, 1.0, 1.3, 1.5, 1.57}) {
    const Eigen::Vector3d w = DirectionFromAngles(theta, 0), v = DirectionFromAngles(theta, 2.0);
    const double sigma = He::EffectiveRoughness(p.data(), w, v);
    const double k = 2 * std::tan(theta) * std::erfc(tau / (2 * sigma0) / std::tan(theta));
    const double x = detail::HeZ0OverSigma(k / (4 * std::sqrt(kPi / 2)));
    const double z0 = x * sigma0;
    EXPECT_NEAR(std::sqrt(kPi / 2) * z0, sigma0 / 4 * k * std::exp(-z0 * z0 / (2 * sigma0 * sigma0)),
                1e-14 * std::max(z0, 1e-300));
    EXPECT_NEAR(sigma, sigma0 / std::sqrt(1 + x * x), 1e-15);
    EXPECT_LE(sigma, previous);
    previous = sigma;
  }
  EXPECT_LT(previous, 0.5 * sigma0);
}

// sigma_0 >> lambda: the series tends to the geometric-optics (Beckmann,
// alpha = 2 sigma / tau) microfacet model |F|^2 S D / (4 cos_i cos_o).
TEST(He, RoughLimitIsTheBeckmannMicrofacetModel) {
  const ModelInfo info = Model::Parse("he").Info();
  const std::vector<double> p = ParseParams(info, "sigma_0=4,tau=20,n=1.5,k=0,a=0");
  std::mt19937_64 rng(4);
  double worst = 0;
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Vector3d wi = test::RandomUpperDirection(rng), wo = test::RandomUpperDirection(rng);
    if (wi.z() < 0.2 || wo.z() < 0.2) continue;
    const Eigen::Vector3d m = HalfVector(wi, wo);
    const double sigma = He::EffectiveRoughness(p.data(), wi, wo);
    const double alpha = 2 * sigma / 20;
    const double want = FresnelDielectric(1.5, wi.dot(m)) * He::Shadowing(p.data(), wi, wo) *
                        DBeckmann(m, alpha, alpha) / (4 * wi.z() * wo.z());
    if (want < 1e-6) continue;  // far tails: the series' 1/g corrections dominate there
    const double got = He::DirectionalDiffuse(p.data(), wi, wo)[1];
    // The series is sum_m Poisson(m; g) exp(-c/m) / m; expanding about m = g
    // with variance g gives relative corrections of order (1 + X)^2 / g,
    // X = c / g = tan^2(theta_m) / alpha^2.
    const double k = 2 * kPi / 0.55, g = std::pow(k * sigma * (wi.z() + wo.z()), 2);
    const double x = (1 - m.z() * m.z()) / (m.z() * m.z()) / (alpha * alpha);
    const double err = std::abs(got / want - 1);
    EXPECT_LT(err, 2 * (1 + x) * (1 + x) / g) << "g " << g << " X " << x;
    worst = std::max(worst, err);
  }
  RecordProperty("worst_relative_difference", std::to_string(worst));
}

// Angle of the largest f_dd in the plane of incidence.
double PeakAngle(const Bxdf<double>& b, const std::vector<double>& p, double theta_i) {
  const Eigen::Vector3d wi = DirectionFromAngles(theta_i, kPi);
  double best = -1, best_theta = 0;
  for (double t = 0; t < 89.5; t += 0.05) {
    const double f = b.Eval(p.data(), wi, DirectionFromAngles(Deg(t), 0))[1];
    if (f > best) {
      best = f;
      best_theta = t;
    }
  }
  return best_theta;
}

// He et al. Fig. 6-8: for a smooth surface the directional-diffuse lobe
// peaks at the specular angle; as sigma_0 / lambda grows the peak moves
// off-specular, towards grazing.
TEST(He, DirectionalDiffusePeakMovesOffSpecularWithRoughness) {
  const Model m = Model::Parse("he");
  const auto b = m.Make<double>();
  const double theta_i = Deg(45);
  std::vector<double> peaks;
  for (double sigma0 : {0.02, 0.1, 0.2, 0.3, 0.5}) {
    const std::vector<double> p =
        ParseParams(m.Info(), "sigma_0=" + FormatDouble(sigma0) + ",tau=3,n=1.5,k=0,a=0");
    peaks.push_back(PeakAngle(*b, p, theta_i));
  }
  // Measured: 44.95, 45.35, 48.1, 55.85, 79.7 degrees.
  EXPECT_NEAR(peaks.front(), 45.0, 0.1);
  for (std::size_t k = 1; k < peaks.size(); ++k) EXPECT_GT(peaks[k], peaks[k - 1]) << k;
  EXPECT_GT(peaks.back(), 70.0);
}

// --- Kajiya 1985 -------------------------------------------------------------

// Eval against Beckmann & Spizzichino's form written out independently:
// |R|^2 (1 + wi.wo)^2 p(zeta) / (cos_i cos_o (cos_i + cos_o)^4).
TEST(Kajiya, MatchesTheKirchhoffGeometricOpticsForm) {
  const Model m = Model::Parse("kajiya");
  const auto b = m.Make<double>();
  const std::vector<double> p = ParseParams(m.Info(), "sigma_u=0.35,sigma_v=0.08,angle=0.6,n=0.2:1.1:1.6,k=3.5:2.4:1.9");
  std::mt19937_64 rng(8);
  for (int trial = 0; trial < 200; ++trial) {
    const Eigen::Vector3d wi = test::RandomUpperDirection(rng), wo = test::RandomUpperDirection(rng);
    const Eigen::Vector3d h = wi + wo;
    const double zx = -h.x() / h.z(), zy = -h.y() / h.z();
    const double zu = std::cos(0.6) * zx + std::sin(0.6) * zy, zv = -std::sin(0.6) * zx + std::cos(0.6) * zy;
    const double slope_pdf = std::exp(-0.5 * (zu * zu / (0.35 * 0.35) + zv * zv / (0.08 * 0.08))) / (2 * kPi * 0.35 * 0.08);
    const double geometry = std::pow(1 + wi.dot(wo), 2) / (wi.z() * wo.z() * std::pow(wi.z() + wo.z(), 4));
    const Rgb<double> f = b->Eval(p.data(), wi, wo);
    for (int c = 0; c < 3; ++c) {
      const double want = FresnelConductor(p[3 + c], p[6 + c], wi.dot(h.normalized())) * geometry * slope_pdf;
      EXPECT_NEAR(f[c], want, 1e-12 * want + 1e-300);
    }
  }
}

// Isotropic slopes: the Beckmann microfacet model with alpha = sqrt(2) sigma
// and no shadowing; rotating the axes by 90 degrees swaps sigma_u and sigma_v.
TEST(Kajiya, IsotropicAndRotatedCases) {
  const Model m = Model::Parse("kajiya");
  const auto b = m.Make<double>();
  const std::vector<double> iso = ParseParams(m.Info(), "sigma_u=0.2,sigma_v=0.2,n=1.5,k=0");
  const std::vector<double> a = ParseParams(m.Info(), "sigma_u=0.3,sigma_v=0.05,angle=0.2");
  const std::vector<double> r = ParseParams(m.Info(), "sigma_u=0.05,sigma_v=0.3,angle=" + FormatDouble(0.2 + kPi / 2));
  std::mt19937_64 rng(9);
  for (int trial = 0; trial < 100; ++trial) {
    const Eigen::Vector3d wi = test::RandomUpperDirection(rng), wo = test::RandomUpperDirection(rng);
    const Eigen::Vector3d h = HalfVector(wi, wo);
    const double alpha = std::sqrt(2.0) * 0.2;
    const double want = FresnelDielectric(1.5, wi.dot(h)) * DBeckmann(h, alpha, alpha) / (4 * wi.z() * wo.z());
    EXPECT_NEAR(b->Eval(iso.data(), wi, wo)[0], want, 1e-12 * want + 1e-300);
    const double fa = b->Eval(a.data(), wi, wo)[0], fr = b->Eval(r.data(), wi, wo)[0];
    EXPECT_NEAR(fa, fr, 1e-9 * fa + 1e-300);
  }
}

// Kajiya's brushed-surface highlight: a lobe stretched across the grooves.
// At normal incidence the BRDF 20 degrees away across the grooves is far
// above the value 20 degrees along them; and with no shadowing the albedo
// exceeds 1 at grazing (the limitation the doc block states).
TEST(Kajiya, AnisotropicHighlightAndGrazingAlbedo) {
  const Model m = Model::Parse("kajiya");
  const auto b = m.Make<double>();
  const std::vector<double> p = ParseParams(m.Info(), "sigma_u=0.3,sigma_v=0.05,angle=0,n=1,k=20");
  const Eigen::Vector3d n(0, 0, 1);
  const double across = b->Eval(p.data(), n, DirectionFromAngles(Deg(20), 0))[0];
  const double along = b->Eval(p.data(), n, DirectionFromAngles(Deg(20), kPi / 2))[0];
  EXPECT_GT(across, 100 * along);  // exp(-tan^2(10 deg) / 2 (1/0.05^2 - 1/0.3^2)) = 1/422
  auto albedo = [&](double theta) {
    const Eigen::Vector3d wo = DirectionFromAngles(theta, 0.3);
    return test::HemisphereIntegral([&](const Eigen::Vector3d& wi) { return b->Eval(p.data(), wi, wo)[0] * wi.z(); },
                                    24, 96, 1e-5);
  };
  const double e0 = albedo(0), eg = albedo(Deg(88));
  const double f0 = FresnelConductor(1.0, 20.0, 1.0);
  EXPECT_NEAR(e0, f0, 0.05);  // F varies little over the lobe; the lobe stays above the horizon
  EXPECT_GT(eg, 1.0);
}

// Nearly opposite grazing pair (mu = 1e-12, azimuths 2.1 and 2.1 + pi): wi.wo
// rounds to -1 and a dot product with the half vector can come out negative.
// The exact pair at azimuths 0 and pi has the same half vector (the normal) to
// 5e-5 rad and no rounding in it: the values must agree.
struct OppositeGrazing {
  static constexpr double kMu = 1e-12;
  Eigen::Vector3d wi{std::cos(2.1), std::sin(2.1), kMu}, wo{std::cos(2.1 + kPi), std::sin(2.1 + kPi), kMu};
  Eigen::Vector3d wi_exact{1, 0, kMu}, wo_exact{-1, 0, kMu};
};

TEST(Kajiya, OppositeGrazingPairStaysPositive) {
  const Model m = Model::Parse("kajiya");
  const auto b = m.Make<double>();
  const std::vector<double> p = m.Info().Defaults();
  const OppositeGrazing g;
  ASSERT_LT(1 + g.wi.dot(g.wo), 1e-20);  // the rounding the case is about
  // m = z: D = 1 / (2 pi su sv), wo.m = mu.
  const double d = 1 / (2 * kPi * p[0] * p[1]);
  const double pdf = b->Pdf(p.data(), g.wo, g.wi);
  EXPECT_NEAR(pdf / (d / (4 * g.kMu)), 1, 1e-5);
  const double want = FresnelConductor(p[3], p[6], g.kMu) * d / (4 * g.kMu * g.kMu);
  for (int c = 0; c < 3; ++c) {
    const double f = b->Eval(p.data(), g.wi, g.wo)[c];
    ASSERT_TRUE(std::isfinite(f));
    EXPECT_NEAR(f / want, 1, 1e-5);
  }
}

TEST(He, OppositeGrazingPairStaysPositive) {
  const Model m = Model::Parse("he");
  const auto b = m.Make<double>();
  const std::vector<double> p = m.Info().Defaults();
  const OppositeGrazing g;
  const double pdf = b->Pdf(p.data(), g.wo, g.wi), pdf_exact = b->Pdf(p.data(), g.wo_exact, g.wi_exact);
  ASSERT_GT(pdf_exact, 0);
  EXPECT_NEAR(pdf / pdf_exact, 1, 1e-4);
  const Rgb<double> f = b->Eval(p.data(), g.wi, g.wo), f_exact = b->Eval(p.data(), g.wi_exact, g.wo_exact);
  for (int c = 0; c < 3; ++c) {
    ASSERT_TRUE(std::isfinite(f[c]));
    EXPECT_GE(f[c], p[11 + c] * kInvPi);  // at least the uniform-diffuse term
    EXPECT_NEAR(f[c] / f_exact[c], 1, 1e-4);
  }
}

// --- Poulin & Fournier 1990 ----------------------------------------------------

// Independent computation of the cross-section average: points along one
// period (arc and plane), each tested for light and view by explicit
// ray-circle and ray-plane intersection against the neighbouring cylinders,
// midpoint rule.
Rgb<double> BruteForcePf(const std::vector<double>& p, const Eigen::Vector3d& wi_w, const Eigen::Vector3d& wo_w,
                         int samples) {
  const Eigen::Vector3d wi = PoulinFournier::ToCylinderFrame(p.data(), wi_w);
  const Eigen::Vector3d wo = PoulinFournier::ToCylinderFrame(p.data(), wo_w);
  const double e = p[6], d = p[7], h = p[8];
  const double theta_m = std::acos(1 - h), w = std::sin(theta_m), period = 2 * w + d;
  const Eigen::Vector2d cz(0, h - 1);  // cylinder centre in (x, z)
  auto free = [&](const Eigen::Vector2d& q, const Eigen::Vector3d& dir) {
    const Eigen::Vector2d l = Eigen::Vector2d(dir.x(), dir.z()).normalized();
    for (int k = -3; k <= 3; ++k) {
      const Eigen::Vector2d c = cz + Eigen::Vector2d(k * period, 0);
      const Eigen::Vector2d oc = c - q;
      const double t = oc.dot(l), dist2 = oc.squaredNorm() - t * t;
      if (dist2 >= 1) continue;
      const double t_hit = t - std::sqrt(1 - dist2);
      if (t_hit > 1e-9) return false;
    }
    return true;
  };
  auto local = [&](const Eigen::Vector3d& n, int c) {
    const double ci = wi.dot(n), co = wo.dot(n);
    if (ci <= 0 || co <= 0) return 0.0;
    const Eigen::Vector3d r = 2 * ci * n - wi;
    const double lobe = r.dot(wo) > 0 ? std::pow(r.dot(wo), e) : 0.0;
    return (p[c] / kPi + p[3 + c] * (e + 2) / (2 * kPi) * lobe) * ci * co;
  };
  Rgb<double> sum = Rgb<double>::Zero();
  // Arc: parameter theta, arc length d theta.
  for (int s = 0; s < samples; ++s) {
    const double theta = -theta_m + 2 * theta_m * (s + 0.5) / samples;
    const Eigen::Vector2d q = cz + Eigen::Vector2d(std::sin(theta), std::cos(theta));
    const Eigen::Vector3d n(std::sin(theta), 0, std::cos(theta));
    if (!free(q, wi) || !free(q, wo)) continue;
    for (int c = 0; c < 3; ++c) sum[c] += local(n, c) * 2 * theta_m / samples;
  }
  for (int s = 0; s < samples && d > 0; ++s) {
    const Eigen::Vector2d q(w + d * (s + 0.5) / samples, 0);
    if (!free(q, wi) || !free(q, wo)) continue;
    for (int c = 0; c < 3; ++c) sum[c] += local(Eigen::Vector3d(0, 0, 1), c) * d / samples;
  }
  return sum / (period * wi.z() * wo.z());
}

TEST(PoulinFournier, ShadowingAndMaskingMatchRayTracedCrossSection) {
  const Model m = Model::Parse("poulin_fournier");
  const auto b = m.Make<double>();
  std::mt19937_64 rng(12);
  const std::vector<std::string> cases = {"kd=0.4,ks=0.5,e=8,d=0.5,h=1,angle=0.3",
                                          "kd=0.2,ks=0.7,e=30,d=0,h=1,angle=1.1",
                                          "kd=0.3,ks=0.3,e=5,d=1.5,h=0.4,angle=2.0",
                                          "kd=0.5,ks=0.2,e=2,d=0.2,h=0.1,angle=0.0"};
  double worst = 0;
  for (const std::string& text : cases) {
    const std::vector<double> p = ParseParams(m.Info(), text);
    for (int trial = 0; trial < 25; ++trial) {
      Eigen::Vector3d wi = test::RandomUpperDirection(rng), wo = test::RandomUpperDirection(rng);
      if (trial % 3 == 0) {  // grazing pairs, where most of the period is in shadow
        wi = DirectionFromAngles(Deg(80 + 9 * (trial % 2)), 2 * kPi * trial / 25);
        wo = DirectionFromAngles(Deg(70 + trial % 19), 3.0 * trial);
      }
      const Rgb<double> got = b->Eval(p.data(), wi, wo);
      const Rgb<double> want = BruteForcePf(p, wi, wo, 20000);
      for (int c = 0; c < 3; ++c) {
        const double err = std::abs(got[c] - want[c]) / std::max(want[c], 1e-3);
        worst = std::max(worst, err);
        EXPECT_LT(err, 2e-3) << text << " wi " << wi.transpose() << " wo " << wo.transpose() << " got " << got[c]
                             << " want " << want[c];
      }
    }
  }
  RecordProperty("worst_relative_difference", std::to_string(worst));
}

// Diffuse material at normal incidence and view: nothing is shadowed, and
// f = kd / pi (int_{-theta_m}^{theta_m} cos^2 + d) / P in closed form.
TEST(PoulinFournier, DiffuseNormalIncidenceClosedForm) {
  const Model m = Model::Parse("poulin_fournier");
  const auto b = m.Make<double>();
  for (double h : {0.05, 0.5, 1.0}) {
    for (double d : {0.0, 0.7, 4.0}) {
      const std::vector<double> p = ParseParams(m.Info(), "kd=0.6,ks=0,d=" + std::to_string(d) + ",h=" + std::to_string(h));
      const double tm = std::acos(1 - h), period = 2 * std::sin(tm) + d;
      const double want = 0.6 / kPi * (tm + std::sin(2 * tm) / 2 + d) / period;
      const Eigen::Vector3d n(0, 0, 1);
      EXPECT_NEAR(b->Eval(p.data(), n, n)[0], want, 1e-14) << h << " " << d;
    }
  }
}

// Low, widely spaced cylinders: the plane's modified Phong BRDF.
TEST(PoulinFournier, FlatLimitIsThePlanePhong) {
  const Model m = Model::Parse("poulin_fournier");
  const auto b = m.Make<double>();
  const std::vector<double> p = ParseParams(m.Info(), "kd=0.2,ks=0.6,e=20,d=10,h=0.01");
  std::mt19937_64 rng(2);
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Vector3d wi = test::RandomUpperDirection(rng);
    const Eigen::Vector3d wo = (Reflect(wi) + 0.2 * test::RandomUpperDirection(rng)).normalized();
    if (wi.z() < 0.3 || wo.z() < 0.3) continue;
    const double lobe = std::pow(std::max(0.0, Reflect(wi).dot(wo)), 20);
    const double want = 0.2 / kPi + 0.6 * 22 / (2 * kPi) * lobe;
    EXPECT_NEAR(b->Eval(p.data(), wi, wo)[0], want, 0.03 * want);
  }
}

// The arc's specular integral against a 4000-panel reference over the same
// lit-and-seen intervals, up to e = 1e4 (lobes 0.005 rad wide in theta).
TEST(PoulinFournier, SpecularQuadratureAccuracy) {
  const Model m = Model::Parse("poulin_fournier");
  const auto b = m.Make<double>();
  const GaussLegendre gl(8);
  std::mt19937_64 rng(21);
  double worst = 0;
  for (double e : {1.0, 10.0, 100.0, 1e3, 1e4}) {
    const std::vector<double> p = ParseParams(m.Info(), "kd=0,ks=1,d=0.3,h=0.8,angle=0.4,e=" + std::to_string(e));
    for (int trial = 0; trial < 20; ++trial) {
      const Eigen::Vector3d wi = test::RandomUpperDirection(rng);
      // wo near the reflected band so the lobe is hit: mirror about a random arc normal.
      const double theta = (2 * std::uniform_real_distribution<double>(0, 1)(rng) - 1) * 0.9;
      const Eigen::Vector3d nc(std::sin(theta), 0, std::cos(theta));
      const Eigen::Vector3d n = Eigen::Vector3d(-std::sin(0.4) * nc.x(), std::cos(0.4) * nc.x(), nc.z());
      const Eigen::Vector3d wo = 2 * wi.dot(n) * n - wi;
      if (wo.z() < 0.05 || wi.dot(n) <= 0) continue;
      const Eigen::Vector3d a = PoulinFournier::ToCylinderFrame(p.data(), wi);
      const Eigen::Vector3d c = PoulinFournier::ToCylinderFrame(p.data(), wo);
      detail::PfSet<double> arc_i, plane_i, arc_o, plane_o;
      PoulinFournier::LitSets(p.data(), a, arc_i, plane_i);
      PoulinFournier::LitSets(p.data(), c, arc_o, plane_o);
      const auto arc = detail::PfIntersect(arc_i, arc_o);
      const auto plane = detail::PfIntersect(plane_i, plane_o);
      // The lobe's support cos(2 (t - t*)) > y_i y_o / (r_i r_o): the
      // reference splits there, where max(0, .)^e has its kink.
      const double ai = std::atan2(a.x(), a.z()), ao = std::atan2(c.x(), c.z());
      const double amp = std::hypot(a.x(), a.z()) * std::hypot(c.x(), c.z());
      const double t0 = 0.5 * std::acos(std::clamp(a.y() * c.y() / amp, -1.0, 1.0));
      double spec = 0;
      for (int k = 0; k < arc.n; ++k) {
        const double lo = std::max(arc.lo[k], 0.5 * (ai + ao) - t0), hi = std::min(arc.hi[k], 0.5 * (ai + ao) + t0);
        if (!(lo < hi)) continue;
        const int panels = 4000;
        const double len = (hi - lo) / panels;
        for (int j = 0; j < panels; ++j)
          for (int q = 0; q < gl.size(); ++q) {
            const double t = lo + len * (j + gl.node01(q));
            const Eigen::Vector3d nn(std::sin(t), 0, std::cos(t));
            const double ci = a.dot(nn), co = c.dot(nn);
            const double rr = (2 * ci * nn - a).dot(c);
            spec += len * gl.weight01(q) * (rr > 0 ? std::pow(rr, e) : 0.0) * ci * co;
          }
      }
      double plane_len = 0;
      for (int k = 0; k < plane.n; ++k) plane_len += plane.hi[k] - plane.lo[k];
      const double period = 2 * std::sqrt(0.8 * 1.2) + 0.3;
      const double norm = (e + 2) / (2 * kPi);
      const double want = norm * spec / (period * wi.z() * wo.z()) +
                          norm * std::pow(std::max(0.0, Reflect(wi).dot(wo)), e) * plane_len / period;
      const double got = b->Eval(p.data(), wi, wo)[0];
      if (want < 1e-8) continue;
      const double err = std::abs(got / want - 1);
      worst = std::max(worst, err);
      EXPECT_LT(err, 1e-10) << "e " << e;
    }
  }
  RecordProperty("worst_relative_error", std::to_string(worst));
}

// Poulin & Fournier's anisotropic highlight: cylinders along x reflect a
// normal light into a band across them (the y-z plane), not along them.
TEST(PoulinFournier, HighlightSpreadsAcrossTheCylinders) {
  const Model m = Model::Parse("poulin_fournier");
  const auto b = m.Make<double>();
  const std::vector<double> p = ParseParams(m.Info(), "kd=0,ks=0.8,e=200,d=0.2,h=1,angle=0");
  const Eigen::Vector3d n(0, 0, 1);
  const double across = b->Eval(p.data(), n, DirectionFromAngles(Deg(40), kPi / 2))[0];
  const double along = b->Eval(p.data(), n, DirectionFromAngles(Deg(40), 0))[0];
  EXPECT_GT(across, 0.1);
  EXPECT_LT(along, 1e-6 * across);
}

// Both directions grazing (mu = 1e-12) from the same side, across the
// cylinders: only a 2e-6 rad cap of each cylinder top is lit and seen (the
// plane is in shadow), and the value is that cap's integral divided by
// P mu_i mu_o = 2.5e-24. Reference: the cap edges solved independently from
// the tangent-ray condition (distance from the neighbour's centre to the ray
// = 1) and the facing condition, and the cap integrated in long double.
TEST(PoulinFournier, GrazingPairMatchesTheLitCap) {
  const Model m = Model::Parse("poulin_fournier");
  const auto b = m.Make<double>();
  std::vector<double> p = ParseParams(m.Info(), "kd=0.1,ks=0.5,e=50,d=0.5,h=1");
  p[9] = kPi / 2;  // cylinder axis along y, as the stress sweep sets it
  const Eigen::Vector3d wi_w(1, 0, 1e-12), wo_w(0.50484610459985702, -0.86320936664887404, 1e-12);
  const Eigen::Vector3d wi = PoulinFournier::ToCylinderFrame(p.data(), wi_w);
  const Eigen::Vector3d wo = PoulinFournier::ToCylinderFrame(p.data(), wo_w);
  ASSERT_LT(wi.x(), 0);
  ASSERT_LT(wo.x(), 0);
  const long double period = 2.5L;  // 2 sin(theta_m) + d with h = 1
  // Both directions come from -x: the neighbour at (-P, 0) shadows; the arc
  // point (sin t, cos t) is free iff the ray towards the light passes at
  // distance >= 1 from it. Lower edge of the free cap by bisection.
  auto lower_edge = [&](const Eigen::Vector3d& w) {
    const long double r = std::hypot((long double)w.x(), (long double)w.z());
    const long double lx = w.x() / r, lz = w.z() / r;
    auto blocked = [&](long double t) {
      const long double cx = -period - std::sin(t), cz = -std::cos(t);
      return std::abs(cx * lz - cz * lx) < 1;
    };
    long double lo = -0.5L, hi = 0;  // blocked at lo, free at hi
    for (int it = 0; it < 200; ++it) {
      const long double mid = (lo + hi) / 2;
      (blocked(mid) ? lo : hi) = mid;
    }
    return hi;
  };
  // Facing edge: w.n = x sin t + z cos t = 0.
  auto facing_edge = [](const Eigen::Vector3d& w) { return std::atan2((long double)w.z(), -(long double)w.x()); };
  const long double lo = std::max(lower_edge(wi), lower_edge(wo));
  const long double hi = std::min(facing_edge(wi), facing_edge(wo));
  ASSERT_LT(lo, hi);
  const int n = 20000;
  Rgb<double> want = Rgb<double>::Zero();
  for (int j = 0; j < n; ++j) {
    const long double t = lo + (hi - lo) * (j + 0.5L) / n;
    const long double st = std::sin(t), ct = std::cos(t);
    const long double ci = wi.x() * st + wi.z() * ct, co = wo.x() * st + wo.z() * ct;
    const long double rr = 2 * ci * (wo.x() * st + wo.z() * ct) - (wi.x() * wo.x() + wi.y() * wo.y() + wi.z() * wo.z());
    const long double lobe = rr > 0 ? std::pow(rr, 50.0L) : 0.0L;
    for (int c = 0; c < 3; ++c)
      want[c] += double((p[c] / kPi + p[3 + c] * 52 / (2 * kPi) * lobe) * ci * co * (hi - lo) / n /
                        (period * wi.z() * wo.z()));
  }
  const Rgb<double> f = b->Eval(p.data(), wi_w, wo_w);
  for (int c = 0; c < 3; ++c) {
    ASSERT_TRUE(std::isfinite(f[c]));
    EXPECT_GT(want[c], 1e3);  // the cap is lit: a large positive value
    EXPECT_NEAR(f[c] / want[c], 1, 1e-6);
  }
  EXPECT_GE(b->Pdf(p.data(), wo_w, wi_w), 0);
  EXPECT_TRUE(std::isfinite(b->Pdf(p.data(), wo_w, wi_w)));
}

}  // namespace
}  // namespace brdfkit
