// He, Torrance, Sillion & Greenberg 1991, "A comprehensive physical model for
// light reflection", SIGGRAPH 91 (Computer Graphics 25(4)): Kirchhoff
// scattering from an isotropic Gaussian random surface (height rms sigma_0,
// Gaussian autocorrelation of length tau) with Smith shadowing, a complex
// Fresnel coefficient and the effective roughness of shadowed surfaces.
//
//   rho_bd = rho_sp + rho_dd + rho_ud        (the paper's summary of the model)
//
// Notation (the paper's): k_i = -wi is the incident propagation direction,
// k_r = wo; v = k (k_r - k_i) = k h with h = wi + wo and k = 2 pi / lambda,
// v_xy = k |h_xy|, v_z = k (cos_i + cos_o).
//
// Directional diffuse (the summary formulas for rho_dd and D):
//   rho_dd = |F|^2 G S D / (pi cos_i cos_o)
//   D = (pi^2 tau^2 / (4 lambda^2)) sum_{m>=1} g^m e^-g / (m! m) exp(-v_xy^2 tau^2 / (4 m))
//   g = ((2 pi sigma / lambda) (cos_i + cos_o))^2
//   G = (v.v / v_z)^2 |k_r x k_i|^-4 [(s_r.k_i)^2 + (p_r.k_i)^2] [(s_i.k_r)^2 + (p_i.k_r)^2]
//     (v as the unit-vector difference k_r - k_i). For unpolarised light each
//     bracket is |k_r x k_i|^2 (s, p, k form an orthonormal triad), so
//     G = (h.h / h_z)^2 exactly.
//   F: Fresnel reflectance (unpolarised, mean of s and p) of the complex index
//     n + ik at the local angle of incidence cos = wi.h / |h| (the bisector).
// Shadowing (the paper's S, after Smith 1967):
//   S = S(theta_i) S(theta_o),  S(theta) = (1 - erfc(nu) / 2) / (Lambda + 1),
//   Lambda = (exp(-nu^2) / (sqrt(pi) nu) - erfc(nu)) / 2,  nu = tau cot(theta) / (2 sigma_0).
// Effective roughness (the paper's sigma, z0 and K):
//   sigma = sigma_0 / sqrt(1 + z0^2 / sigma_0^2),
//   sqrt(pi / 2) z0 = (sigma_0 / 4) (K_i + K_o) exp(-z0^2 / (2 sigma_0^2)),
//   K = tan(theta) erfc(tau cot(theta) / (2 sigma_0)),
//   solved for x = z0 / sigma_0 by Newton's method on log x (the equation is
//   monotone in log x); the last steps run in T so fits get the derivative of
//   the root (implicit function theorem).
// Uniform diffuse: rho_ud = a(lambda) / pi here, a being the
//   hemispherical reflectance of the subsurface term (the paper's a(lambda)
//   is that value divided by pi).
//
// The series. Term m is exp(l_m), l_m = m ln g - g - ln m! - ln m - v_xy^2 tau^2 / (4 m),
// log-concave in m for m >= 2. It is summed in log space (no overflow of
// g^m or m!) outward from its largest term; on each side it stops once the
// tail bound t_j r / (1 - r) (log-concavity: the ratio r of successive terms
// only falls) is below 1e-17 of the sum, so the truncation error is bounded by
// 2e-17 relative. When the peak is wide (Gaussian width w = (-l'')^-1/2 >= 4
// terms, from g of about 20 upwards) and 10 w away from m = 1, the sum is
// replaced by the integral of the same smooth function of m over +-12 w by a
// 192-point composite Gauss-Legendre rule: by Poisson summation the
// difference is of order exp(-2 pi^2 w^2) < 1e-100 relative. What remains is
// rounding: l_m is formed from numbers of size g |ln g|, so the result carries
// a relative error of about 1e-16 g (|ln g| + 1) (measured against long-double
// direct sums for g from 1e-6 to 2e4: within 1e-15 g (|ln g| + 1), and below
// 1e-13 for g < 20). The cost is constant in g, up to ~1e6 (sigma_0 / lambda
// ~ 100). For g >> 1 the result tends to the geometric-optics limit
// |F|^2 S D_Beckmann(alpha = 2 sigma / tau) / (4 cos_i cos_o), with relative
// corrections of order (1 + tan^2(theta_m) / alpha^2)^2 / g, which the tests
// check. With small slopes at normal incidence the directional-diffuse
// albedo plus the specular fraction equals F0 to 2e-6 (the power the
// Kirchhoff model takes from the coherent beam goes into rho_dd).
//
// The specular term rho_sp = |F(theta_i)|^2 e^-g S Delta / (cos_i d omega_i)
// is a Dirac delta about the mirror direction: it is NOT part of Eval
// (a delta has no finite value to evaluate, check, tabulate or fit against
// finitely many measured directions; measured peaks belong to rho_dd, which
// holds all the light of a rough surface). Its strength, the fraction of the
// incident power reflected coherently into the mirror direction,
// |F(theta_i)|^2 e^-g S(theta_i)^2 with g at theta_o = theta_i, is given per
// channel by He::SpecularReflectance. Checks of Eval therefore see only
// rho_dd + rho_ud: the albedo they report leaves out that fraction.
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// The default k is 0.5, not 0: F depends on k through k^2, so k = 0 is a
// stationary point from which a fit could not move k.
//
// Properties: reciprocal (every factor is symmetric in wi, wo, and the
// effective roughness uses K_i + K_o). Not energy-conserving by construction:
// the Kirchhoff approximation and the uncorrelated product S(theta_i)
// S(theta_o) bound nothing, and a is free; brdfkit check reports what it finds.
//
// Sampling: a mixture of cosine sampling (weight mean(a) + 0.05, which also
// covers the wide tails of rho_dd), and half-vector sampling of two Beckmann
// lobes, the geometric-optics one (alpha = 2 sigma_0 / tau) and the
// smooth-surface one of the m = 1 term (alpha = lambda / (2 pi tau)), split
// by 1 / (1 + g_0) (g_0 at normal incidence, mean wavelength); their total
// weight is the mean Fresnel reflectance at normal incidence.
#pragma once

