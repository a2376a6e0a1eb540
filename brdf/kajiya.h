// Kajiya 1985, "Anisotropic reflection models", SIGGRAPH 85 (Computer
// Graphics 19(3)): reflection from a surface with anisotropic micro-geometry
// computed from the Kirchhoff (tangent-plane) approximation of the scattered
// field, for a parameterised family of surfaces.
//
// Kirchhoff integral (as Kajiya writes it after Beckmann & Spizzichino
// 1963, "The scattering of electromagnetic waves from rough surfaces"):
// with k = 2 pi / lambda, v = k (k_r - k_i) and the local Fresnel
// coefficient R of the tangent plane, the scattered field of a patch of area
// A over the height field z(x, y) is
//   E_2 ~ int_A (a z_x + b z_y - c) exp(i v.r) dx dy,
//   a = (1 - R) sin t1 + (1 + R) sin t2 cos t3,  b = (1 + R) sin t2 sin t3,
//   c = (1 + R) cos t2 - (1 - R) cos t1,
// (t1 incidence, t2 exit polar angle, t3 exit azimuth from the plane of
// incidence). Kajiya evaluates it per facet of the micro-geometry. Where the
// phase varies over many wavelengths within a facet, stationary phase leaves
// only the points whose normal is the bisector m = h / |h|, h = wi + wo, and
// R evaluated on them; averaging |E_2|^2 over the surface's slope statistics
// gives Beckmann & Spizzichino's geometric-optics result with Kajiya's local R
//
//   f_r = |R(wi.m)|^2 (1 + wi.wo)^2 p(zeta_u, zeta_v) / (cos_i cos_o (cos_i + cos_o)^4),
//
// with p the joint density of surface slopes and zeta = -h_xy / h_z the slope
// of the stationary-phase facet. (1 + wi.wo)^2 = (h.h)^2 / 4 is the squared
// geometric factor F_3 of Beckmann (1 + cos t1 cos t2 - sin t1 sin t2 cos t3);
// it equals the microfacet form |R|^2 D(m) / (4 cos_i cos_o) with
// D(m) = p(zeta) / cos^4(theta_m).
//
// Surface family: a stationary random surface with Gaussian slopes of rms
// sigma_u across and sigma_v along an axis u rotated by `angle` from x
// (brushed or lathed metal: sigma_v << sigma_u):
//   p(zeta_u, zeta_v) = exp(-zeta_u^2 / (2 sigma_u^2) - zeta_v^2 / (2 sigma_v^2)) / (2 pi sigma_u sigma_v).
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// What is approximated (as in Kajiya's Kirchhoff evaluation):
//  - tangent plane: the local field is the Fresnel reflection off the
//    tangent plane, so the radius of curvature must be large against lambda;
//  - stationary phase (geometric optics): the surface is rough on the scale
//    of the wavelength (height rms * k * (cos_i + cos_o) >> 1), so there is no
//    coherent specular spike and no diffraction; the wavelength drops out;
//  - no shadowing or masking and no multiple scattering: the Kirchhoff
//    integral illuminates and sees every facet. The 1 / (cos_i cos_o) is
//    therefore not cancelled near the horizon and the albedo exceeds 1 at
//    grazing angles: brdfkit check reports it (it is the physics of the
//    approximation, not patched);
//  - the surface is described statistically: Kajiya's per-facet evaluation
//    of an explicit (tabulated or periodic) micro-geometry, with its
//    diffraction orders, is not implemented;
//  - |R|^2 is the unpolarised reflectance of the complex index n + ik at the
//    local angle of incidence (mean of s and p).
//  - The default k is 0.5, not 0: F depends on k through k^2, so k = 0 is a
//    stationary point from which a fit could not move k.
// Reciprocal: every factor is symmetric in wi, wo (wi.m = wo.m).
//
// Sampling: the distribution of normals D(m) cos(theta_m) is sampled exactly
// (Gaussian slopes in the rotated frame) and wi is the mirror of wo about m:
// pdf(wi) = D(m) cos(theta_m) / (4 wo.m). Samples below the horizon are invalid.
#pragma once

#include "brdf/core.h"
#include "brdf/microfacet.h"

#include <cmath>

namespace brdfkit {

class Kajiya {
 public:
  explicit Kajiya(const Settings& = {}) {}

