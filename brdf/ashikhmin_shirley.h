// Ashikhmin-Shirley: anisotropic Phong lobe on the half vector with Schlick
// Fresnel, plus a diffuse term that takes the energy the specular layer
// leaves (Ashikhmin & Shirley 2000, "An anisotropic Phong BRDF model",
// JGT 5(2)).
//
//   specular (eq. 4):
//     sqrt((nu + 1)(nv + 1)) / (8 pi)
//       * (n.h)^((nu (h.u)^2 + nv (h.v)^2) / (1 - (n.h)^2))
//       / ((h.k) max(cos_i, cos_o)) * F(k.h),
//     F(c) = Rs + (1 - Rs)(1 - c)^5 (Schlick), h the unit half vector, k = wi
//   diffuse (eq. 5):
//     28 Rd / (23 pi) (1 - Rs) (1 - (1 - cos_i / 2)^5) (1 - (1 - cos_o / 2)^5)
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// Notes:
//  - At h = n the exponent is 0/0 while (n.h)^e = 1 for any e. The lobe is
//    evaluated as exp((nu hx^2 + nv hy^2) log(hz) / (hx^2 + hy^2)), with
//    log(hz) / sin^2 = log1p(-sin^2) / (2 sin^2) replaced by its Taylor
//    series for small sin^2; it is exactly 1 with finite derivatives at h = n.
//  - The 1 / ((h.k) max(cos_i, cos_o)) factor is the paper's heuristic for
//    masking and the half-vector Jacobian; it is reciprocal but not derived
//    from a surface. With dwi = 4 (h.k) dwh the specular albedo is
//    int p_h(h) F cos_i / max(cos_i, cos_o) dwh <= int p_h dwh = 1, so the
//    specular term alone never exceeds 1. The paper also claims the sum with
//    the diffuse term conserves energy; that is not proven here (it needs
//    int p_h (1 - k.h)^5 cos_i / max(...) <= (1 - cos_o / 2)^5), so the flag
//    stays false; the tests find the total below 1 in every case tried.
//  - With Rs = 1 and nu = nv = n the albedo at normal incidence is
//    2 (n+1)/(n+3) (1 - 2^(-(n+3)/2)) - (1 - 2^(-(n+1)/2)) = 1 - 4/(n+3) + ...
//    (close to 1 for large exponents only); at grazing it tends to 1/2.
//  - The constant 28/23 normalises the angular factor: int (1 - (1 - cos/2)^5)
//    cos dw = 23 pi / 28, so the diffuse albedo is exactly
//    Rd (1 - Rs) (1 - (1 - cos_o / 2)^5), at most 31/32 Rd (1 - Rs).
//
// Sampling: a mixture of the paper's half-vector sampling (eqs. 9-10),
//   phi_h = atan(sqrt((nu + 1) / (nv + 1)) tan(pi u / 2)) per quadrant,
//   cos theta_h = (1 - u2)^(1 / (nu cos^2 phi_h + nv sin^2 phi_h + 1)),
//   p_h(h) = sqrt((nu + 1)(nv + 1)) / (2 pi) (n.h)^(nu cos^2 phi_h + nv sin^2 phi_h),
//   pdf(wi) = p_h(h) / (4 wo.h),
// and cosine-weighted sampling for the diffuse term, chosen in proportion to
// the mean of Rs + (1 - Rs)/21 and of Rd (1 - Rs).
#pragma once

#include "brdf/core.h"

#include <algorithm>
#include <cmath>

namespace brdfkit {

struct AshikhminShirley {
  explicit AshikhminShirley(const Settings& = {}) {}

  static constexpr Slot kRd{"rd", 0, true}, kRs{"rs", 3, true}, kNu{"nu", 6}, kNv{"nv", 7};
  static constexpr std::array kSlots{kRd, kRs, kNu, kNv};
  static constexpr unsigned kKind = LobeKind::kDiffuse | LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;
  // The half-vector lobe is cos^nu(theta_h) along x and cos^nv along y.
  LobeWidth Width(const double* p) const { return {PhongExponentWidth(At(p, kNu)), PhongExponentWidth(At(p, kNv))}; }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "ashikhmin_shirley";
    info.summary = "Ashikhmin-Shirley 2000 anisotropic Phong with Schlick Fresnel and coupled diffuse";
    using S = ParamInfo::Scale;
    info.params.push_back({"rd", 0.0, 1.0, 0.3, true, "diffuse reflectance Rd"});
    info.params.push_back({"rs", 0.0, 1.0, 0.05, true, "specular reflectance at normal incidence Rs"});
    info.params.push_back({"nu", 1e-3, 1e8, 100.0, false, "Phong exponent along x", S::kLog});
    info.params.push_back({"nv", 1e-3, 1e8, 100.0, false, "Phong exponent along y", S::kLog});
    info.reciprocal = true;
    info.energy_conserving = false;  // specular part bounded; the sum with the diffuse term unproven (header)
    return info;
  }

