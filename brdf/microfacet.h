// Microfacet theory: GGX (Trowbridge-Reitz) and Beckmann distributions,
// isotropic and anisotropic; Smith masking-shadowing, separable and
// height-correlated; Fresnel (Schlick, exact dielectric, conductor); and the
// Cook-Torrance style reflection model built from them.
//
//   f_r(wi, wo) = D(wh) G2(wi, wo, wh) F(wi.wh) / (4 cos_theta_i cos_theta_o)
//                 (Walter et al. 2007, "Microfacet Models for Refraction
//                  through Rough Surfaces", eq. 20)
//
//   D_GGX(m)  = 1 / (pi ax ay (mx^2/ax^2 + my^2/ay^2 + mz^2)^2)
//               (Walter 2007 eq. 33; anisotropic form: Heitz 2014, eq. 82)
//   D_Beck(m) = exp(-(mx^2/ax^2 + my^2/ay^2) / mz^2) / (pi ax ay mz^4)
//               (Walter 2007 eq. 25; Heitz 2014 eq. 80)
//   Lambda_GGX(w)  = (sqrt(1 + a^2 tan^2) - 1) / 2         (Heitz 2014 eq. 86)
//   Lambda_Beck(w) = (erf(v) - 1) / 2 + exp(-v^2) / (2 v sqrt(pi)),
//                    v = 1 / (a tan)                       (Heitz 2014 eq. 83)
//     with a^2 tan^2 = (ax^2 wx^2 + ay^2 wy^2) / wz^2 for anisotropic alpha.
//   G1 = chi+(w.m) / (1 + Lambda(w))                        (Heitz 2014 eq. 43)
//   G2 separable = G1(wi) G1(wo); height-correlated = 1 / (1 + L(wi) + L(wo))
//                                                           (Heitz 2014 eq. 99)
//
// Sampling: GGX samples the distribution of visible normals (Heitz 2018,
// "Sampling the GGX Distribution of Visible Normals"); Beckmann samples
// D(m) cos(theta_m) through its Gaussian slope distribution (Walter 2007
// eq. 28, written in slope space). pdf(wi) = pdf(wm) / (4 |wo.wm|).
// Samples below the horizon are returned invalid, so the pdf integrates over
// the upper hemisphere to the fraction of samples that stay above it.
//
// Approximation: single scattering only (energy is lost at high roughness;
// the albedo tables of validate/ give the compensation).
#pragma once

#include "brdf/batch.h"
#include "brdf/core.h"

#include <string>
#include <type_traits>

