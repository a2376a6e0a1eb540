// Rough dielectric BSDF: reflection and refraction at a rough interface
// between two dielectrics (Walter, Marschner, Li, Torrance 2007, "Microfacet
// Models for Refraction through Rough Surfaces"), GGX or Beckmann microfacets.
//
// Sides and index. The interface separates the outside (z > 0, index eta_out)
// from the inside (z < 0, index eta_in); the parameter is the relative index
// eta = eta_in / eta_out (eta < 1: a denser medium outside). Both wi and wo
// may lie on either side. For a pair the index ratio is
//   eta_r = eta_wi / eta_wo  (index on wi's side over that on wo's side),
// so eta_r = eta for wo outside and wi inside, 1 / eta for the reverse, 1 for
// a pair on one side (RelativeIndex below). The Fresnel term of a facet seen
// from wo's side uses the index of the far side over that of wo's side,
// eta' = eta for wo.z > 0 and 1 / eta for wo.z < 0 (total internal reflection
// where eta' < 1).
//
//   reflection (wi.z wo.z > 0), h = sign(h.z) (wi + wo) / |wi + wo|:
//     f_r = F(|wo.h|, eta') D(h) G(wi, wo, h) / (4 |wi.z| |wo.z|)
//                                                        (Walter 2007 eq. 20)
//   refraction (wi.z wo.z < 0), h = sign(h.z) (eta' wi + wo) / |eta' wi + wo|:
//     f_t = |wi.h| |wo.h| (1 - F(|wo.h|, eta')) D(h) G(wi, wo, h)
//           / (|wi.z| |wo.z| (eta' wi.h + wo.h)^2)      (Walter 2007 eq. 21
//                                 and 16, index 1 on wo's side, eta' on wi's)
//   both zero unless the facet faces each direction from its own side:
//   (wi.h) wi.z > 0 and (wo.h) wo.z > 0 (Walter 2007 eq. 19's chi+).
// Computed as written symmetrically in (wi, wo): h from n_wi wi + n_wo wo
// (n = 1 outside, eta inside), (eta' wi.h + wo.h)^2 = |n_wi wi + n_wo wo|^2
// / n_wo^2, and F of a refraction pair at the cosine of the outside
// direction (Fresnel's reflectance is the same from both sides), so that
// swapping wi and wo rounds alike.
//
// This is f in pbrt's radiance convention (pbrt-v4 DielectricBxDF, mode
// Radiance; no cosine): light refracted from wi into wo is scaled by
// eta_wo^2 / eta_wi^2, so f is not symmetric but obeys the generalised
// reciprocity f(wi, wo) / eta_wo^2 = f(wo, wi) / eta_wi^2 (Veach 1997,
// sec. 5.2), i.e. f(wi, wo) eta_r^2 = f(wo, wi). Energy conservation holds for
// the power scattered from a light direction, int f(wi, wo) |wo.z| dwo <= 1
// for every wi; the radiance albedo int f(wi, wo) |wi.z| dwi exceeds 1 for
// wo inside a denser medium (in the smooth limit it is F + (1 - F) / eta_r^2,
// F + (1 - F) eta^2 for wo inside).
//
// D: GGX (Walter 2007 eq. 33) or Beckmann (eq. 25), evaluated at the facet
// normal h turned to the outside. G: separable Smith, G = G1(wi) G1(wo),
// G1(w) = 1 / (1 + Lambda(w)) (Walter 2007 eq. 23 with Heitz 2014 eq. 43,
// 83, 86), or height-correlated Smith, G = 1 / (1 + Lambda(wi) +
// Lambda(wo)) for reflection and refraction alike (Heitz 2014 eq. 99 and
// 102 with Lambda even in w.z; the form Blender Cycles' glass uses), each
// zero unless the facet faces both directions from their sides; Lambda
// depends on w.z only through w.z^2, so it is the same seen from either
// side. F: exact unpolarised dielectric Fresnel reflectance.
//
// Sampling over the whole sphere: reflection is chosen with probability
// P_R = F(|wo.z|, eta') clamped to [0.05, 0.95] (the Fresnel term at the
// macro normal: the model's Sample receives two random numbers and the
// facet normal consumes both, so the choice precedes the normal and u1 is
// reused within the chosen branch), then a facet normal is drawn: GGX from
// the visible normals seen from wo (Heitz 2018) and Beckmann from D(h) h.z
// (Walter 2007 eq. 28), and wo is reflected or refracted about it.
//   pdf = P_R p(h) / (4 |wo.h|)                   for reflection pairs,
//   pdf = (1 - P_R) p(h) eta'^2 |wi.h| / (eta' wi.h + wo.h)^2  for refraction
//         (Walter 2007 eq. 14 and 17), p(h) the density of the facet normal.
// A refraction sampled at total internal reflection, or a direction on the
// wrong side, is returned invalid: the pdf integrates over the sphere to the
// share of valid samples.
//
// Approximation: single scattering (energy is lost at high roughness).
#pragma once