#include "brdf/core.h"
#include "brdf/microfacet.h"
#include "brdf/torrance_sparrow.h"

#include <algorithm>
#include <cmath>

namespace brdfkit {

namespace detail {

inline const GaussLegendre01<24>& HeRule() {
  static const GaussLegendre01<24> rule;
  return rule;
}

// Smith shadowing S(theta) of the paper for cos_t = cos(theta) and
// sin_t = sin(theta), ratio r = tau / (2 sigma_0).
template <typename T>
inline T HeShadowing(const T& cos_t, const T& sin_t, const T& r) {
  using std::erfc;
  using std::exp;
  if (sin_t <= T(0)) return T(1);  // normal direction: nothing shadows it
  const T nu = r * cos_t / sin_t;
  if (nu > T(26)) return T(1);  // erfc(26) and exp(-26^2) are below 1e-290: Lambda = 0
  const T lambda = (exp(-nu * nu) / (T(std::sqrt(kPi)) * nu) - erfc(nu)) / T(2);
  return (T(1) - erfc(nu) / T(2)) / (lambda + T(1));
}

// K(theta) = tan(theta) erfc(tau cot(theta) / (2 sigma_0)) of the z0 equation.
template <typename T>
inline T HeK(const T& cos_t, const T& sin_t, const T& r) {
  using std::erfc;
  if (sin_t <= T(0)) return T(0);  // tan = 0 at the normal
  return sin_t / cos_t * erfc(r * cos_t / sin_t);
}

// Root x > 0 of x = a exp(-x^2 / 2) (the z0 equation with x = z0 / sigma_0), as
// y = log x: y + e^{2y} / 2 - log a = 0 is increasing and convex in y, so
// Newton's method converges monotonically after its first step.
template <typename T>
inline T HeZ0OverSigma(const T& a) {
  using std::exp;
  using std::log;
  const double ad = Value(a);
  if (!(ad > 0)) return T(0);  // both directions normal: no shadowing, z0 = 0
  // x = a - a^3 / 2 + ...: below 1e-8 the root is a to 1e-16, and log(a)
  // would lose the derivative of an a near underflow (erfc of large arguments).
  if (ad < 1e-8) return a;
  const double la = std::log(ad);
  double y = la < 0 ? la : 0.5 * std::log(2.0 * la + 1.0);
  for (int it = 0; it < 100; ++it) {
    const double e = std::exp(2.0 * y);
    const double step = (y + 0.5 * e - la) / (1.0 + e);
    y -= step;
    if (std::abs(step) < 1e-15 * std::max(1.0, std::abs(y))) break;
  }
  // One Newton step in T from the converged root carries its derivative.
  T yt = T(y);
  const T e = exp(T(2) * yt);
  yt -= (yt + e / T(2) - log(a)) / (T(1) + e);
  return exp(yt);
}

// Log of the series sum_{m>=1} g^m e^-g / (m! m) exp(-c / m), c = v_xy^2 tau^2 / 4.
// Returns -infinity (as a plain value) when the sum underflows.
template <typename T>
inline T HeLogSeries(const T& g, const T& c) {
  using std::exp;
  using std::log;
  const double gd = Value(g), cd = Value(c);
  const double lg = std::log(gd);
  auto term = [&](double m) { return m * lg - gd - std::lgamma(m + 1.0) - std::log(m) - cd / m; };
  // Continuous peak: l'(m) = ln g - psi(m + 1) - 1/m + c/m^2 = 0, with
  // psi(m + 1) ~ ln(m + 1/2); increasing residual for m >= 2, bisection.
  auto slope = [&](double m) { return lg - std::log(m + 0.5) - 1.0 / m + cd / (m * m); };
  double lo = 1.0, hi = std::max(2.0, 2.0 * gd + 2.0);
  while (slope(hi) > 0) hi *= 2.0;
  double m_star = 1.0;
  if (slope(lo) > 0) {
    for (int it = 0; it < 64 && hi - lo > 1e-9 * hi; ++it) {
      const double mid = 0.5 * (lo + hi);
      (slope(mid) > 0 ? lo : hi) = mid;
    }
    m_star = 0.5 * (lo + hi);
  }
  const double curvature = 1.0 / (m_star + 0.5) - 1.0 / (m_star * m_star) + 2.0 * cd / (m_star * m_star * m_star);
  const double width = curvature > 0 ? 1.0 / std::sqrt(curvature) : 0.0;
  const T log_g = log(g);
  if (width >= 4.0 && m_star - 10.0 * width >= 1.0) {
    // Wide peak: the sum equals the integral over m to exp(-2 pi^2 w^2).
    const auto& rule = HeRule();
    const double a = std::max(0.5, m_star - 12.0 * width), b = m_star + 12.0 * width;
    const double peak = term(m_star);
    constexpr int kPanels = 8;
    const double hpanel = (b - a) / kPanels;
    T sum = T(0);
    for (int k = 0; k < kPanels; ++k) {
      for (int j = 0; j < 24; ++j) {
        const double m = a + hpanel * (k + rule.x[j]);
        const T l = T(m) * log_g - g - T(std::lgamma(m + 1.0) + std::log(m)) - c / T(m);
        sum += T(hpanel * rule.w[j]) * exp(l - T(peak));
      }
    }
    return log(sum) + T(peak);
  }
  // Direct sum from the largest term outward.
  double m0 = std::max(1.0, std::round(m_star));
  while (term(m0 + 1) > term(m0)) m0 += 1;
  while (m0 > 1 && term(m0 - 1) > term(m0)) m0 -= 1;
  const double peak = term(m0);
  if (!(peak > -700)) return T(-std::numeric_limits<double>::infinity());  // underflows: no light
  auto add = [&](double m, T& sum) {
    sum += exp(T(m) * log_g - g - T(std::lgamma(m + 1.0) + std::log(m)) - c / T(m) - T(peak));
  };
  T sum = T(0);
  double sum_d = 0;
  add(m0, sum);
  sum_d += 1;
  // Upward: ratios fall (log-concave), so the tail after term j is below t_j r / (1 - r).
  constexpr int kMaxTerms = 4000;  // never reached: the peak is under 4 terms wide here
  for (double m = m0 + 1; m < m0 + kMaxTerms; m += 1) {
    const double t = std::exp(term(m) - peak), r = std::exp(term(m + 1) - term(m));
    add(m, sum);
    sum_d += t;
    if (r < 1 && t * r / (1 - r) < 1e-17 * sum_d) break;
  }
  // Downward: the same bound holds for the terms m >= 2; term 1 is outside
  // the log-concave range and is always added.
  for (double m = m0 - 1; m >= 2; m -= 1) {
    const double t = std::exp(term(m) - peak), r = std::exp(term(m - 1) - term(m));
    add(m, sum);
    sum_d += t;
    if (m > 2 && r < 1 && t * r / (1 - r) < 1e-17 * sum_d) break;
  }
  if (m0 > 1) add(1.0, sum);
  return log(sum) + T(peak);
}

}  // namespace detail

class He {
 public:
  explicit He(const Settings& = {}) {}

