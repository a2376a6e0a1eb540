// brdfkit core: vector types, frame helpers, parameter tables and the
// run-time model interface shared by every BRDF model.
//
// Conventions (see README "Conventions"):
//  - local shading frame, z is the surface normal;
//  - wi points towards the light, wo towards the detector, both away from
//    the surface;
//  - Eval returns f_r(wi, wo) in 1/sr, per RGB channel, WITHOUT the cosine;
//  - a direction with cos(theta) <= 0 (at or below the horizon) gives f_r = 0,
//    except in a model whose kind has LobeKind::kTransmission: it scatters
//    over the whole sphere, and gives f = 0 only on the horizon.
//
// Everything is templated on the scalar T so the same code runs with double,
// float and ceres::Jet. Math is called unqualified (using std::sqrt; sqrt(x))
// so that the Jet overloads are found by argument-dependent lookup.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <algorithm>
#include <cctype>
#include <array>
#include <cmath>
#include <cstddef>
#include <limits>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

namespace brdfkit {

template <typename T>
using Vec3 = Eigen::Matrix<T, 3, 1>;
template <typename T>
using Rgb = Eigen::Array<T, 3, 1>;

inline constexpr double kPi = 3.14159265358979323846;
inline constexpr double kDeg = kPi / 180;  // radians per degree
inline constexpr double kInvPi = 0.31830988618379067154;

// The plain value of a scalar: itself for float/double, the value part of an
// automatic-differentiation number (anything with a member `a`, as ceres::Jet).
inline double Value(double x) { return x; }
inline double Value(float x) { return x; }
template <typename J>
  requires requires(const J& j) { j.a; }
inline double Value(const J& j) {
  return Value(j.a);
}

template <typename T>
inline constexpr bool kIsFloat = std::is_same_v<T, float>;

template <typename T>
inline T CosTheta(const Vec3<T>& w) { return w.z(); }
template <typename T>
inline T Cos2Theta(const Vec3<T>& w) { return w.z() * w.z(); }
// sin^2 from the tangential components, exact near the normal where
// 1 - cos^2 would cancel.
template <typename T>
inline T Sin2Theta(const Vec3<T>& w) { return w.x() * w.x() + w.y() * w.y(); }

// sqrt that returns 0 for x <= 0: negative arguments only come from
// rounding, and the derivative of sqrt at 0 is infinite (fits need it finite).
template <typename T>
inline T SafeSqrt(const T& x) {
  using std::sqrt;
  if (x <= T(0)) return T(0);
  return sqrt(x);
}

// x^n for x >= 0 through exp(n log x), with 0 where x <= 0: pow(0, n) has a
// non-finite derivative with respect to n, and every use here is a lobe that
// vanishes where its base does.
template <typename T>
inline T PowLobe(const T& x, const T& n) {
  using std::exp;
  using std::log;
  if (x <= T(0)) return T(0);
  return exp(n * log(x));
}

// Mirror direction of w about the normal.
template <typename T>
inline Vec3<T> Reflect(const Vec3<T>& w) { return Vec3<T>(-w.x(), -w.y(), w.z()); }

// Unnormalised half vector wi + wo and its normalised form. When wi = -wo
// the half vector is undefined; both directions must then be in the upper
// hemisphere, which every caller checks first, so |wi + wo| >= 2 mu > 0.
template <typename T>
inline Vec3<T> HalfVector(const Vec3<T>& wi, const Vec3<T>& wo) {
  using std::sqrt;
  Vec3<T> h = wi + wo;
  return h / sqrt(h.squaredNorm());
}

// wi.h = wo.h = |wi + wo| / 2 for unit wi, wo and h = HalfVector(wi, wo):
// > 0 above the horizon, where the dot product with h cancels and goes
// negative for nearly opposite grazing pairs (|w| = 1 holds only to rounding).
template <typename T>
inline T HalfCos(const Vec3<T>& wi, const Vec3<T>& wo) {
  using std::sqrt;
  return T(0.5) * sqrt(T((wi + wo).squaredNorm()));
}

// Both directions strictly above the horizon.
template <typename T>
inline bool SameUpperHemisphere(const Vec3<T>& wi, const Vec3<T>& wo) {
  return wi.z() > T(0) && wo.z() > T(0);
}

// Orthonormal basis with z along n (Duff et al. 2017, "Building an
// orthonormal basis, revisited", branch-free version of Frisvad's).
template <typename T>
inline void BasisFromZ(const Vec3<T>& n, Vec3<T>& b1, Vec3<T>& b2) {
  using std::copysign;
  const T sign = copysign(T(1), n.z());
  const T a = T(-1) / (sign + n.z());
  const T b = n.x() * n.y() * a;
  b1 = Vec3<T>(T(1) + sign * n.x() * n.x() * a, sign * b, -sign * n.x());
  b2 = Vec3<T>(b, sign + n.y() * n.y() * a, -n.y());
}

// Cosine-weighted hemisphere sample (Malley's method, concentric disc).
template <typename T>
inline Vec3<T> SampleCosineHemisphere(double u1, double u2) {
  using std::cos;
  using std::sin;
  using std::sqrt;
  const double ox = 2.0 * u1 - 1.0, oy = 2.0 * u2 - 1.0;
  double r = 0, phi = 0;
  if (ox != 0.0 || oy != 0.0) {
    if (std::abs(ox) > std::abs(oy)) {
      r = ox;
      phi = kPi / 4 * (oy / ox);
    } else {
      r = oy;
      phi = kPi / 2 - kPi / 4 * (ox / oy);
    }
  }
  const double x = r * std::cos(phi), y = r * std::sin(phi);
  const double z = std::sqrt(std::max(0.0, 1.0 - x * x - y * y));
  return Vec3<T>(T(x), T(y), T(z));
}

// Sample of a cos^n lobe around the unit axis `axis`: density
// (n + 1) / (2 pi) cos^n(angle to axis) over the sphere of directions.
template <typename T>
inline Vec3<T> SampleCosinePowerLobe(const Vec3<T>& axis, const T& n, double u1, double u2) {
  using std::cos;
  using std::pow;
  using std::sin;
  using std::sqrt;
  const double nv = Value(n);
  // u1 -> cos^(n+1) is uniform; 1 - u1 keeps u1 = 0 away from cos = 0.
  const double c = std::pow(1.0 - u1, 1.0 / (nv + 1.0));
  const double s = std::sqrt(std::max(0.0, 1.0 - c * c));
  const double phi = 2.0 * kPi * u2;
  Vec3<T> b1, b2;
  BasisFromZ(axis, b1, b2);
  return b1 * T(s * std::cos(phi)) + b2 * T(s * std::sin(phi)) + axis * T(c);
}

template <typename T>
inline T CosinePowerLobePdf(const Vec3<T>& axis, const T& n, const Vec3<T>& w) {
  return (n + T(1)) * T(0.5 * kInvPi) * PowLobe(T(axis.dot(w)), n);
}

// ---------------------------------------------------------------------------
// Parameter tables.

struct ParamInfo {
  std::string name;
  double lower = 0;
  double upper = 1;
  double default_value = 0;
  bool colour = false;      // one value per RGB channel
  std::string meaning;
  // Scale on which a fit moves the parameter: roughness and exponents span
  // orders of magnitude and converge only in log space.
  enum class Scale { kLinear, kLog } scale = Scale::kLinear;
};

// Static description of a model (one lobe or a sum of lobes).
struct ModelInfo {
  std::string name;
  std::string summary;                 // one line: paper and what it is
  std::vector<ParamInfo> params;
  bool reciprocal = true;              // f(wi, wo) == f(wo, wi) by construction
  bool energy_conserving = false;      // albedo <= 1 for all wo, by construction, within bounds
  std::vector<std::string> settings;   // non-numeric construction options (e.g. "path")

