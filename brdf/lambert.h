// Lambert: the ideal diffuse reflector, f_r = rho / pi.
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// Lambert 1760, "Photometria". E(wo) = rho for every wo. Sampling is
// cosine-weighted (pdf = cos_theta_i / pi), exact importance sampling.
#pragma once

#include "brdf/core.h"

namespace brdfkit {

struct Lambert : CosineSampling {
  explicit Lambert(const Settings& = {}) {}

  static constexpr Slot kAlbedo{"albedo", 0, true};
  static constexpr std::array kSlots{kAlbedo};
  static constexpr unsigned kKind = LobeKind::kDiffuse;
  static constexpr bool kChannelsIndependent = true;
  static constexpr bool kVanishes = true;  // zero with its colour parameters at 0

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "lambert";
    info.summary = "ideal diffuse reflector rho/pi (Lambert 1760)";
    info.params = {{"albedo", 0.0, 1.0, 0.5, true, "directional albedo rho"}};
    info.reciprocal = true;
    info.energy_conserving = true;
    return info;
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    return RgbAt(p, kAlbedo) * T(kInvPi);
  }

  double SampleWeight(const double* p) const { return MeanRgb(p, kAlbedo); }
};

}  // namespace brdfkit
