// Torrance-Sparrow and Cook-Torrance: specular reflection off V-groove
// microfacets with the V-groove masking-shadowing term and exact dielectric
// Fresnel reflectance.
//
//   f_r(wi, wo) = ks F(wi.h) D(h) G(wi, wo, h) / (4 cos_theta_i cos_theta_o)
//   G = min(1, 2 (n.h)(n.wo) / (wo.h), 2 (n.h)(n.wi) / (wo.h))
//   h = (wi + wo) / |wi + wo|
//
// torrance_sparrow (Torrance & Sparrow 1967, "Theory for off-specular
// reflection from roughened surfaces", JOSA 57(9)): facet slope angle
// alpha = theta_h with a Gaussian distribution P(alpha) = b exp(-c^2 alpha^2),
// here written D(h) = exp(-(theta_h / m)^2) / N(m) with m = 1/c in radians.
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// cook_torrance (Cook & Torrance 1981, "A reflectance model for computer
// graphics", SIGGRAPH; ACM TOG 1(1) 1982): Beckmann distribution
// D(h) = exp(-tan^2(theta_h) / m^2) / (pi m^2 cos^4(theta_h)) (Walter et al.
// 2007 eq. 25), same G and Fresnel.
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// Constants. Cook & Torrance write R_s = F D G / (pi (N.L)(N.V)) with
// Beckmann's unnormalised D_B = exp(-tan^2 / m^2) / (m^2 cos^4), for which
// int D_B cos dw = pi. brdfkit normalises D (int D cos dw = 1, so D_B = pi D)
// and divides by 4 as in Walter et al. 2007 eq. 20, the factor that comes from
// the half-vector Jacobian dw_h / dw_i = 1 / (4 wi.h). The paper's formula is
// therefore 4 times brdfkit's f_r; printings that carry 4 m^2 in the
// denominator of D_B agree with brdfkit exactly. Fitted ks absorbs the constant.
// Cook & Torrance obtain a per-wavelength index from the measured normal-
// incidence reflectance F0 by n = (1 + sqrt(F0)) / (1 - sqrt(F0)); eta is that
// n per RGB channel (eta = 100 gives F0 = 0.96, bright metals).
//
// Approximations:
//  - Torrance-Sparrow's normalisation N(m) = int exp(-(theta/m)^2) cos(theta) dw
//    = pi m int_0^{pi/(2m)} exp(-t^2) sin(2 m t) dt has no elementary closed
//    form: it is pi m F(m) (F Dawson's function, pi m^2 (1 - 2 m^2/3 + ...))
//    while the horizon cut is negligible, and less for broad lobes. It is
//    computed by 48-point composite Gauss-Legendre in t = theta / m on
//    [0, min(pi / (2m), 9)] (exp(-81) is below double precision): relative
//    error below 1e-15 for m from 1e-7 to 1 against a long-double reference,
//    and differentiable through ceres::Jet.
//  - Fresnel is the unpolarised dielectric formula with a real index; the
//    complex index of metals (used by Cook & Torrance for some spectra) is
//    replaced by the real n that gives the same F0.
//  - The V-groove G is not a Smith masking function and does not satisfy the
//    weak white furnace test; the model is not energy-conserving by
//    construction. It is reciprocal (G and D are symmetric in wi, wo, and
//    F depends on wi.h = wo.h). With ks = 1, F0 = 0.96 the albedo of a smooth
//    surface (m = 0.05) falls from F0 at normal incidence to about 0.62 at
//    89.9 degrees (shadowing), that of a rough one (m = 1) rises from about
//    0.5 to 0.9 (Fresnel); it stayed below 1 in every case computed.
//  - Only the specular term: Torrance-Sparrow's and Cook-Torrance's diffuse
//    term is a separate Lambert lobe ("lambert+cook_torrance").
//
// Sampling: the distribution of normals D(h) cos(theta_h) is sampled exactly
// (Torrance-Sparrow: Newton inversion of its CDF in t = theta/m; Beckmann:
// Gaussian slopes, Walter 2007 eq. 28) and wi is the mirror of wo about h:
// pdf(wi) = D(h) cos(theta_h) / (4 wo.h). Samples below the horizon are
// invalid.
#pragma once

#include "brdf/core.h"
#include "brdf/quadrature.h"
#include "brdf/microfacet.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <type_traits>

