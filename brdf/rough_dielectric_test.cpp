// Rough dielectric BSDFs against closed forms and independent computations:
// the smooth limit (Fresnel's equations written with Snell's angles), the
// index-matched limit (the Smith masking of the light direction), generalised
// reciprocity, sampling against the pdf over the sphere, Jet derivatives.
#include <ceres/jet.h>
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <memory>
#include <random>

#include "brdf/model.h"
#include "brdf/quadrature.h"
#include "brdf/rough_dielectric.h"
#include "tests/test_util.h"
#include "validate/sampling_check.h"

namespace brdfkit {
namespace {

using Fn = std::function<double(const Eigen::Vector3d&)>;

// int over the sphere of g(w) dw in polar coordinates about `axis`: composite
// Gauss-Legendre in the angle t to the axis on breaks doubling from t_min
// (to resolve a peak down to about t_min wide there) up to pi, times
// Gauss-Legendre in the azimuth about the axis.
double SphereIntegralAbout(const Eigen::Vector3d& axis, const Fn& g, double t_min = 1e-7) {
  const GaussLegendre gt(16), gp(64);
  Eigen::Vector3d b1, b2;
  BasisFromZ<double>(axis, b1, b2);
  std::vector<double> breaks = {0.0};
  for (double t = t_min; t < kPi; t *= 2) breaks.push_back(t);
  breaks.push_back(kPi);
  double sum = 0;
  for (std::size_t k = 0; k + 1 < breaks.size(); ++k) {
    const double a = breaks[k], b = breaks[k + 1];
    for (int i = 0; i < gt.size(); ++i) {
      const double t = a + (b - a) * gt.node01(i), wt = (b - a) * gt.weight01(i) * std::sin(t);
      for (int j = 0; j < gp.size(); ++j) {
        const double phi = 2 * kPi * gp.node01(j);
        const Eigen::Vector3d w = std::cos(t) * axis + std::sin(t) * (std::cos(phi) * b1 + std::sin(phi) * b2);
        sum += wt * 2 * kPi * gp.weight01(j) * g(w);
      }
    }
  }
  return sum;
}

// Fresnel reflectance of unpolarised light arriving at angle ti in index n1
// on index n2, by Snell's angles (Born & Wolf 1.5.3): 1 past the critical angle.
double FresnelBySnell(double ti, double n1, double n2) {
  const double st = n1 / n2 * std::sin(ti);
  if (st >= 1) return 1.0;
  if (ti == 0) return std::pow((n1 - n2) / (n1 + n2), 2);
  const double tt = std::asin(st);
  const double rs = std::sin(tt - ti) / std::sin(tt + ti), rp = std::tan(ti - tt) / std::tan(ti + tt);
  return 0.5 * (rs * rs + rp * rp);
}

// The mirror and refracted directions of the light direction wi at a smooth
// interface of relative index eta (wi may be on either side).
Eigen::Vector3d Mirror(const Eigen::Vector3d& wi) { return Eigen::Vector3d(-wi.x(), -wi.y(), wi.z()); }
Eigen::Vector3d Refracted(const Eigen::Vector3d& wi, double eta) {
  const double e = wi.z() > 0 ? eta : 1 / eta;  // far side over wi's side
  const double s2 = (1 - wi.z() * wi.z()) / (e * e);
  return Eigen::Vector3d(-wi.x() / e, -wi.y() / e, -std::copysign(std::sqrt(std::max(0.0, 1 - s2)), wi.z()));
}

template <typename M>
class RoughDielectricTest : public ::testing::Test {
 protected:
  M model_{Settings{}};
  double F(const double* p, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) const {
    return model_.template Eval<double>(p, wi, wo)[0];
  }
  std::unique_ptr<Bxdf<double>> Adapter() const {
    return std::make_unique<detail::ModelAdapter<M, double>>(std::make_shared<const M>(Settings{}), M::Info());
  }
};

using Models = ::testing::Types<GgxGlass, GgxGlassCorrelated, BeckmannGlass>;
TYPED_TEST_SUITE(RoughDielectricTest, Models);

Eigen::Vector3d Dir(double theta, double phi, bool inside) {
  Eigen::Vector3d w = test::DirectionFromAngles(theta, phi);
  if (inside) w.z() = -w.z();
  return w;
}

// alpha -> 0: light from wi is reflected in the fraction F of Fresnel's
// equations and refracted in the fraction 1 - F (the power integral over wo,
// int f(wi, wo) |wo.z| dwo, split at the surface); the radiance albedo of wo,
// int f(wi, wo) |wi.z| dwi, is F + (1 - F) eta_wo^2 / eta_wi^2 (pbrt's
// radiance convention). From both sides, below and past the critical angle.
TYPED_TEST(RoughDielectricTest, SmoothLimitIsFresnel) {
  for (double eta : {1.5, 1 / 1.5, 2.4}) {
    const std::vector<double> p = {1e-3, eta};
    for (bool inside : {false, true})
      for (double theta : {0.0, 0.5, 0.8, 1.2}) {
        const Eigen::Vector3d w = Dir(theta, 0.3, inside);
        const double n_here = inside ? eta : 1.0, n_far = inside ? 1.0 : eta;
        const double fr = FresnelBySnell(theta, n_here, n_far);
        SCOPED_TRACE("eta " + std::to_string(eta) + (inside ? " inside" : " outside") + " theta " + std::to_string(theta));
        const auto side = [&](bool same, bool power) {
          return [&, same, power](const Eigen::Vector3d& v) {
            if ((v.z() * w.z() > 0) != same) return 0.0;
            return power ? this->F(p.data(), w, v) * std::abs(v.z()) : this->F(p.data(), v, w) * std::abs(v.z());
          };
        };
        const double r_power = SphereIntegralAbout(Mirror(w), side(true, true));
        const double r_albedo = SphereIntegralAbout(Mirror(w), side(true, false));
        EXPECT_NEAR(r_power, fr, 1e-4);
        EXPECT_NEAR(r_albedo, fr, 1e-4);
        if (fr == 1.0) continue;  // total internal reflection: nothing refracts
        const double t_power = SphereIntegralAbout(Refracted(w, eta), side(false, true));
        const double t_albedo = SphereIntegralAbout(Refracted(w, eta), side(false, false));
        EXPECT_NEAR(t_power, 1 - fr, 1e-4);
        // Radiance seen from w through the interface: scaled by (n_here / n_far)^2.
        EXPECT_NEAR(t_albedo, (1 - fr) * std::pow(n_here / n_far, 2), 1e-4 * std::pow(n_here / n_far, 2));
      }
  }
}

// Smith Lambda written from Heitz 2014 eq. 83 and 86 for an isotropic alpha.
double Lambda(bool ggx, double alpha, double theta) {
  const double at = alpha * std::tan(theta);
  if (ggx) return 0.5 * (std::sqrt(1 + at * at) - 1);
  const double v = 1 / at;
  return 0.5 * (std::erf(v) - 1) + std::exp(-v * v) / (2 * v * std::sqrt(kPi));
}

// eta = 1: no reflection at all, for every roughness; as eta -> 1 the
// refracted light concentrates on -wi with the power G2 / G1(wi) that the
// Smith term lets through (-> 1 as alpha -> 0): G1(wi) = 1 / (1 + Lambda)
// separable, (1 + Lambda) / (1 + 2 Lambda) height-correlated.
// The power int f(wi, wo) |wo.z| dwo is integrated over the facet normal h:
// wo = wi refracted about h (Snell), dwo = (n_i wi.h + n_o wo.h)^2 /
// (n_o^2 |wo.h|) dh (Walter 2007 eq. 17), smooth where the peak in wo is not.
TYPED_TEST(RoughDielectricTest, IndexMatchedInterfaceTransmitsAll) {
  const bool ggx = TypeParam::kDist == MicrofacetDistribution::kGgx;
  const bool correlated = TypeParam::kSmith == SmithForm::kHeightCorrelated;
  std::mt19937_64 rng(4);
  for (double alpha : {0.05, 0.3, 1.0}) {
    const std::vector<double> p1 = {alpha, 1.0};
    for (int k = 0; k < 200; ++k) {
      const Eigen::Vector3d a = test::RandomUpperDirection(rng), b = test::RandomUpperDirection(rng);
      // Zero up to the rounding of Fresnel's rs, rp at eta = 1 (~1e-17 each, squared).
      EXPECT_LT(this->F(p1.data(), a, b), 1e-25);
      EXPECT_LT(this->F(p1.data(), -a, -b), 1e-25);
    }
    for (double theta : {0.0, 0.6, 1.2})
      for (bool inside : {false, true}) {
        const Eigen::Vector3d w = Dir(theta, 0.3, inside);
        const double lambda = theta == 0 ? 0.0 : Lambda(ggx, alpha, theta);
        const double expected = correlated ? (1 + lambda) / (1 + 2 * lambda) : 1 / (1 + lambda);
        double previous_error = 1;
        for (double d : {1e-2, 1e-3, 1e-4}) {
          const double eta = 1 + d, n_i = inside ? eta : 1.0, n_o = inside ? 1.0 : eta;
          const std::vector<double> p = {alpha, eta};
          const double side = inside ? -1.0 : 1.0;
          const double e = test::HemisphereIntegral([&](const Eigen::Vector3d& h) {
            const double c = side * w.dot(h);  // the facet seen from wi's side
            if (c <= 0) return 0.0;
            const double e_rel = n_i / n_o, s2 = (1 - c * c) * e_rel * e_rel;
            if (s2 >= 1) return 0.0;  // total internal reflection
            const Eigen::Vector3d wo = -e_rel * w + (e_rel * c - std::sqrt(1 - s2)) * side * h;
            const double jac = std::pow(n_i * w.dot(h) + n_o * wo.dot(h), 2) / (n_o * n_o * std::abs(wo.dot(h)));
            return this->F(p.data(), w, wo) * std::abs(wo.z()) * jac;
          }, 24, 96, 1e-5, side * w);
          SCOPED_TRACE("alpha " + std::to_string(alpha) + " theta " + std::to_string(theta) + " eta - 1 = " + std::to_string(d));
          EXPECT_LT(std::abs(e - expected), 5 * d);
          EXPECT_LE(std::abs(e - expected), previous_error + 1e-5);  // converges as eta -> 1, to the quadrature's accuracy
          previous_error = std::abs(e - expected);
        }
      }
  }
}

// Generalised reciprocity (Veach 1997 sec. 5.2): f(wi, wo) / eta_wo^2 =
// f(wo, wi) / eta_wi^2, eta_w the index on w's side; RelativeIndex gives
// eta_wi / eta_wo. Refraction pairs are not symmetric: the ratio is eta^2.
TYPED_TEST(RoughDielectricTest, GeneralisedReciprocity) {
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> u(0, 1);
  int refraction_pairs = 0;
  for (int k = 0; k < 4000; ++k) {
    const std::vector<double> p = {std::exp(std::log(1e-3) * u(rng)), 0.3 + 2.5 * u(rng)};
    Eigen::Vector3d wi = test::RandomUpperDirection(rng), wo = test::RandomUpperDirection(rng);
    if (k % 2) wi.z() = -wi.z();
    if (k % 4 > 1) wo.z() = -wo.z();
    const double a = this->F(p.data(), wi, wo), b = this->F(p.data(), wo, wi);
    const double r = this->model_.RelativeIndex(p.data(), wi, wo);
    EXPECT_NEAR(a * r * r, b, 1e-14 * std::max(a * r * r, b) + 1e-300);  // + the denormal range
    if (wi.z() * wo.z() < 0) {
      EXPECT_DOUBLE_EQ(r, wo.z() > 0 ? p[1] : 1 / p[1]);
      refraction_pairs += a > 0;
    } else {
      EXPECT_EQ(r, 1.0);
    }
  }
  EXPECT_GT(refraction_pairs, 200);
}

// Sample against Pdf over the whole sphere: the pdf integrates to the share
// of valid samples (<= 1) and a chi-square test on 20 x 40 bins of (cos
// theta in [-1, 1], phi) accepts the histogram, from both sides.
TYPED_TEST(RoughDielectricTest, SamplingMatchesPdfOverTheSphere) {
  const auto b = this->Adapter();
  const int tests = 2 * 2 * 2 * 3 * 2;
  const double level = 1 - std::pow(1 - 0.01, 1.0 / tests);  // Sidak-corrected 1 % over the family
  for (double alpha : {0.3, 0.7})
    for (double eta : {1.5, 1 / 1.33})
      for (bool inside : {false, true})
        for (double theta : {0.0, 0.8, 1.35}) {
          const std::vector<double> p = {alpha, eta};
          const Eigen::Vector3d wo = Dir(theta, 0.4, inside);
          validate::SamplingCheckOptions opt;
          opt.samples = 100000;
          opt.seed = 23;
          const auto r = validate::CheckSampling(*b, p.data(), wo, opt);
          SCOPED_TRACE("alpha " + std::to_string(alpha) + " eta " + std::to_string(eta) + (inside ? " inside" : " outside") +
                       " theta " + std::to_string(theta));
          EXPECT_EQ(r.nonfinite, 0);
          EXPECT_EQ(r.pdf_mismatch, 0);
          EXPECT_GT(r.valid_fraction, 0.5);
          EXPECT_NEAR(r.pdf_integral, r.valid_fraction, 4 * std::sqrt(r.valid_fraction / opt.samples) + 2e-3);
          EXPECT_LE(r.pdf_integral, 1 + 2e-3);
          // Both hemispheres: the histogram's bins cover the sphere.
          EXPECT_GT(r.p_value, level) << "chi2 " << r.chi2 << " dof " << r.dof;
          EXPECT_GT(r.dof, 40);
        }
}

// Values finite and >= 0 on both sides in double, float and Jet, at the
// parameter bounds and at edge directions (normal, grazing, opposite, mirror).
TYPED_TEST(RoughDielectricTest, FiniteAndNonNegativeEverywhere) {
  using J = ceres::Jet<double, 2>;
  std::vector<Eigen::Vector3d> dirs;
  for (double theta : {0.0, 1e-8, 0.5, 1.3, kPi / 2 - 1e-7, kPi / 2})
    for (double phi : {0.0, 2.0})
      for (bool inside : {false, true}) dirs.push_back(Dir(theta, phi, inside));
  int bad = 0;
  for (double alpha : {1e-4, 0.3, 1.0})
    for (double eta : {0.2, 1.0, 1.5, 5.0}) {
      const double p[2] = {alpha, eta};
      const float pf[2] = {float(alpha), float(eta)};
      const J pj[2] = {J(alpha, 0), J(eta, 1)};
      for (const auto& a : dirs)
        for (const Eigen::Vector3d& b : {dirs[(&a - dirs.data() + 7) % dirs.size()], Eigen::Vector3d(-a), Mirror(a), Refracted(a, eta)}) {
          const double fd = this->model_.template Eval<double>(p, a, b)[0];
          const float ff = this->model_.template Eval<float>(pf, a.cast<float>(), b.cast<float>())[0];
          const J fj = this->model_.template Eval<J>(pj, a.cast<J>(), b.cast<J>())[0];
          const double pdf = this->model_.template Pdf<double>(p, a, b);
          const bool ok = std::isfinite(fd) && fd >= 0 && std::isfinite(ff) && ff >= 0 && std::isfinite(fj.a) &&
                          fj.v.allFinite() && std::isfinite(pdf) && pdf >= 0;
          if (!ok && bad++ < 5)
            ADD_FAILURE() << "alpha " << alpha << " eta " << eta << " wi " << a.transpose() << " wo " << b.transpose()
                          << ": " << fd << " " << ff << " " << fj << " pdf " << pdf;
        }
    }
  EXPECT_EQ(bad, 0);
}

// Jet derivatives by alpha and eta against central finite differences, for
// reflection and refraction pairs on both sides.
TYPED_TEST(RoughDielectricTest, JetDerivativesMatchFiniteDifferences) {
  using J = ceres::Jet<double, 2>;
  std::mt19937_64 rng(12);
  std::uniform_real_distribution<double> u(0, 1);
  int compared = 0;
  for (int k = 0; k < 400; ++k) {
    const double p[2] = {0.02 + 0.9 * u(rng), 0.4 + 2.0 * u(rng)};
    Eigen::Vector3d wi = test::RandomUpperDirection(rng), wo = test::RandomUpperDirection(rng);
    if (k % 2) wi.z() = -wi.z();
    if (k % 4 > 1) wo.z() = -wo.z();
    const J pj[2] = {J(p[0], 0), J(p[1], 1)};
    const J fj = this->model_.template Eval<J>(pj, wi.cast<J>(), wo.cast<J>())[0];
    const double f0 = this->F(p, wi, wo);
    // Same value up to rounding (a Jet divides as a * (1 / b)), amplified by
    // 1 - F near the critical angle.
    ASSERT_NEAR(fj.a, f0, 1e-10 * f0);
    if (!(f0 > 1e-6)) continue;
    for (int j = 0; j < 2; ++j) {
      const auto fd = [&](double h) {
        double a[2] = {p[0], p[1]}, b[2] = {p[0], p[1]};
        a[j] += h;
        b[j] -= h;
        return (this->F(a, wi, wo) - this->F(b, wi, wo)) / (2 * h);
      };
      const double d1 = fd(1e-5 * p[j]), d2 = fd(0.25e-5 * p[j]);
      const double scale = std::max({std::abs(d2), std::abs(fj.v[j]), f0 / p[j]});
      if (std::abs(d1 - d2) > 1e-5 * scale) continue;  // a kink (total internal reflection) within h
      ++compared;
      EXPECT_NEAR(fj.v[j], d2, 1e-6 * scale) << "d f / d p" << j << " wi " << wi.transpose() << " wo " << wo.transpose();
    }
  }
  EXPECT_GT(compared, 300);
}

}  // namespace
}  // namespace brdfkit
