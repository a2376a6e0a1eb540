// Poulin & Fournier 1990, "A model for anisotropic reflection", SIGGRAPH 90
// (Computer Graphics 24(4)): the surface is a plane covered with parallel
// cylinders (threads, brushed grooves) of radius 1, cut by the plane; each
// point reflects with a Phong model, and the macroscopic BRDF is the average
// over one period of the cross-section of what is lit and seen, with the
// self-shadowing and masking of the neighbouring cylinders computed
// analytically.
//
// Geometry (cross-section perpendicular to the cylinder axis, radius 1): the
// cylinder top is at height h above the plane, so its visible arc spans the
// normal angles theta in [-theta_m, theta_m], theta_m = acos(1 - h), and it
// covers a width 2 w, w = sin(theta_m), of the plane; neighbouring
// cylinders leave a strip d of plane between them; period P = 2 w + d.
// The cylinder axis lies in the tangent plane at `angle` from x.
//
// A direction w has the components x (across the cylinders), y (along the
// axis) and z; in the cross-section it is seen under alpha = atan2(x, z)
// from the vertical, with projected length r = sqrt(x^2 + z^2). The arc
// normal n(theta) = (sin theta, 0, cos theta) gives w.n = r cos(theta - alpha).
//
// Shadowing (Poulin & Fournier's construction, written out for the cut
// cylinder): for
// alpha >= 0 (light from the +x side) the point at theta of the arc is
// shadowed by the next cylinder iff the ray passes within 1 of its centre and
// that centre lies ahead: with u = theta - alpha,
//   sin u > P cos alpha - 1   and   cos u < P sin alpha.
// A plane point x in [w, P - w] is shadowed iff the ray passes below the
// neighbour's support line: if sin alpha > 1 - h, the shadow edge is
//   x_s = P - cos alpha - (sin alpha - (1 - h)) tan alpha,
// and [max(x_s, w), P - w] is in shadow (no plane shadow otherwise). Only the
// nearest cylinder can shadow (the next one is P further along the ray).
// alpha < 0 is the mirror image. Masking is the same construction with wo.
// No interreflection between cylinders (as in the paper).
//
// The BRDF (radiance of the period over irradiance, per unit projected area):
//   f_r = [ int_{lit and seen arc} f_loc(n(theta)) (wi.n)(wo.n) d theta
//           + L_plane f_loc(z) cos_i cos_o ] / (P cos_i cos_o)
//   f_loc(n) = kd / pi + ks (e + 2) / (2 pi) max(0, R_n(wi).wo)^e,
// R_n the mirror about n (the normalised Phong of Lafortune & Willems 1994 in
// place of the paper's un-normalised Phong intensity, so that ks is an albedo
// and the model is reciprocal). On the arc R_n(wi).wo = A cos(2 (theta - theta*))
// - y_i y_o with A = r_i r_o and theta* = (alpha_i + alpha_o) / 2. The
// diffuse part, A cos(theta - alpha_i) cos(theta - alpha_o), has a closed form
// (theta cos(alpha_i - alpha_o) / 2 + sin(2 theta - alpha_i - alpha_o) / 4), but
// its difference of primitives cancels on the narrow lit arcs of grazing
// pairs, so it is integrated by one 24-point Gauss-Legendre panel per
// interval (exact to rounding for this degree-2 trigonometric polynomial),
// with (wi.n)(wo.n) formed from the components so it never goes negative.
// When both directions near the horizon on one side, the lit-and-seen arc
// shrinks like sqrt(P cos) and f_r grows like cos^-1/2 towards the
// horizon (no interreflection or finite light-source size bounds it). The
// specular part (no closed form for real e, the paper integrates it
// numerically) is integrated by 24-point Gauss-Legendre panels placed on the lobe: breaks at
// theta* +- 6 s and +- 12 s, s = sqrt((A - y_i y_o) / (4 e A)) the lobe's
// Gaussian width, and at the edges of its support and of the lit-and-seen
// intervals. Measured against a 4000-panel reference (physical_models_test.cpp)
// the relative error is below 1e-10 for e from 1 to 1e4.
//
// Parameters, ranges and defaults: Info() below (`brdfkit models`).
//
// Reciprocal: the lit-and-seen set is symmetric in wi, wo and so is the
// integrand. Not energy-conserving by construction (the normalised Phong
// lobe's albedo exceeds ks off normal incidence on tilted facets, and kd + ks
// is not bounded by 1): brdfkit check reports what it finds.
//
// Sampling: a mixture of cosine sampling (weight mean kd + 0.05) and, with
// weight mean ks, cos^s lobes about the mirror of wo in K = 9 normals spread
// evenly over [-theta_m, theta_m], s = min(e, 1 / Delta^2) with Delta their
// spacing, so neighbouring lobes overlap and cover the reflected band.
#pragma once