#include "brdf/core.h"
#include "brdf/microfacet.h"

#include <array>

namespace brdfkit {

// Derived supplies kName and kSummary; Dist is GGX or Beckmann.
template <typename Derived, MicrofacetDistribution Dist, SmithForm Smith = SmithForm::kSeparable>
class RoughDielectricModel {
 public:
  explicit RoughDielectricModel(const Settings& = {}) {}

  static constexpr Slot kAlpha{"alpha", 0};
  static constexpr Slot kEta{"eta", 1};
  static constexpr std::array kSlots{kAlpha, kEta};
  static constexpr unsigned kKind = LobeKind::kGlossy | LobeKind::kTransmission;
  static constexpr MicrofacetDistribution kDist = Dist;
  static constexpr SmithForm kSmith = Smith;
  static constexpr bool kChannelsIndependent = true;
  LobeWidth Width(const double* p) const { return {At(p, kAlpha), At(p, kAlpha)}; }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = Derived::kName;
    info.summary = Derived::kSummary;
    using S = ParamInfo::Scale;
    info.params.push_back({"alpha", 1e-4, 1.0, 0.3, false, "roughness (alpha = r^2)", S::kLog});
    info.params.push_back({"eta", 0.2, 5.0, 1.5, false, "relative index eta_inside / eta_outside", S::kLinear});
    // Refraction obeys f(wi, wo) / eta_wo^2 = f(wo, wi) / eta_wi^2 instead.
    info.reciprocal = false;
    // F <= 1 and G <= G1 of the light direction (both forms): the power
    // scattered is at most the visible-normal measure.
    info.energy_conserving = true;
    return info;
  }

  // eta_wi / eta_wo: the index on wi's side over that on wo's side.
  template <typename T>
  T RelativeIndex(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if ((wi.z() > T(0)) == (wo.z() > T(0))) return T(1);
    return wo.z() > T(0) ? At(p, kEta) : T(1) / At(p, kEta);
  }

  template <typename T>
  T D(const T* p, const Vec3<T>& wm) const {
    const T a = At(p, kAlpha);
    if constexpr (Dist == MicrofacetDistribution::kGgx) return DGgx(wm, a, a);
    else return DBeckmann(wm, a, a);
  }

  // Smith masking of the facet wm (outside-facing) seen from w on either
  // side: zero when the facet faces away from w's side.
  template <typename T>
  T G1(const T* p, const Vec3<T>& w, const Vec3<T>& wm) const {
    if (w.dot(wm) * w.z() <= T(0)) return T(0);  // back side of the facet, or w on the surface
    const T a = At(p, kAlpha);
    if constexpr (Dist == MicrofacetDistribution::kGgx) return T(1) / (T(1) + LambdaGgx(w, a, a));
    else return T(1) / (T(1) + LambdaBeckmann(w, a, a));
  }

