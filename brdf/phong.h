// Phong-type cosine lobes: Phong's original shading formula read as a BRDF,
// the energy-normalised modified Phong model, and normalised Blinn-Phong.
//
// Notation: cos(alpha) = R(wi).wo = wi.R(wo), the cosine of the angle between
// wo and the mirror direction R(wi) = (-x, -y, z) of wi; theta_h is the polar
// angle of the half vector h = (wi + wo) / |wi + wo|. Every lobe cos^n is
// evaluated with PowLobe (0 where the cosine is <= 0, finite derivatives).
//
// Exponent n, shared by all three (and by lafortune):
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// A fit moves n on a log scale (exponents of measured materials span 1 to
// 1e5), which needs a positive lower bound: 1e-3. A lobe with n = 1e-3 is
// the n -> 0 limit to within 0.1 % wherever cos > 0.37. The upper bound 1e8
// is a lobe about 1e-4 rad wide; PowLobe keeps values and derivatives finite
// up to it in float, double and Jet.
//
// --- phong_original ------------------------------------------------------------
// Phong 1975, "Illumination for Computer Generated Pictures", CACM 18(6):
// the specular term W cos^n(alpha) of his shading formula scales the light's
// intensity without the cos(theta_i) that his diffuse term carries; per unit
// irradiance (the BRDF's definition) it is
//
//   f_r = ks cos^n(alpha) / cos(theta_i).
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// NOT reciprocal (f(wi, wo) / f(wo, wi) = cos_theta_o / cos_theta_i) and NOT
// energy-conserving: at normal view the albedo is ks 2 pi / (n + 1), above 1
// for every ks > (n + 1) / (2 pi). It is here as the historical reference
// that checks must reject. Guard: cos(theta_i) is floored at 1e-15 in the
// division, which keeps f and its derivatives finite in float; f cos_theta_i
// is bounded, so no integral notices.
// Sampling draws the cos^n lobe around R(wo): f cos_theta_i / pdf is the
// constant ks 2 pi / (n + 1) (exact importance sampling).
//
// --- phong -----------------------------------------------------------------
// Lafortune & Willems 1994, "Using the modified Phong reflectance model for
// physically based rendering", report CW 197, KU Leuven: the specular lobe
//
//   f_r = ks (n + 2) / (2 pi) cos^n(alpha).
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// Reciprocal and energy-conserving: the albedo is ks exactly at normal view
// and smaller elsewhere (part of the lobe falls below the horizon). The
// diffuse term kd/pi of the paper is the separate model lambert (write
// lambert+phong). Sampling draws the cos^n lobe around R(wo), pdf
// (n + 1) / (2 pi) cos^n(alpha); samples below the horizon are returned
// invalid, so the pdf integrates over the upper hemisphere to the sampled
// fraction.
//
// --- blinn_phong -----------------------------------------------------------
// Blinn 1977, "Models of Light Reflection for Computer Synthesized Pictures"
// (the cos^n(theta_h) lobe), with the normalisation (n + 8) / (8 pi) of
// Akenine-Moller, Haines & Hoffman, "Real-Time Rendering" (3rd ed., 2008):
//
//   f_r = ks (n + 8) / (8 pi) cos^n(theta_h).
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// Approximation: (n + 8) / (8 pi) is an approximation of the factor that
// would make the albedo at normal view equal ks; the exact albedo there is
//   E(1) = ks (n + 8) [2 (1 - 2^-(n+4)/2) / (n + 4) - (1 - 2^-(n+2)/2) / (n + 2)],
// 1 at n = 0 and above 1 for every n > 0: 1.0752 at n = 8.76 (the maximum),
// 1.0607 at n = 20, about 1 + 2/n for large n. So with ks = 1 the model
// reflects more than it receives; Info says it is not energy-conserving.
// Reciprocal. Sampling draws h with density
// (n + 1) / (2 pi) cos^n(theta_h) and reflects wo about it:
// pdf(wi) = pdf(h) / (4 wo.h); samples below the horizon are invalid.
#pragma once

#include "brdf/core.h"

namespace brdfkit {

inline ParamInfo PhongExponentParam() {
  return {"n", 1e-3, 1e8, 20.0, false, "lobe exponent (larger: narrower lobe)", ParamInfo::Scale::kLog};
}

// The parameters and traits shared by the three Phong lobes: a colour
// weight and the exponent n; the lobe is glossy with width ~ sqrt(2 / (n + 2)).
struct PhongLobe {
  static constexpr Slot kKs{"ks", 0, true}, kN{"n", 3};
  static constexpr std::array kSlots{kKs, kN};
  static constexpr unsigned kKind = LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;
  static constexpr bool kVanishes = true;  // zero with its colour parameters at 0
  LobeWidth Width(const double* p) const {
    const double w = PhongExponentWidth(At(p, kN));
    return {w, w};
  }
};

// Pdf and sampling of a cos^n lobe around the mirror direction of wo, for
// the Phong lobes.
struct MirrorLobeSampling : PhongLobe {
  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    BsdfSample<T> s;
    if (wo.z() <= T(0)) return s;
    s.wi = SampleCosinePowerLobe(Vec3<T>(Reflect(wo)), At(p, kN), u1, u2);
    if (s.wi.z() <= T(0)) return s;  // the lobe reaches below the horizon
    s.pdf = Pdf(p, wo, s.wi);
    s.valid = s.pdf > T(0);
    return s;
  }