#include "brdf/core.h"
#include "brdf/torrance_sparrow.h"

#include <algorithm>
#include <array>
#include <cmath>

namespace brdfkit {

namespace detail {

inline const GaussLegendre01<24>& PfRule() {
  static const GaussLegendre01<24> rule;
  return rule;
}

// A union of at most 6 disjoint intervals.
template <typename T>
struct PfSet {
  std::array<T, 6> lo{}, hi{};
  int n = 0;
  void Add(const T& a, const T& b) {
    if (a < b && n < 6) {
      lo[n] = a;
      hi[n] = b;
      ++n;
    }
  }
};

// set minus (a, b).
template <typename T>
inline PfSet<T> PfSubtract(const PfSet<T>& s, const T& a, const T& b) {
  if (!(a < b)) return s;  // empty cut
  PfSet<T> out;
  for (int k = 0; k < s.n; ++k) {
    out.Add(s.lo[k], a < s.hi[k] ? a : s.hi[k]);
    out.Add(b > s.lo[k] ? b : s.lo[k], s.hi[k]);
  }
  return out;
}

template <typename T>
inline PfSet<T> PfIntersect(const PfSet<T>& s, const PfSet<T>& t) {
  PfSet<T> out;
  for (int i = 0; i < s.n; ++i)
    for (int j = 0; j < t.n; ++j) out.Add(s.lo[i] > t.lo[j] ? s.lo[i] : t.lo[j], s.hi[i] < t.hi[j] ? s.hi[i] : t.hi[j]);
  return out;
}

// Lit (or seen) part of the arc, in theta, for a direction at alpha >= 0
// with cos_a = cos(alpha), sin_a = sin(alpha) from the direction's components.
template <typename T>
inline PfSet<T> PfArcLit(const T& alpha, const T& cos_a, const T& sin_a, const T& period, const T& theta_m) {
  using std::acos;
  using std::asin;
  using std::sqrt;
  const T half_pi = T(kPi / 2);
  PfSet<T> lit;
  // Facing the direction (|u| < pi/2) and on the arc, in u = theta - alpha.
  const T u0 = -theta_m - alpha > -half_pi ? T(-theta_m - alpha) : T(-half_pi);
  const T u1 = theta_m - alpha < half_pi ? T(theta_m - alpha) : half_pi;
  lit.Add(u0, u1);
  const T s_a = period * cos_a - T(1);
  // s_a >= 1: the ray clears the neighbour everywhere (and asin has an
  // infinite derivative at 1).
  if (s_a < T(1)) {
    // asin(s_a) as 2 asin(sqrt((1 + s_a) / 2)) - pi/2: near grazing s_a -> -1
    // and asin(s_a) would lose the lit width sqrt(2 P cos_a) to rounding.
    const T u_a = T(2) * asin(sqrt(period * cos_a / T(2))) - half_pi;
    const T c_b = period * sin_a;
    if (c_b >= T(1)) {
      lit = PfSubtract(lit, u_a, half_pi);
    } else {
      const T u_b = acos(c_b);
      lit = PfSubtract(lit, u_a > u_b ? u_a : u_b, half_pi);
      lit = PfSubtract(lit, u_a, T(-u_b));
    }
  }
  for (int k = 0; k < lit.n; ++k) {
    lit.lo[k] += alpha;
    lit.hi[k] += alpha;
  }
  return lit;
}

// Lit part of the plane strip [w, P - w] for a direction at alpha >= 0.
template <typename T>
inline PfSet<T> PfPlaneLit(const T& alpha, const T& period, const T& w, const T& h) {
  using std::cos;
  using std::sin;
  using std::tan;
  PfSet<T> lit;
  lit.Add(w, T(period - w));
  const T rise = sin(alpha) - (T(1) - h);
  if (rise > T(0)) {
    const T x_s = period - cos(alpha) - rise * tan(alpha);
    lit = PfSubtract(lit, x_s, T(period - w));
  }
  return lit;
}

template <typename T>
inline PfSet<T> PfMirrorArc(const PfSet<T>& s) {
  PfSet<T> out;
  for (int k = s.n - 1; k >= 0; --k) out.Add(T(-s.hi[k]), T(-s.lo[k]));
  return out;
}

template <typename T>
inline PfSet<T> PfMirrorPlane(const PfSet<T>& s, const T& period) {
  PfSet<T> out;
  for (int k = s.n - 1; k >= 0; --k) out.Add(T(period - s.hi[k]), T(period - s.lo[k]));
  return out;
}

}  // namespace detail

class PoulinFournier {
 public:
  explicit PoulinFournier(const Settings& = {}) {}