  static constexpr Slot kSigma0{"sigma_0", 0}, kTau{"tau", 1}, kN{"n", 2, true}, kK{"k", 5, true},
      kLambdaR{"lambda_r", 8}, kLambdaG{"lambda_g", 9}, kLambdaB{"lambda_b", 10}, kA{"a", 11, true};
  static constexpr std::array kSlots{kSigma0, kTau, kN, kK, kLambdaR, kLambdaG, kLambdaB, kA};
  static constexpr std::array<Slot, 3> kLambda{kLambdaR, kLambdaG, kLambdaB};  // per channel
  static constexpr unsigned kKind = LobeKind::kDiffuse | LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;
  // The directional-diffuse lobe: Beckmann of alpha = 2 sigma_0 / tau for a
  // rough surface (g >> 1), of the m = 1 term's lambda / (2 pi tau) for a
  // smooth one, blended as the sampling mixture blends them (1 / (1 + g_0)).
  LobeWidth Width(const double* p) const {
    const Mixture m = MixtureOf(p);
    const double w = (m.p_geo * m.alpha_geo + m.p_wave * m.alpha_wave) / (m.p_geo + m.p_wave);
    return {w, w};
  }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "he";
    info.summary = "He-Torrance-Sillion-Greenberg 1991 physical model: directional-diffuse Kirchhoff series + uniform diffuse";
    using S = ParamInfo::Scale;
    info.params.push_back({"sigma_0", 1e-3, 10.0, 0.2, false, "rms surface height (micrometres)", S::kLog});
    info.params.push_back({"tau", 0.05, 100.0, 2.0, false, "autocorrelation length (micrometres)", S::kLog});
    info.params.push_back({"n", 0.05, 20.0, 1.5, true, "real part of the complex refractive index"});
    info.params.push_back({"k", 0.0, 20.0, 0.5, true, "imaginary part of the complex refractive index"});
    info.params.push_back({"lambda_r", 0.2, 2.0, 0.65, false, "wavelength of the red channel (micrometres)"});
    info.params.push_back({"lambda_g", 0.2, 2.0, 0.55, false, "wavelength of the green channel (micrometres)"});
    info.params.push_back({"lambda_b", 0.2, 2.0, 0.45, false, "wavelength of the blue channel (micrometres)"});
    info.params.push_back({"a", 0.0, 1.0, 0.1, true, "uniform-diffuse reflectance"});
    info.reciprocal = true;
    info.energy_conserving = false;  // Kirchhoff + uncorrelated Smith shadowing bound nothing
    return info;
  }

