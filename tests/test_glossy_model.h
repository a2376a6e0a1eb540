// A model that exists only in the tests, registered from tests/ with one
// line (tests/test_glossy_model.cpp): the proof that a model written
// outside brdf/ gets every tool with no other edit.
//
//   f_r = kd / pi + ks p_h(h) / (4 (wi.h) max(cos_i, cos_o)),
//   p_h(h) = (n + 1) / (2 pi) cos^n(theta_h),
//
// h the unit half vector. p_h integrates to 1 over the hemisphere of h and
// dwi = 4 (wi.h) dwh, so the glossy albedo is
// ks int p_h cos_i / max(cos_i, cos_o) dwh <= ks: the model conserves
// energy when kd + ks <= 1 (the box bounds do not say so, so the flag stays
// false). Reciprocal: wi.h = wo.h. Sampling mixes cosine sampling and
// sampling h from p_h, half and half.
#pragma once

#include "brdf/core.h"

#include <algorithm>
#include <array>
#include <cmath>

namespace brdfkit::test {

struct TestGlossy {
  explicit TestGlossy(const Settings& = {}) {}

  static constexpr Slot kKd{"kd", 0, true}, kKs{"ks", 3, true}, kN{"n", 6};
  static constexpr std::array kSlots{kKd, kKs, kN};
  static constexpr unsigned kKind = LobeKind::kDiffuse | LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;
  LobeWidth Width(const double* p) const {
    const double w = PhongExponentWidth(At(p, kN));
    return {w, w};
  }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "test_glossy";
    info.summary = "test-only model: Lambert plus a normalised cos^n half-vector lobe";
    info.params = {{"kd", 0.0, 1.0, 0.3, true, "diffuse reflectance"},
                   {"ks", 0.0, 1.0, 0.5, true, "glossy albedo bound"},
                   {"n", 1.0, 1e4, 40.0, false, "half-vector lobe exponent", ParamInfo::Scale::kLog}};
    info.reciprocal = true;
    info.energy_conserving = false;  // only when kd + ks <= 1
    return info;
  }

  template <typename T>
  static T Lobe(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) {
    const Vec3<T> h = HalfVector(wi, wo);
    const T& n = At(p, kN);
    return (n + T(1)) * T(0.5 * kInvPi) * PowLobe(h.z(), n);
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const T max_cos = wi.z() > wo.z() ? wi.z() : wo.z();
    const T glossy = Lobe(p, wi, wo) / (T(4) * HalfCos(wi, wo) * max_cos);
    return RgbAt(p, kKd) * T(kInvPi) + RgbAt(p, kKs) * glossy;
  }

  // Half the samples cosine-weighted, half from p_h reflected about h.
  template <typename T>
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const {
    if (!SameUpperHemisphere(wi, wo)) return T(0);
    return T(0.5) * (wi.z() * T(kInvPi) + Lobe(p, wi, wo) / (T(4) * HalfCos(wi, wo)));
  }

  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    if (wo.z() <= T(0)) return {};
    // u1 reused inside each half; the clamp keeps it below 1.
    const double v = std::min(2.0 * (u1 < 0.5 ? u1 : u1 - 0.5), 1.0 - 1e-16);
    if (u1 < 0.5) return SampledFrom(*this, p, wo, Eigen::Vector3d(SampleCosineHemisphere<double>(v, u2)));
    const Eigen::Vector3d h = SampleCosinePowerLobe(Vec3<double>(0, 0, 1), Value(At(p, kN)), v, u2);
    Eigen::Vector3d wi;
    if (!ReflectAbout(wo, h, wi)) return {};  // h seen from behind
    return SampledFrom(*this, p, wo, wi);
  }

  double SampleWeight(const double* p) const { return MeanRgb(p, kKd) + MeanRgb(p, kKs); }
};

}  // namespace brdfkit::test