  static constexpr Slot kKd{"kd", 0, true}, kKs{"ks", 3, true}, kE{"e", 6}, kD{"d", 7}, kH{"h", 8}, kAngle{"angle", 9};
  static constexpr std::array kSlots{kKd, kKs, kE, kD, kH, kAngle};
  static constexpr unsigned kKind = LobeKind::kDiffuse | LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;
  static constexpr bool kVanishes = true;  // zero with its colour parameters at 0
  // Along the cylinders the lobe is the Phong lobe of exponent e; across
  // them the normals of the arc (up to theta_m from z) spread it further, up
  // to the whole hemisphere (width 1). x and y get the rotated marginals.
  // The narrowest lobe along both axes is the local Phong lobe: reflected by
  // the plane strip and the cylinder tops (normals near z) it keeps its width
  // across the cylinders too; the cylinders' sides add a broad part there.
  LobeWidth Width(const double* p) const {
    const double w = PhongExponentWidth(At(p, kE));
    return {w, w};
  }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "poulin_fournier";
    info.summary = "Poulin-Fournier 1990 parallel cylinders with self-shadowing and masking, Phong surface";
    using S = ParamInfo::Scale;
    info.params.push_back({"kd", 0.0, 1.0, 0.1, true, "diffuse reflectance of the material"});
    info.params.push_back({"ks", 0.0, 1.0, 0.5, true, "Phong specular albedo of the material at normal view"});
    info.params.push_back({"e", 1.0, 1e4, 50.0, false, "Phong exponent", S::kLog});
    info.params.push_back({"d", 0.0, 10.0, 0.5, false, "plane strip between cylinders (cylinder radii)"});
    info.params.push_back({"h", 0.01, 1.0, 1.0, false, "height of the cylinder top above the plane (radii)"});
    info.params.push_back({"angle", 0.0, kPi, 0.0, false, "direction of the cylinder axis from x (radians)"});
    info.reciprocal = true;
    info.energy_conserving = false;  // kd + ks unbounded; Phong albedo on tilted facets
    return info;
  }

  // Components of w across the cylinders (x), along them (y) and z.
  template <typename T>
  static Vec3<T> ToCylinderFrame(const T* p, const Vec3<T>& w) {
    using std::cos;
    using std::sin;
    const T c = cos(At(p, kAngle)), s = sin(At(p, kAngle));
    return Vec3<T>(-s * w.x() + c * w.y(), c * w.x() + s * w.y(), w.z());
  }

  // Lit part of the arc (theta) and of the plane strip (x) for direction w.
  template <typename T>
  static void LitSets(const T* p, const Vec3<T>& w, detail::PfSet<T>& arc, detail::PfSet<T>& plane) {
    using std::atan2;
    using std::sqrt;
    const T& h = At(p, kH);
    const T theta_m = atan2(sqrt(h * (T(2) - h)), T(1) - h);
    const T half_w = sqrt(h * (T(2) - h));  // sin(theta_m)
    const T period = T(2) * half_w + At(p, kD);
    const T alpha = atan2(w.x(), w.z());
    // cos and sin of alpha from the components: cos(alpha) near pi/2 would
    // carry the rounding of alpha (1e-16) into a cosine of order w.z.
    const T r = sqrt(w.x() * w.x() + w.z() * w.z());
    const T cos_a = w.z() / r, sin_a = (w.x() >= T(0) ? w.x() : T(-w.x())) / r;
    if (alpha >= T(0)) {
      arc = detail::PfArcLit(alpha, cos_a, sin_a, period, theta_m);
      plane = detail::PfPlaneLit(alpha, period, half_w, h);
    } else {
      arc = detail::PfMirrorArc(detail::PfArcLit(T(-alpha), cos_a, sin_a, period, theta_m));
      plane = detail::PfMirrorPlane(detail::PfPlaneLit(T(-alpha), period, half_w, h), period);
    }
  }