  // Masking-shadowing of the pair about the facet h (Geometry has checked
  // that h faces both directions from their sides).
  template <typename T>
  T G2(const T* p, const Vec3<T>& wi, const Vec3<T>& wo, const Vec3<T>& h) const {
    if constexpr (Smith == SmithForm::kSeparable) {
      return G1(p, wi, h) * G1(p, wo, h);
    } else {
      const T a = At(p, kAlpha);
      if constexpr (Dist == MicrofacetDistribution::kGgx)
        return T(1) / (T(1) + LambdaGgx(wi, a, a) + LambdaGgx(wo, a, a));
      else
        return T(1) / (T(1) + LambdaBeckmann(wi, a, a) + LambdaBeckmann(wo, a, a));
    }
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const {
    const Pair<T> q = Geometry(p, wi, wo);
    if (!q.valid) return Rgb<T>::Constant(T(0));
    const T dg = D(p, q.h) * G2(p, wi, wo, q.h);
    T value;
    if (q.reflect) {
      value = q.fresnel * dg / (T(4) * q.abs_ci * q.abs_co);
    } else {
      // (eta' wi.h + wo.h)^2 = |eta' wi + wo|^2 = len2 / n_wo^2.
      value = (T(1) - q.fresnel) * dg * q.abs_wi_h * q.abs_wo_h * q.n_wo * q.n_wo / (q.abs_ci * q.abs_co * q.len2);
    }
    return Rgb<T>::Constant(value);
  }

  template <typename T>
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const {
    const Pair<T> q = Geometry(p, wi, wo);
    if (!q.valid) return T(0);
    const T pr = ReflectProbability(p, wo);
    const T ph = NormalPdf(p, wo, q.h);
    if (q.reflect) return pr * ph / (T(4) * q.abs_wo_h);
    // eta'^2 |wi.h| / (eta' wi.h + wo.h)^2 = n_wi^2 |wi.h| / len2.
    return (T(1) - pr) * ph * q.n_wi * q.n_wi * q.abs_wi_h / q.len2;
  }

  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    BsdfSample<T> s;
    if (wo.z() == T(0)) return s;  // on the surface: no side to scatter from
    const double pr = Value(ReflectProbability(p, wo));
    const bool reflect = u1 < pr;
    // u1 rescaled to [0, 1) within the chosen branch; the clamp keeps
    // rounding from reaching 1.
    const double u = std::min(reflect ? u1 / pr : (u1 - pr) / (1.0 - pr), 1.0 - 1e-16);
    const Eigen::Vector3d v(Value(wo.x()), Value(wo.y()), Value(wo.z()));
    const double a = Value(At(p, kAlpha));
    Eigen::Vector3d h;
    if constexpr (Dist == MicrofacetDistribution::kGgx) {
      // Visible normals of the side wo is on: sample about wo turned outside.
      h = SampleGgxVisibleNormal(a, a, v.z() > 0 ? v : Eigen::Vector3d(-v), u, u2);
    } else {
      h = SampleBeckmannNormal(a, a, u, u2);
    }
    const double dwo = v.dot(h);
    if (dwo * v.z() <= 0) return s;  // facet seen from behind
    Eigen::Vector3d wi;
    if (reflect) {
      wi = 2.0 * dwo * h - v;
    } else {
      // Refraction of v about h with relative index eta' (pbrt-v4 Refract).
      const double eta = v.z() > 0 ? Value(At(p, kEta)) : 1.0 / Value(At(p, kEta));
      const double c = std::abs(dwo);
      const double sin2_t = (1.0 - c * c) / (eta * eta);
      if (sin2_t >= 1.0) return s;  // total internal reflection: nothing refracts
      const double cos_t = std::sqrt(1.0 - sin2_t);
      const Eigen::Vector3d n = dwo > 0 ? h : Eigen::Vector3d(-h);
      wi = -v / eta + (c / eta - cos_t) * n;
    }
    // A reflection must stay on wo's side and a refraction cross over.
    if (wi.z() * v.z() <= 0 ? reflect : !reflect) return s;
    s.wi = Vec3<T>(T(wi.x()), T(wi.y()), T(wi.z()));
    s.pdf = Pdf(p, wo, s.wi);
    s.valid = s.pdf > T(0);
    return s;
  }

  double SampleWeight(const double*) const { return 1.0; }  // reflection plus refraction scatter about everything

 private:
  template <typename T>
  struct Pair {
    bool valid = false, reflect = false;
    Vec3<T> h;
    T n_wi, n_wo;  // the index on wi's and on wo's side, relative to the outside
    T len2, abs_ci, abs_co, abs_wi_h, abs_wo_h, fresnel;
  };