namespace brdfkit {

// --- distributions ---------------------------------------------------------

// The direction arguments may be of a scalar type V other than T: double
// directions with Jet roughness keep the directions' arithmetic in double.
template <typename T, typename V>
inline T DGgx(const Vec3<V>& wm, const T& ax, const T& ay) {
  if (wm.z() <= V(0)) return T(0);  // back-facing microfacets do not exist
  const T e = wm.x() * wm.x() / (ax * ax) + wm.y() * wm.y() / (ay * ay) + wm.z() * wm.z();
  return T(1) / (T(kPi) * ax * ay * e * e);
}

template <typename T, typename V>
inline T DBeckmann(const Vec3<V>& wm, const T& ax, const T& ay) {
  using std::exp;
  if (wm.z() <= V(0)) return T(0);  // back-facing microfacets do not exist
  using std::log;
  const V z2 = wm.z() * wm.z();
  const T tan2_term = (wm.x() * wm.x() / (ax * ax) + wm.y() * wm.y() / (ay * ay)) / z2;
  // 1 / cos^4 folded into the exponent: near the horizon cos^4 underflows
  // (in float already at cos = 1e-10) while the exponential vanishes anyway.
  return exp(-tan2_term - V(2) * log(z2)) / (T(kPi) * ax * ay);
}

// The isotropic forms (ax = ay = a) sum the azimuthal terms in V first:
// on Jet roughness with double directions half the Jet operations.
template <typename T, typename V>
inline T DGgx(const Vec3<V>& wm, const T& a) {
  if (wm.z() <= V(0)) return T(0);  // back-facing microfacets do not exist
  const T a2 = a * a;
  const T e = V(wm.x() * wm.x() + wm.y() * wm.y()) / a2 + V(wm.z() * wm.z());
  return T(1) / (T(kPi) * a2 * e * e);
}

template <typename T, typename V>
inline T DBeckmann(const Vec3<V>& wm, const T& a) {
  using std::exp;
  using std::log;
  if (wm.z() <= V(0)) return T(0);  // back-facing microfacets do not exist
  const V z2 = wm.z() * wm.z();
  const T a2 = a * a;
  const T tan2_term = V((wm.x() * wm.x() + wm.y() * wm.y()) / z2) / a2;
  return exp(-tan2_term - V(2) * log(z2)) / (T(kPi) * a2);  // 1 / cos^4 in the exponent, as above
}

// a^2 tan^2(theta) for projected roughness along w (Heitz 2014 eq. 80 ff.).
template <typename T, typename V>
inline T Alpha2Tan2(const Vec3<V>& w, const T& ax, const T& ay) {
  return (ax * ax * w.x() * w.x() + ay * ay * w.y() * w.y()) / (w.z() * w.z());
}
template <typename T, typename V>
inline T Alpha2Tan2(const Vec3<V>& w, const T& a) {
  return a * a * V((w.x() * w.x() + w.y() * w.y()) / (w.z() * w.z()));
}

// Lambda from a^2 tan^2(theta).
template <typename T>
inline T LambdaGgxOf(const T& a2t2) {
  using std::sqrt;
  // (sqrt(1 + x) - 1) / 2 written without the cancellation near x = 0.
  return a2t2 / (T(2) * (T(1) + sqrt(T(1) + a2t2)));
}

template <typename T>
inline T LambdaBeckmannOf(const T& a2t2) {
  using std::erfc;
  using std::exp;
  using std::sqrt;
  if (a2t2 <= T(0)) return T(0);  // w along the normal: nothing is masked
  const T v = T(1) / sqrt(a2t2);
  // erf(v) - 1 = -erfc(v) keeps the small difference accurate for large v.
  return (exp(-v * v) / (v * T(1.7724538509055160273)) - erfc(v)) / T(2);
}

template <typename T, typename V>
inline T LambdaGgx(const Vec3<V>& w, const T& ax, const T& ay) {
  return LambdaGgxOf(Alpha2Tan2(w, ax, ay));
}

template <typename T, typename V>
inline T LambdaBeckmann(const Vec3<V>& w, const T& ax, const T& ay) {
  return LambdaBeckmannOf(Alpha2Tan2(w, ax, ay));
}

// --- Fresnel ----------------------------------------------------------------

// The cosine may be of a scalar type V other than T (see DGgx).
template <typename T, typename V>
inline T FresnelSchlick(const T& f0, const V& cos_theta) {
  // Rounding can put a cosine just outside [0, 1]; (1 - c)^5 must not go negative.
  const V c = cos_theta > V(1) ? V(1) : (cos_theta > V(0) ? cos_theta : V(0));
  const V m = V(1) - c;
  const V m2 = m * m;
  return f0 + (T(1) - f0) * (m2 * m2 * m);
}

// Unpolarised Fresnel reflectance of a dielectric interface with relative
// index eta (transmitted over incident), light arriving at cos_theta.
template <typename T, typename V>
inline T FresnelDielectric(const T& eta, const V& cos_theta) {
  using std::sqrt;
  const V c = cos_theta > V(0) ? cos_theta : V(0);
  const T sin2_t = (T(1) - c * c) / (eta * eta);
  if (sin2_t >= T(1)) return T(1);  // total internal reflection (eta < 1)
  const T cos_t = sqrt(T(1) - sin2_t);
  const T rs = (c - eta * cos_t) / (c + eta * cos_t);
  const T rp = (eta * c - cos_t) / (eta * c + cos_t);
  return (rs * rs + rp * rp) / T(2);
}

// Unpolarised Fresnel reflectance of a conductor with complex index eta + i k,
// real-valued form of the complex Fresnel equations.
template <typename T, typename V>
inline T FresnelConductor(const T& eta, const T& k, const V& cos_theta) {
  const V c = cos_theta > V(0) ? cos_theta : V(0);
  const V c2 = c * c;
  const V s2 = V(1) - c2;
  const T t0 = eta * eta - k * k - s2;
  const T a2b2 = SafeSqrt(T(t0 * t0 + T(4) * eta * eta * k * k));
  const T a = SafeSqrt(T((a2b2 + t0) / T(2)));
  const T t1 = a2b2 + c2;
  const T t2 = T(2) * a * c;
  // At c = 0 and a = 0 together (k = 0, eta <= 1) t1 + t2 = 0: that is
  // total reflection.
  if (t1 + t2 <= T(0)) return T(1);
  // Numerators as sums of squares, t1 - t2 = (a - c)^2 + b^2 and t3 - t4 =
  // (a c - s^2)^2 + b^2 c^2: the differences cancel to negative rounding
  // noise when eta = 1, k = 0.
  const T b2_raw = (a2b2 - t0) / T(2);
  const T b2 = b2_raw > T(0) ? b2_raw : T(0);
  const T rs = ((a - c) * (a - c) + b2) / (t1 + t2);
  const T t3 = c2 * a2b2 + s2 * s2;
  const T t4 = t2 * s2;
  const T rp = t3 + t4 > T(0) ? rs * ((a * c - s2) * (a * c - s2) + b2 * c2) / (t3 + t4) : rs;
  return (rs + rp) / T(2);
}

// --- sampling ----------------------------------------------------------------

// A GGX normal from the distribution of normals visible from v (v.z > 0),
// density G1(v, m) max(0, v.m) D(m) / v.z (Heitz 2018, listing 1: stretch,
// sample the projected hemisphere, unstretch).
inline Eigen::Vector3d SampleGgxVisibleNormal(double ax, double ay, const Eigen::Vector3d& v, double u1, double u2) {
  const Eigen::Vector3d vh = Eigen::Vector3d(ax * v.x(), ay * v.y(), v.z()).normalized();
  const double lensq = vh.x() * vh.x() + vh.y() * vh.y();
  const Eigen::Vector3d t1 =
      lensq > 0 ? Eigen::Vector3d(-vh.y(), vh.x(), 0) / std::sqrt(lensq) : Eigen::Vector3d(1, 0, 0);
  const Eigen::Vector3d t2 = vh.cross(t1);
  const double r = std::sqrt(u1), phi = 2.0 * kPi * u2;
  const double a = r * std::cos(phi);
  double b = r * std::sin(phi);
  const double s_blend = 0.5 * (1.0 + vh.z());
  b = (1.0 - s_blend) * std::sqrt(std::max(0.0, 1.0 - a * a)) + s_blend * b;
  const Eigen::Vector3d nh = a * t1 + b * t2 + std::sqrt(std::max(0.0, 1.0 - a * a - b * b)) * vh;
  return Eigen::Vector3d(ax * nh.x(), ay * nh.y(), std::max(0.0, nh.z())).normalized();
}

// A Beckmann normal with density D(m) cos(theta_m) (Walter 2007 eq. 28 in
// slope space: the slopes are Gaussian with variance alpha^2 / 2 per axis).
inline Eigen::Vector3d SampleBeckmannNormal(double ax, double ay, double u1, double u2) {
  const double r = std::sqrt(-std::log(1.0 - u1));
  const double phi = 2.0 * kPi * u2;
  return Eigen::Vector3d(-ax * r * std::cos(phi), -ay * r * std::sin(phi), 1.0).normalized();
}

// --- the model ---------------------------------------------------------------

enum class MicrofacetDistribution { kGgx, kBeckmann };
enum class SmithForm { kHeightCorrelated, kSeparable };
enum class FresnelForm { kSchlick, kDielectric, kConductor };

template <MicrofacetDistribution Dist, bool Aniso, SmithForm Smith, FresnelForm Fres>
struct MicrofacetConfig {
  static constexpr MicrofacetDistribution kDist = Dist;
  static constexpr bool kAniso = Aniso;
  static constexpr SmithForm kSmith = Smith;
  static constexpr FresnelForm kFresnel = Fres;
};

// Derived supplies kName and kSummary; Config is a MicrofacetConfig.
template <typename Derived, typename Config>
class MicrofacetModel {
 public:
  static constexpr std::size_t kRoughnessSlots = Config::kAniso ? 2 : 1;