  template <typename T>
  Rgb<T> Eval(const T* p, const Vec3<T>& wi_world, const Vec3<T>& wo_world) const {
    using std::atan2;
    using std::cos;
    using std::sin;
    using std::sqrt;
    Rgb<T> f = Rgb<T>::Constant(T(0));
    if (!SameUpperHemisphere(wi_world, wo_world)) return f;
    const Vec3<T> wi = ToCylinderFrame(p, wi_world), wo = ToCylinderFrame(p, wo_world);
    const T& e = At(p, kE);
    const T& h = At(p, kH);
    const T period = T(2) * sqrt(h * (T(2) - h)) + At(p, kD);
    detail::PfSet<T> arc_i, plane_i, arc_o, plane_o;
    LitSets(p, wi, arc_i, plane_i);
    LitSets(p, wo, arc_o, plane_o);
    const detail::PfSet<T> arc = detail::PfIntersect(arc_i, arc_o);
    const detail::PfSet<T> plane = detail::PfIntersect(plane_i, plane_o);

    const T ai = atan2(wi.x(), wi.z()), ao = atan2(wo.x(), wo.z());
    const T ri = sqrt(wi.x() * wi.x() + wi.z() * wi.z()), ro = sqrt(wo.x() * wo.x() + wo.z() * wo.z());
    const T cos_io = wi.z() * wo.z();
    const T norm = (e + T(2)) * T(0.5 * kInvPi);

    // (wi.n)(wo.n) at theta from the components. On the lit-and-seen arc both
    // are >= 0; the clamp removes rounding residue at the interval ends.
    auto cosines = [&](const T& theta) {
      const T st = sin(theta), ct = cos(theta);
      const T ci = wi.x() * st + wi.z() * ct, co = wo.x() * st + wo.z() * ct;
      return (ci > T(0) ? ci : T(0)) * (co > T(0) ? co : T(0));
    };
    const auto& rule = detail::PfRule();

    // Diffuse on the arc: (wi.n)(wo.n) is a trigonometric polynomial of
    // degree 2, which one 24-point Gauss-Legendre panel integrates to
    // rounding over any interval up to pi ((2 pi)^48 / 48! < 1e-22). The closed
    // form (difference of primitives of size 1) cancels catastrophically on
    // the narrow lit arcs of grazing pairs, where the result is divided by
    // the tiny P cos_i cos_o.
    T diffuse_arc = T(0);
    for (int k = 0; k < arc.n; ++k) {
      const T len = arc.hi[k] - arc.lo[k];
      T sum = T(0);
      for (int j = 0; j < 24; ++j) sum += T(rule.w[j]) * cosines(T(arc.lo[k] + len * T(rule.x[j])));
      diffuse_arc += sum * len;
    }

    // Specular on the arc: R.wo = A cos(2 (theta - theta*)) - y_i y_o.
    T spec_arc = T(0);
    const T amp = ri * ro;
    const T yy = wi.y() * wo.y();
    const double peak = Value(amp) - Value(yy);
    if (peak > 0 && arc.n > 0) {
      const double theta_star = 0.5 * (Value(ai) + Value(ao));
      const double ratio = Value(yy) / Value(amp);
      // Support of the lobe: cos(2t) > ratio.
      const double t0 = ratio <= -1 ? kPi : 0.5 * std::acos(std::min(1.0, ratio));
      const double s = std::sqrt(peak / (4.0 * Value(e) * Value(amp)));
      std::array<double, 7> breaks = {-t0, -12 * s, -6 * s, 0.0, 6 * s, 12 * s, t0};
      for (double& b : breaks) b = theta_star + std::clamp(b, -t0, t0);
      std::sort(breaks.begin(), breaks.end());
      for (int k = 0; k < arc.n; ++k) {
        for (int b = 0; b + 1 < 7; ++b) {
          const T lo = arc.lo[k] > T(breaks[b]) ? arc.lo[k] : T(breaks[b]);
          const T hi = arc.hi[k] < T(breaks[b + 1]) ? arc.hi[k] : T(breaks[b + 1]);
          if (!(lo < hi)) continue;
          const T len = hi - lo;
          T sum = T(0);
          for (int j = 0; j < 24; ++j) {
            const T theta = lo + len * T(rule.x[j]);
            const T base = amp * cos(T(2) * theta - ai - ao) - yy;
            sum += T(rule.w[j]) * PowLobe(base, e) * cosines(theta);
          }
          spec_arc += sum * len;
        }
      }
    }

    // The plane strip between the cylinders.
    T plane_len = T(0);
    for (int k = 0; k < plane.n; ++k) plane_len += plane.hi[k] - plane.lo[k];
    const T plane_lobe = PowLobe(T(Reflect(wi).dot(wo)), e);

    for (int c = 0; c < 3; ++c) {
      const T kd = At(p, kKd, c) * T(kInvPi), ks = At(p, kKs, c) * norm;
      f[c] = (kd * diffuse_arc + ks * spec_arc) / (period * cos_io) + (kd + ks * plane_lobe) * plane_len / period;
    }
    return f;
  }