  // Packed layout: colour parameters take 3 consecutive slots (r, g, b).
  std::size_t PackedSize() const {
    std::size_t n = 0;
    for (const auto& p : params) n += p.colour ? 3 : 1;
    return n;
  }
  std::size_t Offset(std::size_t param_index) const {
    std::size_t n = 0;
    for (std::size_t i = 0; i < param_index; ++i) n += params[i].colour ? 3 : 1;
    return n;
  }
  std::vector<double> Defaults() const {
    std::vector<double> v;
    for (const auto& p : params)
      for (int c = 0; c < (p.colour ? 3 : 1); ++c) v.push_back(p.default_value);
    return v;
  }
};

// What a model's lobes are: a set of LobeKind flags, declared by the model
// (static constexpr unsigned kKind) and read through Bxdf::Kind().
struct LobeKind {
  enum : unsigned {
    kDiffuse = 1u << 0,       // spread over the whole hemisphere
    kGlossy = 1u << 1,        // a peak of finite angular width (the model declares Width)
    kSpecular = 1u << 2,      // a delta peak (mirror or refraction): no finite density
    kTransmission = 1u << 3,  // scatters below the surface (a BTDF part)
  };
};

// Angular width, in radians on the scale of a microfacet roughness alpha
// (Walter 2007: a Beckmann lobe of rms slope alpha), of a model's narrowest
// glossy lobe along the tangent x and y axes; zero when it has none. Declared
// by the model as a function of its parameters (LobeWidth Width(const double* p) const).
struct LobeWidth {
  double x = 0, y = 0;
  bool Any() const { return x > 0 && y > 0; }
  double Min() const { return x < y ? x : y; }
};

// The glossy width of measured data f(wi, wo) -> Rgb: the half-vector angle
// (radians) where the mean of f_r cos_i at normal view falls to half its
// value at the mirror direction, by bisection along x; 1 (a broad lobe)
// when it does not fall that far within 80 degrees.
template <typename F>
double MeasuredLobeWidth(const F& f) {
  const Eigen::Vector3d wo(0, 0, 1);
  const auto g = [&](double t) {
    const Eigen::Vector3d wi(std::sin(2 * t), 0, std::cos(2 * t));
    return f(wi, wo).mean() * wi.z();
  };
  const double g0 = g(0);
  if (!(g0 > 0) || g(0.7) >= 0.5 * g0) return 1.0;
  double lo = 0, hi = 0.7;
  for (int i = 0; i < 50; ++i) {
    const double mid = 0.5 * (lo + hi);
    (g(mid) >= 0.5 * g0 ? lo : hi) = mid;
  }
  return std::max(hi, 1e-4);  // below any measured table's angular resolution
}

// A Phong-type exponent n as a width: cos^n(theta) ~ exp(-n theta^2 / 2), the
// Beckmann lobe with alpha^2 = 2 / (n + 2) (Walter 2007, sec. 5.2).
inline double PhongExponentWidth(double n) { return std::sqrt(2.0 / (n + 2.0)); }

// A named slot of the packed parameter vector: the first (or only) value of
// the parameter `name`; a colour parameter holds r, g, b at offset, +1, +2.
// Models read their parameters through these (At(p, kSlot), At(p, kSlot, c)),
// and list them in kSlots, which a registry-wide test holds against Info().
struct Slot {
  const char* name;
  std::size_t offset;
  bool colour = false;
};

template <typename T>
inline const T& At(const T* p, const Slot& s) { return p[s.offset]; }
template <typename T>
inline const T& At(const T* p, const Slot& s, int channel) { return p[s.offset + static_cast<std::size_t>(channel)]; }
// A colour parameter as an RGB triple.
template <typename T>
inline Rgb<T> RgbAt(const T* p, const Slot& s) { return Rgb<T>(p[s.offset], p[s.offset + 1], p[s.offset + 2]); }

// Options given when a model is built (file paths and the like).
using Settings = std::map<std::string, std::string>;

class ModelError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A sampled direction wi with its solid-angle density. valid is false when
// the sample falls below the horizon (a lobe that reaches past it); such a
// sample carries no weight and the model's pdf integrates over the upper
// hemisphere to the sampled fraction. A transmitting model samples the
// whole sphere, and its pdf integrates over the sphere to that fraction.
template <typename T>
struct BsdfSample {
  Vec3<T> wi = Vec3<T>(T(0), T(0), T(1));
  T pdf = T(0);
  bool valid = false;
};

// Optional microfacet view: the distribution D(wm) and, for Smith models,
// the masking function G1(w, wm). Used by the checks (normalisation of D and
// the weak white furnace test).
template <typename T>
class MicrofacetView {
 public:
  virtual ~MicrofacetView() = default;
  virtual T D(const T* p, const Vec3<T>& wm) const = 0;
  virtual bool HasSmithG1() const = 0;
  virtual T G1(const T* p, const Vec3<T>& w, const Vec3<T>& wm) const = 0;
};

// Run-time interface for one scalar type. Parameters are the packed vector of
// ModelInfo (colour parameters as r, g, b).
template <typename T>
class Bxdf {
 public:
  virtual ~Bxdf() = default;
  virtual const ModelInfo& Info() const = 0;
  // f_r(wi, wo) in 1/sr per channel, without the cosine.
  virtual Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const = 0;
  // f_r at directions given in double, which carry no derivatives: a model
  // whose Eval also takes double directions with T parameters (microfacet
  // lobes) computes the directions' part once in double instead of on T
  // (a fit's Jacobian, T a Jet); any other model gets them cast to T.
  virtual Rgb<T> EvalAt(const T* p, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) const {
    return Eval(p, Vec3<T>(wi.template cast<T>()), Vec3<T>(wo.template cast<T>()));
  }
  // sum_k w[k] f_r(wi, wo[k]) over n outgoing directions in one call (the
  // aperture quadrature's inner sum; adapters override it with the model's
  // Eval inlined in the loop).
  virtual Rgb<T> EvalSum(const T* p, const Vec3<T>& wi, const Vec3<T>* wo, const double* w, std::size_t n) const {
    Rgb<T> sum = Rgb<T>::Constant(T(0));
    for (std::size_t k = 0; k < n; ++k) sum += Eval(p, wi, wo[k]) * T(w[k]);
    return sum;
  }
  // f_r of n pairs, rows wi + k * wi_stride and wo + k * wo_stride (x, y, z;
  // stride 0 repeats one direction), into out[3 k + c]: one virtual call for
  // the whole batch (adapters run the model's own vectorised kernel, or the
  // loop of brdf/batch.h with Eval inlined).
  virtual void EvalBatch(const T* p, const T* wi, std::size_t wi_stride, const T* wo, std::size_t wo_stride,
                         std::size_t n, T* out) const {
    for (std::size_t k = 0; k < n; ++k) {
      const T* a = wi + k * wi_stride;
      const T* b = wo + k * wo_stride;
      const Rgb<T> f = Eval(p, Vec3<T>(a[0], a[1], a[2]), Vec3<T>(b[0], b[1], b[2]));
      for (int c = 0; c < 3; ++c) out[3 * k + c] = f[c];
    }
  }
  // Importance sample wi given wo; pdf with respect to solid angle.
  virtual BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const = 0;
  // Density of Sample, with respect to solid angle.
  virtual T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const = 0;
  // Relative weight for choosing this lobe in a sum (about its albedo).
  virtual double SampleWeight(const double* p) const = 0;
  // Whether Sample and Pdf are the model's own (a model may leave them out:
  // then Sample returns invalid samples, Pdf 0, and the checks that need
  // them are skipped with a note).
  virtual bool CanSample() const { return true; }
  // Declared traits (see brdf/model.h); the defaults are what a model that
  // declares nothing is taken to be: of unknown kind (0), without a glossy
  // lobe, with channels that may depend on each other.
  virtual unsigned Kind() const { return 0; }
  virtual LobeWidth Width(const double* /*p*/) const { return {}; }
  // Channel c of f_r depends only on channel c of every colour parameter.
  virtual bool ChannelsIndependent() const { return false; }
  virtual const MicrofacetView<T>* Microfacet() const { return nullptr; }
  // eta_wi / eta_wo, the refractive index on wi's side over that on wo's
  // side, for a transmitting model (generalised reciprocity: f(wi, wo)
  // RelativeIndex(wi, wo)^2 = f(wo, wi)); 1 for every other model.
  virtual T RelativeIndex(const T* /*p*/, const Vec3<T>& /*wi*/, const Vec3<T>& /*wo*/) const { return T(1); }
};

// Sampling by reflection about a sampled unit normal m (a microfacet normal
// or a half vector, in double): wi = 2 (wo.m) m - wo. Returns false when m
// faces away from wo (nothing reflects off it towards wo).
template <typename T>
bool ReflectAbout(const Vec3<T>& wo, const Eigen::Vector3d& m, Eigen::Vector3d& wi) {
  const Eigen::Vector3d v(Value(wo.x()), Value(wo.y()), Value(wo.z()));
  const double d = v.dot(m);
  if (d <= 0) return false;
  wi = 2.0 * d * m - v;
  return true;
}

// A sampled direction wi as a BsdfSample with the model's own pdf: invalid
// when wi is at or below the horizon or its pdf is zero.
template <typename T, typename M>
BsdfSample<T> SampledFrom(const M& model, const T* p, const Vec3<T>& wo, const Eigen::Vector3d& wi) {
  BsdfSample<T> s;
  if (wi.z() <= 0) return s;  // reflected below the horizon
  s.wi = Vec3<T>(T(wi.x()), T(wi.y()), T(wi.z()));
  s.pdf = model.Pdf(p, wo, s.wi);
  s.valid = s.pdf > T(0);
  return s;
}

// Cosine-weighted importance sampling (pdf = cos theta_i / pi), shared by the
// models whose lobe is diffuse or tabulated.
struct CosineSampling {
  template <typename T>
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const {
    BsdfSample<T> s;
    if (wo.z() <= T(0)) return s;
    s.wi = SampleCosineHemisphere<T>(u1, u2);
    s.pdf = Pdf(p, wo, s.wi);
    s.valid = s.pdf > T(0);
    return s;
  }