  explicit MicrofacetModel(const Settings& = {}) {}

  static constexpr Slot kAlphaX{Config::kAniso ? "alpha_x" : "alpha", 0};
  static constexpr Slot kAlphaY{Config::kAniso ? "alpha_y" : "alpha", kRoughnessSlots - 1};
  // Fresnel: f0 (Schlick), eta (dielectric), or eta and k (conductor).
  static constexpr Slot kF0{"f0", kRoughnessSlots, true};
  static constexpr Slot kEta{"eta", kRoughnessSlots, Config::kFresnel == FresnelForm::kConductor};
  static constexpr Slot kK{"k", kRoughnessSlots + 3, true};
  static constexpr auto kSlots = [] {
    constexpr Slot r = kAlphaY;
    if constexpr (Config::kFresnel == FresnelForm::kSchlick) {
      if constexpr (Config::kAniso) return std::array{kAlphaX, r, kF0};
      else return std::array{kAlphaX, kF0};
    } else if constexpr (Config::kFresnel == FresnelForm::kDielectric) {
      if constexpr (Config::kAniso) return std::array{kAlphaX, r, kEta};
      else return std::array{kAlphaX, kEta};
    } else {
      if constexpr (Config::kAniso) return std::array{kAlphaX, r, kEta, kK};
      else return std::array{kAlphaX, kEta, kK};
    }
  }();
  static constexpr unsigned kKind = LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;
  LobeWidth Width(const double* p) const { return {At(p, kAlphaX), At(p, kAlphaY)}; }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = Derived::kName;
    info.summary = Derived::kSummary;
    using S = ParamInfo::Scale;
    const double lo = 1e-7, hi = 1.0;  // alpha < 1e-7 is a mirror to double precision
    if constexpr (Config::kAniso) {
      info.params.push_back({"alpha_x", lo, hi, 0.3, false, "roughness along x (alpha = r^2)", S::kLog});
      info.params.push_back({"alpha_y", lo, hi, 0.1, false, "roughness along y", S::kLog});
    } else {
      info.params.push_back({"alpha", lo, hi, 0.3, false, "roughness (alpha = r^2)", S::kLog});
    }
    if constexpr (Config::kFresnel == FresnelForm::kSchlick) {
      info.params.push_back({"f0", 0.0, 1.0, 1.0, true, "reflectance at normal incidence (1: F = 1)"});
    } else if constexpr (Config::kFresnel == FresnelForm::kDielectric) {
      info.params.push_back({"eta", 1.0, 4.0, 1.5, false, "relative refractive index"});
    } else {
      info.params.push_back({"eta", 0.01, 10.0, 0.2, true, "real part of the complex index"});
      info.params.push_back({"k", 0.0, 20.0, 3.0, true, "imaginary part (extinction)"});
    }
    info.reciprocal = true;
    // D G2 with F <= 1 integrates to at most 1 (weak white furnace).
    info.energy_conserving = true;
    return info;
  }