  template <typename T>
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const {
    if (!SameUpperHemisphere(wi, wo)) return T(0);
    const Mixture mix = MixtureOf(p);
    T lobes = T(0);
    for (int k = 0; k < kLobes; ++k) {
      const Vec3<T> axis = MirrorAbout(p, mix, k, wo);
      lobes += CosinePowerLobePdf(axis, T(mix.s), wi);
    }
    return T(mix.p_diffuse) * wi.z() * T(kInvPi) + T(mix.p_spec / kLobes) * lobes;
  }

  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    BsdfSample<T> s;
    if (wo.z() <= T(0)) return s;
    const Mixture mix = MixtureOf(p);
    Vec3<T> wi;
    if (u1 < mix.p_diffuse) {
      // Reuse u1 within the chosen interval; the clamp keeps it below 1.
      wi = SampleCosineHemisphere<T>(std::min(u1 / mix.p_diffuse, 1.0 - 1e-16), u2);
    } else {
      const double v = std::min((u1 - mix.p_diffuse) / mix.p_spec, 1.0 - 1e-16) * kLobes;
      const int k = std::min(kLobes - 1, static_cast<int>(v));
      const Vec3<T> axis = MirrorAbout(p, mix, k, wo);
      wi = SampleCosinePowerLobe(axis, T(mix.s), std::min(v - k, 1.0 - 1e-16), u2);
    }
    if (wi.z() <= T(0)) return s;  // lobe sample below the horizon
    s.wi = wi;
    s.pdf = Pdf(p, wo, s.wi);
    s.valid = s.pdf > T(0);
    return s;
  }

  double SampleWeight(const double* p) const { return MeanRgb(p, kKd) + MeanRgb(p, kKs); }

 private:
  static constexpr int kLobes = 9;

  struct Mixture {
    double p_diffuse, p_spec, s, theta_m, cos_a, sin_a;
  };

  template <typename T>
  static Mixture MixtureOf(const T* p) {
    Mixture m;
    double kd = 0, ks = 0;
    for (int c = 0; c < 3; ++c) {
      kd += Value(At(p, kKd, c)) / 3;
      ks += Value(At(p, kKs, c)) / 3;
    }
    const double wd = kd + 0.05;
    m.p_diffuse = wd / (wd + ks);
    m.p_spec = 1 - m.p_diffuse;
    const double h = Value(At(p, kH));
    m.theta_m = std::atan2(std::sqrt(h * (2 - h)), 1 - h);
    const double spacing = 2 * m.theta_m / (kLobes - 1);
    m.s = std::min(Value(At(p, kE)), 1.0 / (spacing * spacing));
    m.cos_a = std::cos(Value(At(p, kAngle)));
    m.sin_a = std::sin(Value(At(p, kAngle)));
    return m;
  }

  // Mirror of wo about the k-th sampling normal (world frame).
  template <typename T>
  static Vec3<T> MirrorAbout(const T*, const Mixture& mix, int k, const Vec3<T>& wo) {
    const double theta = -mix.theta_m + 2 * mix.theta_m * k / (kLobes - 1);
    // Across-cylinder axis in the world frame is (-sin a, cos a, 0).
    const Vec3<T> n(T(-mix.sin_a * std::sin(theta)), T(mix.cos_a * std::sin(theta)), T(std::cos(theta)));
    return T(2) * wo.dot(n) * n - wo;
  }
};

}  // namespace brdfkit