  template <typename T>
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const {
    if (!SameUpperHemisphere(wi, wo)) return T(0);
    return CosinePowerLobePdf(Vec3<T>(Reflect(wo)), At(p, kN), wi);
  }
};

struct PhongOriginal : MirrorLobeSampling {
  explicit PhongOriginal(const Settings& = {}) {}

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "phong_original";
    info.summary = "Phong 1975 shading formula as a BRDF, ks cos^n / cos_i (not reciprocal, not energy-conserving)";
    info.params = {{"ks", 0.0, 1.0, 0.5, true, "specular coefficient"}, PhongExponentParam()};
    info.reciprocal = false;
    info.energy_conserving = false;
    return info;
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const T lobe = PowLobe(T(Reflect(wi).dot(wo)), At(p, kN));
    // 1/cos diverges at the horizon; the floor keeps float derivatives finite.
    const T cos_i = wi.z() > T(1e-15) ? wi.z() : T(1e-15);
    return RgbAt(p, kKs) * (lobe / cos_i);
  }

  // Albedo at normal view, ks 2 pi / (n + 1).
  double SampleWeight(const double* p) const { return MeanRgb(p, kKs) * 2.0 * kPi / (At(p, kN) + 1.0); }
};

struct Phong : MirrorLobeSampling {
  explicit Phong(const Settings& = {}) {}

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "phong";
    info.summary = "modified Phong lobe ks (n+2)/(2 pi) cos^n, energy-normalised (Lafortune & Willems 1994)";
    info.params = {{"ks", 0.0, 1.0, 0.5, true, "albedo at normal view"}, PhongExponentParam()};
    info.reciprocal = true;
    info.energy_conserving = true;  // albedo <= ks, equality at normal view
    return info;
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const T& n = At(p, kN);
    const T lobe = (n + T(2)) * T(0.5 * kInvPi) * PowLobe(T(Reflect(wi).dot(wo)), n);
    return RgbAt(p, kKs) * lobe;
  }

  double SampleWeight(const double* p) const { return MeanRgb(p, kKs); }
};

struct BlinnPhong : PhongLobe {
  explicit BlinnPhong(const Settings& = {}) {}

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "blinn_phong";
    info.summary = "Blinn-Phong ks (n+8)/(8 pi) cos^n(theta_h), approximate normalisation (Real-Time Rendering)";
    info.params = {{"ks", 0.0, 1.0, 0.5, true, "specular colour"}, PhongExponentParam()};
    info.reciprocal = true;
    info.energy_conserving = false;  // the normalisation is approximate, not a bound
    return info;
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const T& n = At(p, kN);
    const Vec3<T> h = HalfVector(wi, wo);
    const T lobe = (n + T(8)) * T(0.125 * kInvPi) * PowLobe(h.z(), n);
    return RgbAt(p, kKs) * lobe;
  }

  template <typename T>
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const {
    if (!SameUpperHemisphere(wi, wo)) return T(0);
    const Vec3<T> h = HalfVector(wi, wo);
    // wo.h = |wi + wo| / 2 >= (cos_theta_i + cos_theta_o) / 2 > 0 here, computed
    // so: the dot product with h can round negative for opposite grazing pairs.
    return (At(p, kN) + T(1)) * T(0.5 * kInvPi) * PowLobe(h.z(), At(p, kN)) / (T(4) * HalfCos(wi, wo));
  }

  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    BsdfSample<T> s;
    if (wo.z() <= T(0)) return s;
    const Vec3<T> h = SampleCosinePowerLobe(Vec3<T>(T(0), T(0), T(1)), At(p, kN), u1, u2);
    const T wo_h = wo.dot(h);
    if (wo_h <= T(0)) return s;  // h faces away from wo: no reflection
    s.wi = h * T(T(2) * wo_h) - wo;
    if (s.wi.z() <= T(0)) return s;  // reflected below the horizon
    s.pdf = Pdf(p, wo, s.wi);
    s.valid = s.pdf > T(0);
    return s;
  }

  double SampleWeight(const double* p) const { return MeanRgb(p, kKs); }
};

}  // namespace brdfkit