  // Effective roughness sigma for the pair of directions.
  template <typename T>
  static T EffectiveRoughness(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) {
    using std::sqrt;
    const T r = At(p, kTau) / (T(2) * At(p, kSigma0));
    const T ki = detail::HeK(wi.z(), SafeSqrt(Sin2Theta(wi)), r);
    const T ko = detail::HeK(wo.z(), SafeSqrt(Sin2Theta(wo)), r);
    const T x = detail::HeZ0OverSigma(T((ki + ko) / T(4 * std::sqrt(kPi / 2))));
    return At(p, kSigma0) / sqrt(T(1) + x * x);
  }

  // Shadowing S(theta_i) S(theta_o).
  template <typename T>
  static T Shadowing(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) {
    const T r = At(p, kTau) / (T(2) * At(p, kSigma0));
    return detail::HeShadowing(wi.z(), SafeSqrt(Sin2Theta(wi)), r) *
           detail::HeShadowing(wo.z(), SafeSqrt(Sin2Theta(wo)), r);
  }

  // The directional-diffuse term rho_dd per channel.
  template <typename T>
  static Rgb<T> DirectionalDiffuse(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) {
    using std::exp;
    using std::log;
    using std::sqrt;
    Rgb<T> f = Rgb<T>::Constant(T(0));
    if (!SameUpperHemisphere(wi, wo)) return f;
    const T& tau = At(p, kTau);
    const Vec3<T> h = wi + wo;
    const T hh = h.squaredNorm();
    const T hz = h.z();
    const T hxy2 = h.x() * h.x() + h.y() * h.y();
    const T sigma = EffectiveRoughness(p, wi, wo);
    const T shadow = Shadowing(p, wi, wo);
    const T cos_d = HalfCos(wi, wo);  // = wi.h / |h|; the dot product goes negative by rounding for opposite grazing pairs
    // log of G / (pi cos_i cos_o) and the constant of D without 1 / lambda^2.
    const T log_common = T(2) * (log(hh) - log(hz)) - log(wi.z()) - log(wo.z()) + log(T(kPi / 4) * tau * tau);
    for (int c = 0; c < 3; ++c) {
      const T& lambda = At(p, kLambda[c]);
      const T k = T(2 * kPi) / lambda;
      const T s = k * sigma * hz;
      const T g = s * s;
      if (!(g > T(0))) continue;  // underflow of g (float at grazing pairs): no scattered light
      const T cc = k * k * hxy2 * tau * tau / T(4);
      const T log_series = detail::HeLogSeries(g, cc);
      if (!(Value(log_series) > -std::numeric_limits<double>::infinity())) continue;  // underflowed to 0
      const T fresnel = FresnelConductor(At(p, kN, c), At(p, kK, c), cos_d);
      f[c] = fresnel * shadow * exp(log_common + log_series - T(2) * log(lambda));
    }
    return f;
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    Rgb<T> f = DirectionalDiffuse(p, wi, wo);
    for (int c = 0; c < 3; ++c) f[c] += At(p, kA, c) * T(kInvPi);
    return f;
  }