  static constexpr Slot kSigmaU{"sigma_u", 0}, kSigmaV{"sigma_v", 1}, kAngle{"angle", 2}, kN{"n", 3, true},
      kK{"k", 6, true};
  static constexpr std::array kSlots{kSigmaU, kSigmaV, kAngle, kN, kK};
  static constexpr unsigned kKind = LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;
  // Gaussian slopes of rms sigma are a Beckmann lobe with alpha = sqrt(2) sigma;
  // along x and y the rms slope of the rotated ellipse is its marginal.
  LobeWidth Width(const double* p) const {
    const double su = At(p, kSigmaU), sv = At(p, kSigmaV);
    const double c = std::cos(At(p, kAngle)), s = std::sin(At(p, kAngle));
    return {std::sqrt(2.0 * (su * su * c * c + sv * sv * s * s)), std::sqrt(2.0 * (su * su * s * s + sv * sv * c * c))};
  }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "kajiya";
    info.summary = "Kajiya 1985 Kirchhoff reflection, anisotropic Gaussian slopes, complex-index Fresnel";
    using S = ParamInfo::Scale;
    info.params.push_back({"sigma_u", 1e-3, 2.0, 0.3, false, "rms surface slope across the grooves", S::kLog});
    info.params.push_back({"sigma_v", 1e-3, 2.0, 0.1, false, "rms surface slope along the grooves", S::kLog});
    info.params.push_back({"angle", 0.0, kPi, 0.0, false, "direction of the across-groove axis from x (radians)"});
    info.params.push_back({"n", 0.05, 20.0, 1.5, true, "real part of the complex refractive index"});
    info.params.push_back({"k", 0.0, 20.0, 0.5, true, "imaginary part of the complex refractive index"});
    info.reciprocal = true;
    info.energy_conserving = false;  // no shadowing: the albedo exceeds 1 near grazing
    return info;
  }

  // Slopes of a normal direction in the rotated (u, v) frame: zeta = -m_uv / m_z.
  template <typename T>
  static void Slopes(const T* p, const Vec3<T>& m, T& zu, T& zv) {
    using std::cos;
    using std::sin;
    const T c = cos(At(p, kAngle)), s = sin(At(p, kAngle));
    zu = -(c * m.x() + s * m.y()) / m.z();
    zv = -(-s * m.x() + c * m.y()) / m.z();
  }

  // Distribution of normals D(m) = p(zeta) / cos^4(theta_m); int D cos dm = 1.
  template <typename T>
  T D(const T* p, const Vec3<T>& m) const {
    using std::exp;
    using std::log;
    if (m.z() <= T(0)) return T(0);  // back-facing normals do not exist on a height field
    T zu, zv;
    Slopes(p, m, zu, zv);
    const T su = At(p, kSigmaU), sv = At(p, kSigmaV);
    const T e = T(0.5) * (zu * zu / (su * su) + zv * zv / (sv * sv));
    // Log form: exp(-e) and 1 / cos^4 overflow separately near the horizon.
    const T m2 = m.z() * m.z() / m.squaredNorm();
    return exp(-e - T(2) * log(m2)) / (T(2 * kPi) * su * sv);
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const Vec3<T> m = HalfVector(wi, wo);
    // |R|^2 (1 + wi.wo)^2 p / (cos_i cos_o (cos_i + cos_o)^4) written as
    // |R|^2 D(m) / (4 cos_i cos_o): the same number without the fourth power
    // of a sum that underflows in float at grazing pairs.
    const T scalar = D(p, m) / (T(4) * wi.z() * wo.z());
    const T cos_d = HalfCos(wi, wo);  // = wi.m; the dot product goes negative by rounding for opposite grazing pairs
    Rgb<T> f;
    for (int c = 0; c < 3; ++c) f[c] = FresnelConductor(At(p, kN, c), At(p, kK, c), cos_d) * scalar;
    return f;
  }

  template <typename T>
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const {
    if (!SameUpperHemisphere(wi, wo)) return T(0);
    const Vec3<T> m = HalfVector(wi, wo);
    return D(p, m) * m.z() / (T(4) * HalfCos(wi, wo));  // wo.m by HalfCos: never <= 0 by rounding
  }

  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    BsdfSample<T> s;
    if (wo.z() <= T(0)) return s;
    // Gaussian slopes by Box-Muller in the (u, v) frame; 1 - u1 keeps the log finite.
    const double r = std::sqrt(-2.0 * std::log1p(-u1));
    const double zu = Value(At(p, kSigmaU)) * r * std::cos(2 * kPi * u2);
    const double zv = Value(At(p, kSigmaV)) * r * std::sin(2 * kPi * u2);
    const double c = std::cos(Value(At(p, kAngle))), sn = std::sin(Value(At(p, kAngle)));
    const double zx = c * zu - sn * zv, zy = sn * zu + c * zv;
    const Eigen::Vector3d m = Eigen::Vector3d(-zx, -zy, 1.0).normalized();
    Eigen::Vector3d wi;
    if (!ReflectAbout(wo, m, wi)) return s;  // facet seen from behind
    return SampledFrom(*this, p, wo, wi);
  }

  double SampleWeight(const double* p) const {
    double s = 0;
    for (int c = 0; c < 3; ++c) s += FresnelConductor(At(p, kN, c), At(p, kK, c), 0.7);
    return s / 3.0;
  }
};

}  // namespace brdfkit