  template <typename T>
  void Roughness(const T* p, T& ax, T& ay) const {
    ax = At(p, kAlphaX);
    ay = At(p, kAlphaY);
  }

  // The directions of D, Lambda, G1, G2, Fresnel and Eval may be of a scalar
  // type V other than T: double directions with Jet parameters (a fit's
  // Jacobian) keep the half vector and the cosines in double.
  template <typename T, typename V = T>
  T D(const T* p, const Vec3<V>& wm) const {
    if constexpr (!Config::kAniso) {
      if constexpr (Config::kDist == MicrofacetDistribution::kGgx) return DGgx(wm, At(p, kAlphaX));
      else return DBeckmann(wm, At(p, kAlphaX));
    } else {
      T ax, ay;
      Roughness(p, ax, ay);
      if constexpr (Config::kDist == MicrofacetDistribution::kGgx) return DGgx(wm, ax, ay);
      else return DBeckmann(wm, ax, ay);
    }
  }

  template <typename T, typename V = T>
  T Lambda(const T* p, const Vec3<V>& w) const {
    T a2t2;
    if constexpr (!Config::kAniso) {
      a2t2 = Alpha2Tan2(w, At(p, kAlphaX));
    } else {
      T ax, ay;
      Roughness(p, ax, ay);
      a2t2 = Alpha2Tan2(w, ax, ay);
    }
    if constexpr (Config::kDist == MicrofacetDistribution::kGgx) return LambdaGgxOf(a2t2);
    else return LambdaBeckmannOf(a2t2);
  }