  // Fraction of the incident power reflected coherently into the mirror
  // direction (the delta term rho_sp, left out of Eval):
  // |F(theta_i)|^2 exp(-g) S(theta_i)^2, g at theta_o = theta_i.
  template <typename T>
  static Rgb<T> SpecularReflectance(const T* p, const Vec3<T>& wi) {
    using std::exp;
    Rgb<T> r = Rgb<T>::Constant(T(0));
    if (wi.z() <= T(0)) return r;
    const Vec3<T> wo = Reflect(wi);
    const T sigma = EffectiveRoughness(p, wi, wo);
    const T shadow = Shadowing(p, wi, wo);
    for (int c = 0; c < 3; ++c) {
      const T s = T(4 * kPi) * sigma * wi.z() / At(p, kLambda[c]);
      r[c] = FresnelConductor(At(p, kN, c), At(p, kK, c), wi.z()) * exp(-s * s) * shadow;
    }
    return r;
  }

  template <typename T>
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const {
    if (!SameUpperHemisphere(wi, wo)) return T(0);
    const Mixture mix = MixtureOf(p);
    const Vec3<T> m = HalfVector(wi, wo);
    const T jac = m.z() / (T(4) * HalfCos(wi, wo));  // wo.m by HalfCos: never <= 0 by rounding
    return T(mix.p_diffuse) * wi.z() * T(kInvPi) + T(mix.p_geo) * DBeckmann(m, T(mix.alpha_geo), T(mix.alpha_geo)) * jac +
           T(mix.p_wave) * DBeckmann(m, T(mix.alpha_wave), T(mix.alpha_wave)) * jac;
  }

  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    BsdfSample<T> s;
    if (wo.z() <= T(0)) return s;
    const Mixture mix = MixtureOf(p);
    Eigen::Vector3d wi;
    if (u1 < mix.p_diffuse) {
      // Reuse u1 within the chosen interval; the clamp keeps it below 1.
      const Vec3<double> d = SampleCosineHemisphere<double>(std::min(u1 / mix.p_diffuse, 1.0 - 1e-16), u2);
      wi = Eigen::Vector3d(d.x(), d.y(), d.z());
    } else {
      double alpha, v;
      if (u1 < mix.p_diffuse + mix.p_geo) {
        alpha = mix.alpha_geo;
        v = std::min((u1 - mix.p_diffuse) / mix.p_geo, 1.0 - 1e-16);
      } else {
        alpha = mix.alpha_wave;
        v = std::min((u1 - mix.p_diffuse - mix.p_geo) / mix.p_wave, 1.0 - 1e-16);
      }
      // Beckmann: tan^2(theta_m) = -alpha^2 log(1 - v) (Walter et al. 2007 eq. 28).
      const double tan_t = alpha * std::sqrt(-std::log1p(-v));
      const double cos_t = 1.0 / std::sqrt(1.0 + tan_t * tan_t), sin_t = tan_t * cos_t;
      const Eigen::Vector3d m(sin_t * std::cos(2 * kPi * u2), sin_t * std::sin(2 * kPi * u2), cos_t);
      if (!ReflectAbout(wo, m, wi)) return s;  // normal seen from behind: no reflection
    }
    return SampledFrom(*this, p, wo, wi);
  }

  double SampleWeight(const double* p) const {
    double s = 0;
    for (int c = 0; c < 3; ++c) s += FresnelConductor(At(p, kN, c), At(p, kK, c), 1.0);
    return s / 3.0 + MeanRgb(p, kA);
  }

 private:
  struct Mixture {
    double p_diffuse, p_geo, p_wave, alpha_geo, alpha_wave;
  };

  template <typename T>
  static Mixture MixtureOf(const T* p) {
    const double sigma0 = Value(At(p, kSigma0)), tau = Value(At(p, kTau));
    const double lambda = (Value(At(p, kLambdaR)) + Value(At(p, kLambdaG)) + Value(At(p, kLambdaB))) / 3.0;
    double f0 = 0, a = 0;
    for (int c = 0; c < 3; ++c) {
      f0 += FresnelConductor(Value(At(p, kN, c)), Value(At(p, kK, c)), 1.0) / 3.0;
      a += Value(At(p, kA, c)) / 3.0;
    }
    const double g0 = std::pow(4 * kPi * sigma0 / lambda, 2);
    const double wd = a + 0.05, ws = f0;
    Mixture m;
    m.p_diffuse = wd / (wd + ws);
    m.p_wave = ws / (wd + ws) / (1.0 + g0);
    m.p_geo = ws / (wd + ws) - m.p_wave;
    // Lobes wider than alpha = 4 are near-uniform and narrower than 1e-3 are
    // beyond what a sampled check resolves: the clamp only shapes the proposal.
    m.alpha_geo = std::clamp(2.0 * sigma0 / tau, 1e-3, 4.0);
    m.alpha_wave = std::clamp(lambda / (2 * kPi * tau), 1e-3, 4.0);
    return m;
  }
};

}  // namespace brdfkit