namespace brdfkit {

namespace detail {

inline const GaussLegendre01<24>& TsRule() {
  static const GaussLegendre01<24> rule;
  return rule;
}

// sin(2 m t) / m, with its Taylor form where 2 m t is small so that the
// derivative in m has no cancellation (m goes down to 1e-7).
template <typename T>
inline T TsSinRatio(const T& m, const T& t) {
  using std::sin;
  const T x = T(2) * m * t;
  if (x < T(1e-4)) return T(2) * t * (T(1) - x * x / T(6));  // next term x^4/120 < 1e-18
  return sin(x) / m;
}

// int_0^u exp(-t^2) sin(2 m t) / m dt by two 24-point Gauss-Legendre panels.
template <typename T>
inline T TsPartialIntegral(const T& m, const T& u) {
  using std::exp;
  const auto& r = TsRule();
  T sum = T(0);
  const T half = u / T(2);
  for (int panel = 0; panel < 2; ++panel) {
    for (int k = 0; k < 24; ++k) {
      const T t = half * (T(panel) + T(r.x[k]));
      sum += T(r.w[k]) * exp(-t * t) * TsSinRatio(m, t);
    }
  }
  return sum * half;
}

// Upper end of the t = theta/m integration: the horizon, or t = 9 past which
// exp(-t^2) < 1e-35 adds nothing in double precision.
template <typename T>
inline T TsUpper(const T& m) {
  const T horizon = T(kPi / 2) / m;
  return horizon < T(9) ? horizon : T(9);
}

// g(m) = N(m) / (pi m^2), where N(m) = int_hemisphere exp(-(theta/m)^2) cos dw
// = pi m int_0^{pi/(2m)} exp(-t^2) sin(2 m t) dt. g -> 1 as m -> 0.
template <typename T>
inline T TsNormFactor(const T& m) {
  if constexpr (std::is_arithmetic_v<T>) {
    // Plain scalars: double precision once per distinct m (fits and
    // quadratures evaluate many directions at one m).
    thread_local double last_m = -1, last_g = 1;
    const double md = static_cast<double>(m);
    if (md != last_m) {
      last_g = TsPartialIntegral(md, TsUpper(md));
      last_m = md;
    }
    return static_cast<T>(last_g);
  } else {
    return TsPartialIntegral(m, TsUpper(m));
  }
}

// V-groove masking-shadowing (Torrance & Sparrow 1967; Blinn 1977 form).
template <typename T>
inline T VGrooveG(const Vec3<T>& wi, const Vec3<T>& wo, const Vec3<T>& h) {
  const T wo_h = HalfCos(wi, wo);  // not wo.dot(h): it goes negative by rounding for opposite grazing pairs
  const T g_o = T(2) * h.z() * wo.z() / wo_h;
  const T g_i = T(2) * h.z() * wi.z() / wo_h;
  T g = T(1);
  if (g_o < g) g = g_o;
  if (g_i < g) g = g_i;
  return g;
}

}  // namespace detail

enum class VGrooveDistribution { kGaussianAngle, kBeckmann };

// Shared code of torrance_sparrow and cook_torrance; Derived gives the name.
template <typename Derived, VGrooveDistribution Dist>
class VGrooveModel {
 public:
  explicit VGrooveModel(const Settings& = {}) {}

  static constexpr Slot kKs{"ks", 0, true}, kM{"m", 3}, kEta{"eta", 4, true};
  static constexpr std::array kSlots{kKs, kM, kEta};
  static constexpr unsigned kKind = LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;
  static constexpr bool kVanishes = true;  // zero with its colour parameters at 0
  LobeWidth Width(const double* p) const { return {At(p, kM), At(p, kM)}; }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = Derived::kName;
    info.summary = Derived::kSummary;
    using S = ParamInfo::Scale;
    info.params.push_back({"ks", 0.0, 1.0, 1.0, true, "specular weight"});
    if constexpr (Dist == VGrooveDistribution::kGaussianAngle)
      info.params.push_back({"m", 1e-7, 1.0, 0.2, false, "spread of the facet angle (radians)", S::kLog});
    else
      info.params.push_back({"m", 1e-7, 1.0, 0.2, false, "rms facet slope (Beckmann)", S::kLog});
    info.params.push_back({"eta", 1.0, 100.0, 1.5, true, "relative refractive index per channel"});
    info.reciprocal = true;
    info.energy_conserving = false;  // V-groove G fails the weak white furnace test
    return info;
  }