  // The facet normal that takes wo to wi, and the quantities Eval and Pdf
  // share; invalid where f = 0. Written symmetrically in (wi, wo), so that
  // swapping them rounds the same way and reciprocity holds to the last bit.
  template <typename T>
  static Pair<T> Geometry(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) {
    using std::abs;
    using std::sqrt;
    Pair<T> q;
    const T ci = wi.z(), co = wo.z();
    if (ci == T(0) || co == T(0)) return q;  // on the surface: no projected area (1 / cos below)
    const T eta = At(p, kEta);
    q.reflect = (ci > T(0)) == (co > T(0));
    q.n_wi = ci > T(0) ? T(1) : eta;
    q.n_wo = co > T(0) ? T(1) : eta;
    // Generalised half vector n_wi wi + n_wo wo (Walter 2007 eq. 16), wi + wo for reflection.
    const Vec3<T> hv = q.reflect ? Vec3<T>(wi + wo) : Vec3<T>(wi * q.n_wi + wo * q.n_wo);
    q.len2 = hv.squaredNorm();
    // wi = -wo on one side (grazing opposite pair), or refraction at eta = 1
    // along -wo (a delta, no finite density): no facet normal.
    if (!(q.len2 > T(0))) return q;
    q.h = hv / sqrt(q.len2);
    if (q.h.z() < T(0)) q.h = -q.h;  // facet normals face the outside
    const T dwi = wi.dot(q.h), dwo = wo.dot(q.h);
    if (dwi * ci <= T(0) || dwo * co <= T(0)) return q;  // the facet faces away from one of the sides
    q.abs_ci = abs(ci);
    q.abs_co = abs(co);
    q.abs_wi_h = abs(dwi);
    q.abs_wo_h = abs(dwo);
    if (q.reflect) {
      // wi.h = wo.h = |wi + wo| / 2 (HalfCos), seen from their side.
      q.fresnel = FresnelDielectric(co > T(0) ? eta : T(1) / eta, T(sqrt(q.len2) / T(2)));
    } else {
      // Fresnel's reflectance is the same from both sides: take the outside one.
      q.fresnel = FresnelDielectric(eta, ci > T(0) ? q.abs_wi_h : q.abs_wo_h);
    }
    q.valid = true;
    return q;
  }

  template <typename T>
  T ReflectProbability(const T* p, const Vec3<T>& wo) const {
    using std::abs;
    const T eta = wo.z() > T(0) ? At(p, kEta) : T(1) / At(p, kEta);
    const T f = FresnelDielectric(eta, T(abs(wo.z())));
    // Both branches keep a share: the facets tilt F away from its value at
    // the macro normal (refraction past the critical angle, reflection at eta = 1).
    return f < T(0.05) ? T(0.05) : (f > T(0.95) ? T(0.95) : f);
  }

  // Density of the sampled facet normal h (outside-facing) for wo.
  template <typename T>
  T NormalPdf(const T* p, const Vec3<T>& wo, const Vec3<T>& h) const {
    using std::abs;
    if constexpr (Dist == MicrofacetDistribution::kGgx) {
      // Visible normals from wo's side: G1(wo) |wo.h| D(h) / |wo.z|.
      return G1(p, wo, h) * abs(T(wo.dot(h))) * D(p, h) / abs(wo.z());
    } else {
      return D(p, h) * h.z();
    }
  }
};

struct GgxGlass : RoughDielectricModel<GgxGlass, MicrofacetDistribution::kGgx> {
  using RoughDielectricModel::RoughDielectricModel;
  static constexpr const char* kName = "ggx_glass";
  static constexpr const char* kSummary =
      "rough dielectric BSDF, GGX, separable Smith, exact Fresnel, reflection and refraction (Walter 2007)";
};

struct GgxGlassCorrelated
    : RoughDielectricModel<GgxGlassCorrelated, MicrofacetDistribution::kGgx, SmithForm::kHeightCorrelated> {
  using RoughDielectricModel::RoughDielectricModel;
  static constexpr const char* kName = "ggx_glass_correlated";
  static constexpr const char* kSummary =
      "rough dielectric BSDF, GGX, height-correlated Smith (as Blender Cycles' glass), exact Fresnel, reflection "
      "and refraction (Walter 2007, Heitz 2014)";
};

struct BeckmannGlass : RoughDielectricModel<BeckmannGlass, MicrofacetDistribution::kBeckmann> {
  using RoughDielectricModel::RoughDielectricModel;
  static constexpr const char* kName = "beckmann_glass";
  static constexpr const char* kSummary =
      "rough dielectric BSDF, Beckmann, separable Smith, exact Fresnel, reflection and refraction (Walter 2007)";
};

}  // namespace brdfkit