  template <typename T, typename V = T>
  T G1(const T* p, const Vec3<V>& w, const Vec3<V>& wm) const {
    if (w.dot(wm) <= V(0) || w.z() <= V(0)) return T(0);  // back side of the facet
    return T(1) / (T(1) + Lambda(p, w));
  }

  template <typename T, typename V = T>
  T G2(const T* p, const Vec3<V>& wi, const Vec3<V>& wo, const Vec3<V>& wm) const {
    if (wi.dot(wm) <= V(0) || wo.dot(wm) <= V(0)) return T(0);  // facet faces away from one side
    if constexpr (Config::kSmith == SmithForm::kHeightCorrelated)
      return T(1) / (T(1) + Lambda(p, wi) + Lambda(p, wo));
    else
      return G1(p, wi, wm) * G1(p, wo, wm);
  }

  template <typename T, typename V = T>
  Rgb<T> Fresnel(const T* p, const V& cos_theta) const {
    Rgb<T> F;
    for (int c = 0; c < 3; ++c) {
      if constexpr (Config::kFresnel == FresnelForm::kSchlick) F[c] = FresnelSchlick(At(p, kF0, c), cos_theta);
      else if constexpr (Config::kFresnel == FresnelForm::kDielectric) F[c] = FresnelDielectric(At(p, kEta), cos_theta);
      else F[c] = FresnelConductor(At(p, kEta, c), At(p, kK, c), cos_theta);
    }
    return F;
  }

  template <typename T, typename V = T>
  Rgb<T> Eval(const T* p, const Vec3<V>& wi, const Vec3<V>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    if constexpr (kBatchKernel && !std::is_same_v<T, V>) return EvalOfKernel(p, wi, wo);
    const Vec3<V> wm = HalfVector(wi, wo);
    const T scalar = D(p, wm) * G2(p, wi, wo, wm) / V(V(4) * wi.z() * wo.z());
    return Fresnel(p, V(wi.dot(wm))) * scalar;
  }