  // Distribution of normals, int D(wm) cos(theta_m) dwm = 1.
  template <typename T>
  T D(const T* p, const Vec3<T>& wm) const {
    using std::atan2;
    using std::exp;
    using std::log;
    if (wm.z() <= T(0)) return T(0);  // back-facing facets do not exist
    const T& m = At(p, kM);
    if constexpr (Dist == VGrooveDistribution::kGaussianAngle) {
      // atan2 instead of acos(z): finite derivative at the normal.
      const T theta = atan2(SafeSqrt(Sin2Theta(wm)), wm.z());
      const T t = theta / m;
      return exp(-t * t) / (T(kPi) * m * m * detail::TsNormFactor(m));
    } else {
      // Beckmann in log form: tan^2/m^2 and 1/cos^4 overflow separately in
      // float near the horizon, their ratio does not.
      const T z2 = wm.z() * wm.z();
      const T e = Sin2Theta(wm) / (z2 * m * m);
      return exp(-e - T(2) * log(z2)) / (T(kPi) * m * m);
    }
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const Vec3<T> h = HalfVector(wi, wo);
    const T scalar = D(p, h) * detail::VGrooveG(wi, wo, h) / (T(4) * wi.z() * wo.z());
    const T cos_d = HalfCos(wi, wo);  // = wi.h, never negative by rounding
    Rgb<T> f;
    for (int c = 0; c < 3; ++c) f[c] = At(p, kKs, c) * FresnelDielectric(At(p, kEta, c), cos_d) * scalar;
    return f;
  }

  template <typename T>
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const {
    if (!SameUpperHemisphere(wi, wo)) return T(0);
    const Vec3<T> h = HalfVector(wi, wo);
    return D(p, h) * h.z() / (T(4) * HalfCos(wi, wo));  // wo.h, never <= 0 by rounding
  }

  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    BsdfSample<T> s;
    if (wo.z() <= T(0)) return s;
    const double m = Value(At(p, kM));
    double sin_t, cos_t;
    if constexpr (Dist == VGrooveDistribution::kGaussianAngle) {
      const double theta = m * SampleScaledAngle(m, u1);
      sin_t = std::sin(theta);
      cos_t = std::cos(theta);
    } else {
      // Beckmann slopes are Gaussian: tan^2 = -m^2 log(1 - u1) (Walter 2007 eq. 28).
      const double tan_t = m * std::sqrt(-std::log1p(-u1));
      cos_t = 1.0 / std::sqrt(1.0 + tan_t * tan_t);
      sin_t = tan_t * cos_t;
    }
    const double phi = 2.0 * kPi * u2;
    const Eigen::Vector3d wm(sin_t * std::cos(phi), sin_t * std::sin(phi), cos_t);
    Eigen::Vector3d wi;
    if (!ReflectAbout(wo, wm, wi)) return s;  // facet seen from behind
    return SampledFrom(*this, p, wo, wi);
  }

  double SampleWeight(const double* p) const {
    double s = 0;
    for (int c = 0; c < 3; ++c) s += At(p, kKs, c) * FresnelDielectric(At(p, kEta, c), 0.5);
    return s / 3.0;
  }

 private:
  // Inverts the CDF of t = theta/m, density exp(-t^2) sin(2 m t) / (m g(m)),
  // by safeguarded Newton iteration from the small-m solution sqrt(-log(1-u)).
  static double SampleScaledAngle(double m, double u) {
    const double upper = detail::TsUpper(m);
    const double g = detail::TsNormFactor(m);
    const double target = u * g;
    double lo = 0, hi = upper;
    double t = std::min(std::sqrt(-std::log1p(-u)), 0.5 * upper);
    for (int it = 0; it < 60; ++it) {
      const double c = detail::TsPartialIntegral(m, t) - target;
      if (c > 0) hi = t;
      else lo = t;
      const double dens = std::exp(-t * t) * detail::TsSinRatio(m, t);
      double next = dens > 0 ? t - c / dens : 0.5 * (lo + hi);
      if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);  // Newton left the bracket
      // Quadratic convergence: a step of 1e-9 leaves an error near 1e-18.
      if (std::abs(next - t) <= 1e-9 * std::max(1.0, t)) return next;
      t = next;
    }
    return t;
  }
};

struct TorranceSparrow : VGrooveModel<TorranceSparrow, VGrooveDistribution::kGaussianAngle> {
  using VGrooveModel::VGrooveModel;
  static constexpr const char* kName = "torrance_sparrow";
  static constexpr const char* kSummary =
      "Torrance-Sparrow 1967: Gaussian facet angles, V-groove masking, dielectric Fresnel";
};

struct CookTorrance : VGrooveModel<CookTorrance, VGrooveDistribution::kBeckmann> {
  using VGrooveModel::VGrooveModel;
  static constexpr const char* kName = "cook_torrance";
  static constexpr const char* kSummary =
      "Cook-Torrance 1981: Beckmann facets, V-groove masking, dielectric Fresnel per channel";
};

}  // namespace brdfkit