  // (n.h)^(nu cos^2 phi_h + nv sin^2 phi_h) for the unit half vector h.
  template <typename T>
  static T Lobe(const T* p, const Vec3<T>& h) {
    using std::exp;
    using std::log;
    using std::log1p;
    const T hx2 = h.x() * h.x(), hy2 = h.y() * h.y();
    const T s2 = hx2 + hy2;
    T log_c_over_s2;
    if (s2 < T(1e-4)) {
      // log(hz) / s2 = log(1 - s2) / (2 s2): series at h = n (0/0 there);
      // the next term s2^4 / 10 is below 1e-16.
      log_c_over_s2 = T(-0.5) * (T(1) + s2 * (T(0.5) + s2 * (T(1) / T(3) + s2 * T(0.25))));
    } else if (s2 < T(0.5)) {
      log_c_over_s2 = log1p(-s2) / (T(2) * s2);
    } else {
      // Near the horizon 1 - s2 loses hz to rounding; log(hz) does not.
      log_c_over_s2 = log(h.z()) / s2;
    }
    return exp((At(p, kNu) * hx2 + At(p, kNv) * hy2) * log_c_over_s2);
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    using std::sqrt;
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const Vec3<T> h = HalfVector(wi, wo);
    const T k_h = HalfCos(wi, wo);  // = wi.h; the dot product goes negative by rounding for opposite grazing pairs
    const T max_cos = wi.z() > wo.z() ? wi.z() : wo.z();
    const T spec = sqrt((At(p, kNu) + T(1)) * (At(p, kNv) + T(1))) * T(0.125 * kInvPi) * Lobe(p, h) / (k_h * max_cos);
    // Rounding can put k.h just above 1; (1 - k.h)^5 must not go negative.
    const T one_minus_kh = k_h < T(1) ? T(1) - k_h : T(0);
    const T schlick = one_minus_kh * one_minus_kh * one_minus_kh * one_minus_kh * one_minus_kh;
    const T a = T(1) - wi.z() / T(2), b = T(1) - wo.z() / T(2);
    const T diff_angular = (T(1) - a * a * a * a * a) * (T(1) - b * b * b * b * b) * T(28.0 / 23.0 * kInvPi);
    Rgb<T> f;
    for (int c = 0; c < 3; ++c) {
      const T& rd = At(p, kRd, c);
      const T& rs = At(p, kRs, c);
      f[c] = rd * (T(1) - rs) * diff_angular + (rs + (T(1) - rs) * schlick) * spec;
    }
    return f;
  }

  template <typename T>
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const {
    using std::sqrt;
    if (!SameUpperHemisphere(wi, wo)) return T(0);
    double pd, ps;
    LobeProbabilities(p, pd, ps);
    const Vec3<T> h = HalfVector(wi, wo);
    const T spec = sqrt((At(p, kNu) + T(1)) * (At(p, kNv) + T(1))) * T(0.5 * kInvPi) * Lobe(p, h) / (T(4) * HalfCos(wi, wo));
    return T(pd) * wi.z() * T(kInvPi) + T(ps) * spec;
  }

  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    BsdfSample<T> s;
    if (wo.z() <= T(0)) return s;
    double pd, ps;
    LobeProbabilities(p, pd, ps);
    Eigen::Vector3d wi;
    if (u1 < pd) {
      // Reuse u1 within the diffuse interval; the clamp keeps it below 1.
      const Vec3<double> c = SampleCosineHemisphere<double>(std::min(u1 / pd, 1.0 - 1e-16), u2);
      wi = Eigen::Vector3d(c.x(), c.y(), c.z());
    } else {
      const double v = std::min((u1 - pd) / ps, 1.0 - 1e-16);
      const double nu = Value(At(p, kNu)), nv = Value(At(p, kNv));
      // Eq. 9 over all four quadrants at once: tan(phi) = sqrt((nu+1)/(nv+1)) tan(psi).
      const double psi = 2.0 * kPi * u2;
      const double phi = std::atan2(std::sqrt(nu + 1.0) * std::sin(psi), std::sqrt(nv + 1.0) * std::cos(psi));
      const double cp = std::cos(phi), sp = std::sin(phi);
      const double e = nu * cp * cp + nv * sp * sp;
      // Eq. 10 in log form: 1 - cos stays accurate for exponents up to 1e8.
      const double log_c = std::log1p(-v) / (e + 1.0);
      const double c = std::exp(log_c);
      const double sin_t = std::sqrt(std::max(0.0, -std::expm1(log_c) * (1.0 + c)));
      const Eigen::Vector3d h(sin_t * cp, sin_t * sp, c);
      if (!ReflectAbout(wo, h, wi)) return s;  // half vector seen from behind: no reflection
    }
    return SampledFrom(*this, p, wo, wi);
  }

  double SampleWeight(const double* p) const {
    double pd, ps;
    return Weights(p, pd, ps);
  }

 private:
  // Approximate albedos of the two terms: Rd (1 - Rs) and the hemispherical
  // average of Schlick's F, Rs + (1 - Rs) / 21. Returns their sum.
  template <typename T>
  static double Weights(const T* p, double& wd, double& ws) {
    wd = ws = 0;
    for (int c = 0; c < 3; ++c) {
      const double rd = Value(At(p, kRd, c)), rs = Value(At(p, kRs, c));
      wd += rd * (1.0 - rs) / 3.0;
      ws += (rs + (1.0 - rs) / 21.0) / 3.0;
    }
    return wd + ws;
  }

  template <typename T>
  static void LobeProbabilities(const T* p, double& pd, double& ps) {
    double wd, ws;
    const double total = Weights(p, wd, ws);  // ws >= 1/21: never zero
    pd = wd / total;
    ps = ws / total;
  }
};

}  // namespace brdfkit