  template <typename T>
  T Pdf(const T*, const Vec3<T>& wo, const Vec3<T>& wi) const {
    if (!SameUpperHemisphere(wi, wo)) return T(0);
    return wi.z() * T(kInvPi);
  }
};

// "; did you mean X?" (or "X or Y") naming the known names nearest to an
// unknown one: within an edit distance of max(2, |name| / 3) (optimal string
// alignment: insertions, deletions, substitutions, transpositions), or whose
// description holds the unknown name as a word (roughness -> alpha, whose
// meaning reads "roughness ..."). Empty when nothing is near.
struct KnownName {
  std::string name;
  std::string meaning;  // free text searched for the unknown name as a word
};
inline std::string DidYouMean(const std::string& unknown, const std::vector<KnownName>& known) {
  const auto lower = [](std::string s) {
    for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return s;
  };
  const std::string u = lower(unknown);
  const auto distance = [](const std::string& a, const std::string& b) {
    std::vector<std::vector<std::size_t>> d(a.size() + 1, std::vector<std::size_t>(b.size() + 1));
    for (std::size_t i = 0; i <= a.size(); ++i) d[i][0] = i;
    for (std::size_t j = 0; j <= b.size(); ++j) d[0][j] = j;
    for (std::size_t i = 1; i <= a.size(); ++i)
      for (std::size_t j = 1; j <= b.size(); ++j) {
        d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
        if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1]) d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
      }
    return d[a.size()][b.size()];
  };
  const std::size_t limit = std::max<std::size_t>(2, u.size() / 3);
  std::size_t best = limit + 1;
  std::vector<std::string> near;
  for (const KnownName& k : known) {
    std::size_t dist = distance(u, lower(k.name));
    // The unknown name as a whole word of the description counts as distance 1.
    const std::string m = " " + lower(k.meaning) + " ";
    for (std::size_t pos = m.find(u); dist > 1 && u.size() >= 3 && pos != std::string::npos; pos = m.find(u, pos + 1))
      if (!std::isalnum(static_cast<unsigned char>(m[pos - 1])) && !std::isalnum(static_cast<unsigned char>(m[pos + u.size()])))
        dist = 1;
    if (dist > limit || dist > best) continue;
    if (dist < best) near.clear();
    best = dist;
    if (std::find(near.begin(), near.end(), k.name) == near.end()) near.push_back(k.name);
  }
  if (near.empty() || u.empty()) return "";
  std::string out = "; did you mean ";
  for (std::size_t i = 0; i < near.size() && i < 3; ++i)
    out += (i ? (i + 1 == std::min<std::size_t>(near.size(), 3) ? " or " : ", ") : "") + near[i];
  return out + "?";
}

// Luminance-like mean of a colour parameter, for lobe selection weights.
inline double MeanRgb(const double* c) { return (c[0] + c[1] + c[2]) / 3.0; }
inline double MeanRgb(const double* p, const Slot& s) { return MeanRgb(p + s.offset); }

}  // namespace brdfkit
