// Rough diffuse reflection: the qualitative Oren-Nayar model and Fujii's
// improved variant of it.
//
// --- oren_nayar --------------------------------------------------------------
// Oren & Nayar 1994, "Generalization of Lambert's Reflectance Model",
// SIGGRAPH '94, the qualitative model of eq. 30:
//
//   f_r = rho/pi (A + B max(0, cos(phi_i - phi_o)) sin(alpha) tan(beta)),
//   A = 1 - 0.5 s^2 / (s^2 + 0.33),  B = 0.45 s^2 / (s^2 + 0.09),  s = sigma,
//   alpha = max(theta_i, theta_o),  beta = min(theta_i, theta_o).
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// Approximations made (by the paper, and here):
//  - eq. 30 is Oren & Nayar's simplification of their fuller fitted model:
//    the C3 term and the interreflection term are dropped, so light is lost
//    at large sigma and, at small sigma, gained at grazing view: the
//    directional albedo at theta_o -> 90 deg is rho (A + B/2), which exceeds
//    rho for 0 < sigma < 0.3261 (sigma^2 < 0.02925 / 0.275), by up to 1.52 %
//    (sigma = 0.20). The model is therefore not energy-conserving. At normal
//    view the albedo is rho A.
//  - sin(alpha) tan(beta) cos(phi_i - phi_o) is computed as
//    (wi_x wo_x + wi_y wo_y) / max(cos_theta_i, cos_theta_o): identical, with
//    no division by sin(theta) (undefined azimuth at the normal) and no acos.
//  - Guard: tan(beta) diverges when both directions reach the horizon. The
//    denominator is floored at kOrenNayarMinCos = 1e-6, which keeps f and its
//    derivatives finite in float; it changes f only where both directions lie
//    within 1e-6 rad of the horizon, and no albedo by more than 1e-12.
//  sigma = 0 gives A = 1, B = 0: exactly Lambert rho/pi.
//  Sampling is cosine-weighted (pdf = cos_theta_i / pi).
//
// --- oren_nayar_fujii --------------------------------------------------------
// Fujii 2012, "A tiny improvement of Oren-Nayar reflectance model" (web
// note, mimosa-pudica.net; it numbers no equations), the energy-normalised
// form:
//
//   f_r = rho (A + B s / t),  A = 1 / (pi + sigma (pi/2 - 2/3)),  B = sigma A,
//   s = wi.wo - cos_theta_i cos_theta_o   (= wi_xy . wo_xy, signed),
//   t = 1 if s <= 0, else max(cos_theta_i, cos_theta_o).
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// sigma is Fujii's mixing ratio, not a slope angle. Its upper bound is 1
// because s/t reaches -1 (both directions grazing, opposite azimuths), where
// f = rho A (1 - sigma): any sigma > 1 makes f negative.
// The normalisation puts the directional albedo's maximum, rho, at grazing
// view: E(mu) = rho [pi A + B sin_o I(mu)],
// I(mu) = 2 (1 - sin_o^3) / (3 mu) + acos(mu) - mu sin_o - 2/3, and I(0) =
// pi/2 - 2/3; so the model conserves energy for rho <= 1. Approximations: the
// whole model is an empirical fit to the full Oren-Nayar model; the same
// 1e-6 floor on t as above (t only divides where s > 0).
// Sampling is cosine-weighted.
#pragma once

#include "brdf/core.h"

namespace brdfkit {

inline constexpr double kOrenNayarMinCos = 1e-6;

// (wi_x wo_x + wi_y wo_y) / max(cos_theta_i, cos_theta_o, 1e-6), the signed
// sin(alpha) tan(beta) cos(phi_i - phi_o) of Oren & Nayar eq. 30.
template <typename T>
inline T OrenNayarAzimuthTerm(const Vec3<T>& wi, const Vec3<T>& wo) {
  const T s = wi.x() * wo.x() + wi.y() * wo.y();
  T t = wi.z() > wo.z() ? wi.z() : wo.z();
  if (t < T(kOrenNayarMinCos)) t = T(kOrenNayarMinCos);  // tan(beta) diverges at double grazing
  return s / t;
}

// Shared by both variants: the parameters, cosine-weighted sampling, albedo
// as lobe weight.
struct CosineSampledDiffuse : CosineSampling {
  static constexpr Slot kAlbedo{"albedo", 0, true}, kSigma{"sigma", 3};
  static constexpr std::array kSlots{kAlbedo, kSigma};
  static constexpr unsigned kKind = LobeKind::kDiffuse;
  static constexpr bool kChannelsIndependent = true;
  static constexpr bool kVanishes = true;  // zero with its colour parameters at 0
  double SampleWeight(const double* p) const { return MeanRgb(p, kAlbedo); }
};

struct OrenNayar : CosineSampledDiffuse {
  explicit OrenNayar(const Settings& = {}) {}

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "oren_nayar";
    info.summary = "rough diffuse, qualitative model (Oren & Nayar 1994, eq. 30)";
    info.params = {{"albedo", 0.0, 1.0, 0.5, true, "facet albedo rho"},
                   {"sigma", 0.0, kPi / 2, 0.35, false, "std. deviation of facet slope angle (radians)"}};
    info.reciprocal = true;
    info.energy_conserving = false;  // albedo rho (A + B/2) > rho at grazing view for small sigma
    return info;
  }

  // Oren & Nayar 1994 eq. 30 coefficients.
  template <typename T>
  static void Coefficients(const T& sigma, T& a, T& b) {
    const T s2 = sigma * sigma;
    a = T(1) - T(0.5) * s2 / (s2 + T(0.33));
    b = T(0.45) * s2 / (s2 + T(0.09));
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    T a, b;
    Coefficients(At(p, kSigma), a, b);
    const T g = OrenNayarAzimuthTerm(wi, wo);
    const T shape = g > T(0) ? T(a + b * g) : a;  // max(0, cos(phi_i - phi_o))
    return RgbAt(p, kAlbedo) * T(kInvPi) * shape;
  }
};

struct OrenNayarFujii : CosineSampledDiffuse {
  explicit OrenNayarFujii(const Settings& = {}) {}

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "oren_nayar_fujii";
    info.summary = "rough diffuse, Fujii 2012 improved Oren-Nayar, energy-normalised";
    info.params = {{"albedo", 0.0, 1.0, 0.5, true, "albedo rho (directional albedo at grazing view)"},
                   {"sigma", 0.0, 1.0, 0.5, false, "ratio of non-diffuse to diffuse term (B / A)"}};
    info.reciprocal = true;
    info.energy_conserving = true;  // max over wo of the albedo is rho, at grazing view
    return info;
  }

  template <typename T>
  static void Coefficients(const T& sigma, T& a, T& b) {
    a = T(1) / (T(kPi) + sigma * T(kPi / 2 - 2.0 / 3.0));
    b = sigma * a;
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    T a, b;
    Coefficients(At(p, kSigma), a, b);
    const T s = wi.x() * wo.x() + wi.y() * wo.y();
    // t = 1 where s <= 0, so s / t is s itself there.
    const T s_over_t = s > T(0) ? OrenNayarAzimuthTerm(wi, wo) : s;
    return RgbAt(p, kAlbedo) * (a + b * s_over_t);
  }
};

}  // namespace brdfkit