  // Eval over n pairs, vectorised (brdf/batch.h), for the GGX models with
  // Schlick Fresnel in double and float. Eval's value rewritten with two
  // divisions and three square roots instead of ten and three: with
  // h = wi + wo, h2 = |h|^2, wm = h / |h| and, for w = wi, wo,
  // s_w = sqrt(wz^2 + ax^2 wx^2 + ay^2 wy^2) (so 1 + a^2 tan^2 = s_w^2 / wz^2),
  //   D = 1 / (pi ax ay e^2),  e = (hx^2 / ax^2 + hy^2 / ay^2 + hz^2) / h2,
  //   G2 / (4 cos_i cos_o) = 1 / (2 (cos_o s_i + cos_i s_o))    height-correlated,
  //                        = 1 / ((cos_i + s_i) (cos_o + s_o))  separable,
  //   cos(wi, wm) = (wi.h) / |h|,
  // every term positive (no cancellation). Pairs where Eval returns 0
  // (either direction at or below the horizon, wi.h <= 0 or wo.h <= 0) are
  // masked to 0. Agrees with Eval to a few units in the last place, except
  // where the sign of wi.h or wo.h is itself rounding noise (grazing,
  // nearly opposite pairs).
  static constexpr bool kBatchKernel =
      Config::kDist == MicrofacetDistribution::kGgx && Config::kFresnel == FresnelForm::kSchlick;

  // Eval in the kernel's form (GgxKernel) for parameters of a type other
  // than the directions' (a fit's Jacobian: Jet parameters, double
  // directions): every term of the directions alone in V, four divisions
  // (one per Jet division or square root) on T where Eval's form takes eight.
  template <typename T, typename V>
    requires kBatchKernel
  Rgb<T> EvalOfKernel(const T* p, const Vec3<V>& wi, const Vec3<V>& wo) const {
    using std::sqrt;
    const Vec3<V> h = wi + wo;
    const V h2 = h.squaredNorm(), q = V(1) / h2;  // h2 > 0: both directions above the horizon
    const V di = wi.dot(h), dout = wo.dot(h);
    if (!(di > V(0) && dout > V(0))) return Rgb<T>::Constant(T(0));  // facet faces away from one side
    T e, si, so, area;
    if constexpr (Config::kAniso) {
      T ax, ay;
      Roughness(p, ax, ay);
      const T ax2 = ax * ax, ay2 = ay * ay;
      e = V(h.x() * h.x() * q) / ax2 + V(h.y() * h.y() * q) / ay2 + V(h.z() * h.z() * q);
      si = sqrt(ax2 * V(wi.x() * wi.x()) + ay2 * V(wi.y() * wi.y()) + V(wi.z() * wi.z()));
      so = sqrt(ax2 * V(wo.x() * wo.x()) + ay2 * V(wo.y() * wo.y()) + V(wo.z() * wo.z()));
      area = ax * ay;
    } else {
      const T a2 = At(p, kAlphaX) * At(p, kAlphaX);
      e = V((h.x() * h.x() + h.y() * h.y()) * q) / a2 + V(h.z() * h.z() * q);
      si = sqrt(a2 * V(wi.x() * wi.x() + wi.y() * wi.y()) + V(wi.z() * wi.z()));
      so = sqrt(a2 * V(wo.x() * wo.x() + wo.y() * wo.y()) + V(wo.z() * wo.z()));
      area = a2;
    }
    T g;
    if constexpr (Config::kSmith == SmithForm::kSeparable) g = (V(wi.z()) + si) * (V(wo.z()) + so);
    else g = V(wo.z()) * si + V(wi.z()) * so;
    const V scale = Config::kSmith == SmithForm::kSeparable ? V(kPi) : V(2 * kPi);
    return Fresnel(p, V(di / sqrt(h2))) * (T(1) / (scale * area * e * e * g));
  }

  template <typename T>
    requires(std::is_floating_point_v<T> && kBatchKernel)
  void EvalBatch(const T* p, const T* wi, std::size_t wi_stride, const T* wo, std::size_t wo_stride, std::size_t n,
                 T* out) const {
    T ax, ay;
    Roughness(p, ax, ay);
    GgxKernel<T> k;
    k.ax2 = ax * ax;
    k.ay2 = ay * ay;
    k.inv_ax2 = T(1) / k.ax2;
    k.inv_ay2 = T(1) / k.ay2;
    k.scale = T(Config::kSmith == SmithForm::kSeparable ? kPi : 2 * kPi) * ax * ay;
    for (int c = 0; c < 3; ++c) k.f0[c] = At(p, kF0, c);
    RunBatchKernel(k, wi, wi_stride, wo, wo_stride, n, out);
  }

