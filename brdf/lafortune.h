// Lafortune, Foo, Torrance & Greenberg 1997, "Non-Linear Approximation of
// Reflectance Functions", SIGGRAPH '97: one generalized cosine lobe
//
//   f_r = rho (n + 2) / (2 pi) max(0, cx wi_x wo_x + cy wi_y wo_y + cz wi_z wo_z)^n.
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// Relation to the paper's parameters: the paper writes a lobe as
// [Cx ux vx + Cy uy vy + Cz uz vz]^n with its magnitude folded into C, so
// magnitude and direction are entangled through the exponent. Here the scale
// is explicit: a paper lobe C maps to c = C / max|C_k| and
// rho = 2 pi / (n + 2) max|C_k|^n (rho > 1 is outside the range, and such a
// lobe is not bound to conserve energy). c sets the lobe axis
// normalize(cx wo_x, cy wo_y, cz wo_z) and, through |c o wo|^n, dims the lobe
// where c o wo is short. Typical lobes: (-1, -1, 1) is the normalised Phong
// lobe (model phong, exactly); (0, 0, 1) a non-Lambertian diffuse lobe;
// (1, 1, 1) retro-reflection; -cx = -cy > cz forward reflection that grows
// towards grazing (off-specular peak); cx != cy anisotropy.
//
// Several lobes are a sum: "lafortune+lafortune" (parameters lafortune.cx,
// lafortune#2.cx, ...); add lambert for the paper's diffuse term.
//
// Reciprocal (the form is symmetric in wi, wo). Energy-conserving within the
// ranges above: the base is (c o wo).wi <= |c o wo| cos(angle to the axis)
// with |c o wo| <= 1, and a clipped cos^n lobe weighted by cos_theta_i
// integrates over the hemisphere to at most 2 pi / (n + 2), reached with the
// axis on the normal (the integral of two lobes decreasing away from their
// axes is largest when the axes coincide), so E <= rho.
// Sampling draws the cos^n lobe around the axis; samples below the horizon
// are invalid. A lobe whose axis vanishes (c o wo = 0) is black and returns
// no sample.
#pragma once

#include "brdf/core.h"
#include "brdf/phong.h"

#include <algorithm>

namespace brdfkit {

struct Lafortune {
  explicit Lafortune(const Settings& = {}) {}

  static constexpr Slot kRho{"rho", 0, true}, kCx{"cx", 3}, kCy{"cy", 4}, kCz{"cz", 5}, kN{"n", 6};
  static constexpr std::array kSlots{kRho, kCx, kCy, kCz, kN};
  static constexpr unsigned kKind = LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;
  static constexpr bool kVanishes = true;  // zero with its colour parameters at 0
  // The cos^n lobe about its axis; |c| < 1 only lowers it, not its width.
  LobeWidth Width(const double* p) const {
    const double w = PhongExponentWidth(At(p, kN));
    return {w, w};
  }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "lafortune";
    info.summary = "generalized cosine lobe rho (n+2)/(2 pi) (c o wi . wo)^n (Lafortune et al. 1997)";
    info.params = {{"rho", 0.0, 1.0, 0.5, true, "lobe albedo scale"},
                   {"cx", -1.0, 1.0, -1.0, false, "weight of wi_x wo_x"},
                   {"cy", -1.0, 1.0, -1.0, false, "weight of wi_y wo_y"},
                   {"cz", -1.0, 1.0, 1.0, false, "weight of wi_z wo_z"},
                   PhongExponentParam()};
    info.reciprocal = true;
    info.energy_conserving = true;
    return info;
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const T& n = At(p, kN);
    // wi_k wo_k first: the products commute exactly, so f(wi, wo) == f(wo, wi) bit for bit.
    const T base = At(p, kCx) * (wi.x() * wo.x()) + At(p, kCy) * (wi.y() * wo.y()) + At(p, kCz) * (wi.z() * wo.z());
    const T lobe = (n + T(2)) * T(0.5 * kInvPi) * PowLobe(base, n);
    return RgbAt(p, kRho) * lobe;
  }

  // Unit lobe axis c o wo / |c o wo|; false when it vanishes.
  template <typename T>
  static bool Axis(const T* p, const Vec3<T>& wo, Vec3<T>& axis) {
    using std::sqrt;
    axis = Vec3<T>(At(p, kCx) * wo.x(), At(p, kCy) * wo.y(), At(p, kCz) * wo.z());
    const T len2 = axis.squaredNorm();
    if (len2 <= T(0)) return false;  // no axis: the lobe is zero everywhere
    axis /= sqrt(len2);
    return true;
  }

  template <typename T>
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const {
    if (!SameUpperHemisphere(wi, wo)) return T(0);
    Vec3<T> axis;
    if (!Axis(p, wo, axis)) return T(0);
    return CosinePowerLobePdf(axis, At(p, kN), wi);
  }

  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    BsdfSample<T> s;
    if (wo.z() <= T(0)) return s;
    Vec3<T> axis;
    if (!Axis(p, wo, axis)) return s;
    s.wi = SampleCosinePowerLobe(axis, At(p, kN), u1, u2);
    if (s.wi.z() <= T(0)) return s;  // the lobe reaches below the horizon
    s.pdf = Pdf(p, wo, s.wi);
    s.valid = s.pdf > T(0);
    return s;
  }

  // rho times max |c|^n, a bound on the lobe's albedo.
  double SampleWeight(const double* p) const {
    const double c = std::max({std::abs(At(p, kCx)), std::abs(At(p, kCy)), std::abs(At(p, kCz))});
    return MeanRgb(p, kRho) * std::pow(c, At(p, kN));
  }
};

}  // namespace brdfkit
