// Lambert: the ideal diffuse reflector, f_r = rho / pi.
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// Lambert 1760, "Photometria". E(wo) = rho for every wo. Sampling is
// cosine-weighted (pdf = cos_theta_i / pi), exact importance sampling.
#pragma once

#include "brdf/batch.h"
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

  template <typename T, typename V = T>  // V: the directions' scalar (Bxdf::EvalAt)
  Rgb<T> Eval(const T* p, const Vec3<V>& wi, const Vec3<V>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    return RgbAt(p, kAlbedo) * T(kInvPi);
  }

  // Eval over n pairs, vectorised (brdf/batch.h): the same values, bit for bit.
  template <typename T>
    requires std::is_floating_point_v<T>
  void EvalBatch(const T* p, const T* wi, std::size_t wi_stride, const T* wo, std::size_t wo_stride, std::size_t n,
                 T* out) const {
    const Rgb<T> f = RgbAt(p, kAlbedo) * T(kInvPi);
    RunBatchKernel(Kernel<T>{f[0], f[1], f[2]}, wi, wi_stride, wo, wo_stride, n, out);
  }

  double SampleWeight(const double* p) const { return MeanRgb(p, kAlbedo); }

 private:
  template <typename T>
  struct Kernel {
    T r, g, b;  // rho / pi
    [[gnu::always_inline]] void operator()(const T* wi, const T* wo, T* out) const {
      const bool above = (wi[2] > T(0)) & (wo[2] > T(0));
      out[0] = Select(above, r, T(0));
      out[1] = Select(above, g, T(0));
      out[2] = Select(above, b, T(0));
    }
  };
};

}  // namespace brdfkit