  template <typename T>
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const {
    if (!SameUpperHemisphere(wi, wo)) return T(0);
    const Vec3<T> wm = HalfVector(wi, wo);
    if constexpr (Config::kDist == MicrofacetDistribution::kGgx) {
      // Visible normals: D_wo(wm) = G1(wo, wm) D(wm) (wo.wm) / cos_theta_o.
      return G1(p, wo, wm) * D(p, wm) / (T(4) * wo.z());
    } else {
      return D(p, wm) * wm.z() / (T(4) * HalfCos(wi, wo));  // wo.wm by HalfCos: never <= 0 by rounding
    }
  }

  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    BsdfSample<T> s;
    if (wo.z() <= T(0)) return s;
    double ax, ay;
    {
      T tx, ty;
      Roughness(p, tx, ty);
      ax = Value(tx);
      ay = Value(ty);
    }
    Eigen::Vector3d wm;
    if constexpr (Config::kDist == MicrofacetDistribution::kGgx)
      wm = SampleGgxVisibleNormal(ax, ay, Eigen::Vector3d(Value(wo.x()), Value(wo.y()), Value(wo.z())), u1, u2);
    else
      wm = SampleBeckmannNormal(ax, ay, u1, u2);
    Eigen::Vector3d wi;
    if (!ReflectAbout(wo, wm, wi)) return s;  // facet seen from behind
    return SampledFrom(*this, p, wo, wi);
  }

  double SampleWeight(const double* p) const {
    if constexpr (Config::kFresnel == FresnelForm::kSchlick) {
      return MeanRgb(p, kF0) + (1.0 - MeanRgb(p, kF0)) / 21.0;  // hemispherical average of Schlick
    } else if constexpr (Config::kFresnel == FresnelForm::kDielectric) {
      return FresnelDielectric(At(p, kEta), 0.5);
    } else {
      double s = 0;
      for (int c = 0; c < 3; ++c) s += FresnelConductor(At(p, kEta, c), At(p, kK, c), 0.5);
      return s / 3.0;
    }
  }

 private:
  template <typename T>
  struct GgxKernel {
    T ax2, ay2, inv_ax2, inv_ay2;
    T scale;  // pi ax ay (separable) or 2 pi ax ay (height-correlated)
    T f0[3];
    [[gnu::always_inline]] void operator()(const T* wi, const T* wo, T* out) const {
      using std::sqrt;
      const T ix = wi[0], iy = wi[1], iz = wi[2];
      const T ox = wo[0], oy = wo[1], oz = wo[2];
      const T hx = ix + ox, hy = iy + oy, hz = iz + oz;
      const T h2 = hx * hx + hy * hy + hz * hz;
      const T q = T(1) / h2;
      const T di = ix * hx + iy * hy + iz * hz;
      const T dout = ox * hx + oy * hy + oz * hz;
      const T e = (hx * hx * inv_ax2 + hy * hy * inv_ay2 + hz * hz) * q;
      const T si = sqrt(iz * iz + ax2 * ix * ix + ay2 * iy * iy);
      const T so = sqrt(oz * oz + ax2 * ox * ox + ay2 * oy * oy);
      T g;
      if constexpr (Config::kSmith == SmithForm::kSeparable) g = (iz + si) * (oz + so);
      else g = oz * si + iz * so;
      const T value = T(1) / (scale * e * e * g);
      const bool nonzero = (iz > T(0)) & (oz > T(0)) & (di > T(0)) & (dout > T(0));
      const T f = Select(nonzero, value, T(0));
      // Schlick with the cosine clamped to [0, 1], as FresnelSchlick.
      const T cos0 = di * q * sqrt(h2);
      const T cos1 = Select(cos0 > T(0), cos0, T(0));
      const T c = Select(cos1 > T(1), T(1), cos1);
      const T m = T(1) - c;
      const T m2 = m * m;
      const T m5 = m2 * m2 * m;
      for (int ch = 0; ch < 3; ++ch) out[ch] = (f0[ch] + (T(1) - f0[ch]) * m5) * f;
    }
  };
};

// --- presets ---------------------------------------------------------------

using MfIso = MicrofacetConfig<MicrofacetDistribution::kGgx, false, SmithForm::kHeightCorrelated,
                               FresnelForm::kSchlick>;

struct Ggx : MicrofacetModel<Ggx, MfIso> {
  using MicrofacetModel::MicrofacetModel;
  static constexpr const char* kName = "ggx";
  static constexpr const char* kSummary =
      "GGX / Trowbridge-Reitz, height-correlated Smith, Schlick Fresnel (Walter 2007, Heitz 2014)";
};

struct Beckmann
    : MicrofacetModel<Beckmann, MicrofacetConfig<MicrofacetDistribution::kBeckmann, false,
                                                 SmithForm::kHeightCorrelated, FresnelForm::kSchlick>> {
  using MicrofacetModel::MicrofacetModel;
  static constexpr const char* kName = "beckmann";
  static constexpr const char* kSummary =
      "Beckmann, height-correlated Smith, Schlick Fresnel (Walter 2007, Heitz 2014)";
};

struct GgxAniso
    : MicrofacetModel<GgxAniso, MicrofacetConfig<MicrofacetDistribution::kGgx, true,
                                                 SmithForm::kHeightCorrelated, FresnelForm::kSchlick>> {
  using MicrofacetModel::MicrofacetModel;
  static constexpr const char* kName = "ggx_aniso";
  static constexpr const char* kSummary = "anisotropic GGX, height-correlated Smith, Schlick Fresnel (Heitz 2014)";
};

struct BeckmannAniso
    : MicrofacetModel<BeckmannAniso, MicrofacetConfig<MicrofacetDistribution::kBeckmann, true,
                                                      SmithForm::kHeightCorrelated, FresnelForm::kSchlick>> {
  using MicrofacetModel::MicrofacetModel;
  static constexpr const char* kName = "beckmann_aniso";
  static constexpr const char* kSummary =
      "anisotropic Beckmann, height-correlated Smith, Schlick Fresnel (Heitz 2014)";
};

struct GgxSeparable
    : MicrofacetModel<GgxSeparable, MicrofacetConfig<MicrofacetDistribution::kGgx, false, SmithForm::kSeparable,
                                                     FresnelForm::kSchlick>> {
  using MicrofacetModel::MicrofacetModel;
  static constexpr const char* kName = "ggx_separable";
  static constexpr const char* kSummary = "GGX with separable Smith G2 = G1 G1, Schlick Fresnel (Walter 2007)";
};

struct GgxDielectric
    : MicrofacetModel<GgxDielectric, MicrofacetConfig<MicrofacetDistribution::kGgx, false,
                                                      SmithForm::kHeightCorrelated, FresnelForm::kDielectric>> {
  using MicrofacetModel::MicrofacetModel;
  static constexpr const char* kName = "ggx_dielectric";
  static constexpr const char* kSummary = "GGX reflection off a dielectric, exact Fresnel (Walter 2007)";
};

struct GgxConductor
    : MicrofacetModel<GgxConductor, MicrofacetConfig<MicrofacetDistribution::kGgx, false,
                                                     SmithForm::kHeightCorrelated, FresnelForm::kConductor>> {
  using MicrofacetModel::MicrofacetModel;
  static constexpr const char* kName = "ggx_conductor";
  static constexpr const char* kSummary = "GGX conductor, complex-index Fresnel (Walter 2007)";
};

}  // namespace brdfkit
