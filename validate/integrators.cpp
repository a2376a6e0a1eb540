#include "validate/integrators.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "validate/quadrature.h"
#include "validate/sobol.h"

namespace brdfkit::validate {

namespace {

using Eigen::Array3d;
using Eigen::Vector3d;

struct DirSample {
  Vector3d wi = Vector3d::UnitZ();
  double pdf = 0;
  bool valid = false;
};

// One integration problem: the integrand over directions, an optional
// importance sampler, and what is known about a sharp peak.
struct Problem {
  std::function<Array3d(const Vector3d&)> g;
  std::function<DirSample(double, double)> sample;  // empty: cosine or lobe mixture
  Vector3d peak = Vector3d::Zero();                  // zero: no peak known
  double width = 0;                                  // angular width of the peak (radians)
  double lobe_solid_angle = 0;                       // solid angle holding most of the peak's mass
  // Adaptive rule: the BRDF case works in half-vector space.
  const Bxdf<double>* bxdf = nullptr;
  const double* params = nullptr;
  Vector3d wo = Vector3d::UnitZ();
  double alpha_x = 0, alpha_y = 0;
};

double Seconds(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Uniform double in [0, 1) from a SplitMix64 stream.
struct Rng {
  std::uint64_t state;
  double Next() {
    state += 0x9e3779b97f4a7c15ULL;
    std::uint64_t z = state;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    z ^= z >> 31;
    return double(z >> 11) * 0x1.0p-53;
  }
};

// Running mean and variance (Welford), mergeable (Chan et al. 1979).
struct Stats {
  std::int64_t n = 0;
  Array3d mean = Array3d::Zero();
  Array3d m2 = Array3d::Zero();
  void Add(const Array3d& x) {
    ++n;
    const Array3d d = x - mean;
    mean += d / double(n);
    m2 += d * (x - mean);
  }
  void Merge(const Stats& o) {
    if (o.n == 0) return;
    if (n == 0) {
      *this = o;
      return;
    }
    const double na = double(n), nb = double(o.n), nt = na + nb;
    const Array3d d = o.mean - mean;
    mean += d * (nb / nt);
    m2 += o.m2 + d * d * (na * nb / nt);
    n += o.n;
  }
  // Standard error of the mean.
  Array3d StdError() const {
    if (n < 2) return Array3d::Constant(std::numeric_limits<double>::infinity());
    return (m2 / double(n - 1) / double(n)).sqrt();
  }
};

Vector3d UniformHemisphere(double u1, double u2) {
  const double z = 1.0 - u1;  // 1 - u1 in (0, 1]: never exactly on the horizon
  const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
  const double phi = 2.0 * kPi * u2;
  return Vector3d(r * std::cos(phi), r * std::sin(phi), z);
}

// Frame with z along a unit axis.
struct Frame {
  Vector3d s, t, n;
  explicit Frame(const Vector3d& axis) : n(axis) { BasisFromZ<double>(axis, s, t); }
  Vector3d ToWorld(const Vector3d& v) const { return v.x() * s + v.y() * t + v.z() * n; }
  Vector3d ToLocal(const Vector3d& v) const { return Vector3d(v.dot(s), v.dot(t), v.dot(n)); }
};

// GGX-shaped lobe of width `width` around `axis` (heavy tails, so it covers
// both GGX and lighter-tailed peaks): density D_GGX(local) cos(local theta).
Vector3d SampleLobe(const Frame& f, double width, double u1, double u2) {
  const double w2 = width * width;
  const double cos_t = std::sqrt((1.0 - u1) / (1.0 - u1 + w2 * u1));
  const double sin_t = std::sqrt(std::max(0.0, 1.0 - cos_t * cos_t));
  const double phi = 2.0 * kPi * u2;
  return f.ToWorld(Vector3d(sin_t * std::cos(phi), sin_t * std::sin(phi), cos_t));
}

double LobePdf(const Frame& f, double width, const Vector3d& d) {
  const Vector3d l = f.ToLocal(d);
  if (l.z() <= 0) return 0;  // the lobe covers the hemisphere around its axis only
  const double w2 = width * width;
  const double e = (l.x() * l.x() + l.y() * l.y()) / w2 + l.z() * l.z();
  return l.z() / (kPi * w2 * e * e);
}

// Sampler used by the importance methods when the problem brings none:
// cosine-weighted, mixed half and half with a lobe at the peak when known.
std::function<DirSample(double, double)> DefaultSampler(const Problem& pb) {
  if (pb.peak.isZero() || !(pb.width > 0)) {
    return [](double u1, double u2) {
      DirSample s;
      s.wi = SampleCosineHemisphere<double>(u1, u2);
      s.pdf = s.wi.z() * kInvPi;
      s.valid = s.pdf > 0;
      return s;
    };
  }
  const Frame frame(pb.peak);
  const double width = std::min(pb.width, 1e3);
  return [frame, width](double u1, double u2) {
    DirSample s;
    if (u1 < 0.5) {
      s.wi = SampleCosineHemisphere<double>(2.0 * u1, u2);
    } else {
      // 2 u1 - 1 stays below 1 for u1 < 1.
      s.wi = SampleLobe(frame, width, 2.0 * u1 - 1.0, u2);
    }
    if (!(s.wi.z() > 0)) return s;
    s.pdf = 0.5 * s.wi.z() * kInvPi + 0.5 * LobePdf(frame, width, s.wi);
    s.valid = s.pdf > 0;
    return s;
  };
}

// Error a sampler with density `pdf_at_peak` can hide when it rarely lands in
// the peak: the peak's mass M = g(peak) * lobe solid angle is found with
// probability p per sample, and the estimator's standard deviation is then
// M sqrt((1 - p) / (N p)). Sample variance alone misses this when no or few
// samples hit the peak.
Array3d PeakFloor(const Problem& pb, double pdf_at_peak, std::int64_t n) {
  if (pb.peak.isZero() || !(pb.lobe_solid_angle > 0) || n <= 0) return Array3d::Zero();
  const Array3d mass = pb.g(pb.peak).abs() * pb.lobe_solid_angle;
  const double p = std::min(1.0, pdf_at_peak * pb.lobe_solid_angle);
  if (!(p > 0)) return mass;
  return mass * std::sqrt((1.0 - p) / (double(n) * p));
}

constexpr std::int64_t kBlock = 1024;

Estimate MonteCarlo(const Problem& pb, Method method, const IntegrateOptions& o) {
  Estimate e;
  const auto t0 = std::chrono::steady_clock::now();
  const std::int64_t n = std::max<std::int64_t>(o.budget, 2);
  std::function<DirSample(double, double)> sampler;
  double pdf_at_peak = 0;
  if (method == Method::kUniform) {
    sampler = [](double u1, double u2) { return DirSample{UniformHemisphere(u1, u2), 0.5 * kInvPi, true}; };
    pdf_at_peak = 0.5 * kInvPi;
  } else if (method == Method::kCosine) {
    sampler = [](double u1, double u2) {
      DirSample s;
      s.wi = SampleCosineHemisphere<double>(u1, u2);
      s.pdf = s.wi.z() * kInvPi;
      s.valid = s.pdf > 0;
      return s;
    };
    pdf_at_peak = std::max(0.0, pb.peak.z()) * kInvPi;
  } else {
    sampler = pb.sample ? pb.sample : DefaultSampler(pb);
  }
  const std::int64_t blocks = (n + kBlock - 1) / kBlock;
  std::vector<Stats> stats(static_cast<std::size_t>(blocks));
  tbb::parallel_for(tbb::blocked_range<std::int64_t>(0, blocks), [&](const tbb::blocked_range<std::int64_t>& r) {
    for (std::int64_t b = r.begin(); b != r.end(); ++b) {
      Rng rng{Mix64(o.seed * 0x100000001b3ULL + std::uint64_t(method)) ^ Mix64(std::uint64_t(b))};
      Stats& st = stats[static_cast<std::size_t>(b)];
      const std::int64_t end = std::min(n, (b + 1) * kBlock);
      for (std::int64_t i = b * kBlock; i < end; ++i) {
        const double u1 = rng.Next(), u2 = rng.Next();
        const DirSample s = sampler(u1, u2);
        if (!s.valid || !(s.pdf > 0)) {
          st.Add(Array3d::Zero());
          continue;
        }
        st.Add(pb.g(s.wi) / s.pdf);
      }
    }
  });
  Stats total;
  for (const Stats& s : stats) total.Merge(s);
  e.value = total.mean;
  e.evals = n;
  // Three standard errors (a 99.7% band for a normal estimator), and the
  // floor for a peak the sampler may have missed.
  e.error = (3.0 * total.StdError()).max(method == Method::kImportance ? Array3d::Zero()
                                                                       : PeakFloor(pb, pdf_at_peak, n));
  e.seconds = Seconds(t0);
  return e;
}

// Student-t 99% two-sided quantiles for 1..9 degrees of freedom.
double StudentT99(int dof) {
  static const double kT[] = {63.657, 9.925, 5.841, 4.604, 4.032, 3.707, 3.499, 3.355, 3.250};
  return dof >= 1 && dof <= 9 ? kT[dof - 1] : 2.58;
}

Estimate Sobol(const Problem& pb, const IntegrateOptions& o) {
  Estimate e;
  const auto t0 = std::chrono::steady_clock::now();
  const int replicates = o.budget >= 64 ? 8 : 2;
  std::int64_t per = 1;
  while (per * 2 * replicates <= o.budget) per *= 2;
  static const Sobol2D sobol;
  const std::function<DirSample(double, double)> sampler = pb.sample ? pb.sample : DefaultSampler(pb);
  std::vector<Array3d> means(static_cast<std::size_t>(replicates), Array3d::Zero());
  tbb::parallel_for(0, replicates, [&](int r) {
    const std::uint64_t seed = Mix64(Mix64(o.seed) + std::uint64_t(r) * 0x632be59bd9b4e019ULL);
    Array3d sum = Array3d::Zero();
    for (std::int64_t i = 0; i < per; ++i) {
      const std::array<double, 2> u = sobol.Point(static_cast<std::uint32_t>(i), seed);
      const DirSample s = sampler(u[0], u[1]);
      if (s.valid && s.pdf > 0) sum += pb.g(s.wi) / s.pdf;
    }
    means[static_cast<std::size_t>(r)] = sum / double(per);
  });
  Stats st;
  for (const Array3d& m : means) st.Add(m);
  e.value = st.mean;
  e.error = StudentT99(replicates - 1) * st.StdError();
  e.evals = per * replicates;
  e.seconds = Seconds(t0);
  return e;
}

// Product Gauss-Legendre rule in (cos theta, phi) with n x 2n nodes.
Array3d ProductRule(const Problem& pb, int n, double phi0) {
  const GaussLegendre gu(n), gp(2 * n);
  Array3d sum = Array3d::Zero();
  for (int i = 0; i < n; ++i) {
    const double u = gu.node01(i);
    const double s = std::sqrt(std::max(0.0, 1.0 - u * u));
    Array3d row = Array3d::Zero();
    for (int j = 0; j < 2 * n; ++j) {
      const double phi = phi0 + 2.0 * kPi * gp.node01(j);
      row += gp.weight01(j) * pb.g(Vector3d(s * std::cos(phi), s * std::sin(phi), u));
    }
    sum += gu.weight01(i) * row;
  }
  return sum * (2.0 * kPi);
}

Estimate GaussLegendreRule(const Problem& pb, const IntegrateOptions& o) {
  Estimate e;
  const auto t0 = std::chrono::steady_clock::now();
  // Fine rule n x 2n plus the half rule for the error: 2.5 n^2 evaluations.
  const int n = std::max(2, int(std::sqrt(double(o.budget) / 2.5)));
  const int half = std::max(1, n / 2);
  const double phi0 = pb.peak.isZero() ? 0.0 : std::atan2(pb.peak.y(), pb.peak.x()) + kPi;
  const Array3d fine = ProductRule(pb, n, phi0);
  const Array3d coarse = ProductRule(pb, half, phi0);
  e.value = fine;
  e.error = (fine - coarse).abs();
  e.evals = 2 * std::int64_t(n) * n + 2 * std::int64_t(half) * half;
  // A peak narrower than the node spacing can be missed by both rules alike.
  if (!pb.peak.isZero() && pb.width > 0) {
    const GaussLegendre gu(n);
    const double u0 = std::clamp(pb.peak.z(), 0.0, 1.0);
    double du = 1.0;
    for (int i = 0; i + 1 < n; ++i)
      if (gu.node01(i) <= u0 && u0 <= gu.node01(i + 1)) du = gu.node01(i + 1) - gu.node01(i);
    if (u0 < gu.node01(0)) du = gu.node01(0);
    if (u0 > gu.node01(n - 1)) du = 1.0 - gu.node01(n - 1);
    const double sin0 = std::sqrt(std::max(0.0, 1.0 - u0 * u0));
    const double dtheta = du / std::max(sin0, std::sqrt(du));
    const double spacing = std::max(dtheta, sin0 * kPi / n);
    if (spacing > pb.width && pb.lobe_solid_angle > 0)
      e.error = e.error.max(pb.g(pb.peak).abs() * pb.lobe_solid_angle);
  }
  e.seconds = Seconds(t0);
  return e;
}

struct AdaptiveResult {
  Array3d value = Array3d::Zero();
  Array3d error = Array3d::Zero();
  std::int64_t evals = 0;
};

AdaptiveResult AdaptiveHalfVector(const Bxdf<double>&, const double*, const Vector3d&, double, double,
                                  const IntegrateOptions&) {
  throw std::logic_error("adaptive integration is not available in this build");
}
AdaptiveResult AdaptiveDirections(const std::function<Array3d(const Vector3d&)>&, const Vector3d&, double,
                                  const IntegrateOptions&) {
  throw std::logic_error("adaptive integration is not available in this build");
}

Estimate Run(const Problem& pb, Method method, const IntegrateOptions& o) {
  if (o.budget < 1) throw std::invalid_argument("integration budget must be at least 1, got " + std::to_string(o.budget));
  switch (method) {
    case Method::kUniform:
    case Method::kCosine:
    case Method::kImportance:
      return MonteCarlo(pb, method, o);
    case Method::kSobol:
      return Sobol(pb, o);
    case Method::kGaussLegendre:
      return GaussLegendreRule(pb, o);
    case Method::kAdaptive: {
      const auto t0 = std::chrono::steady_clock::now();
      AdaptiveResult r;
      if (pb.bxdf) {
        r = AdaptiveHalfVector(*pb.bxdf, pb.params, pb.wo, pb.alpha_x, pb.alpha_y, o);
      } else {
        r = AdaptiveDirections(pb.g, pb.peak, pb.width, o);
      }
      Estimate e;
      e.value = r.value;
      e.error = r.error;
      e.evals = r.evals;
      e.seconds = Seconds(t0);
      return e;
    }
  }
  throw std::invalid_argument("unknown integration method");
}

// Last component of a dotted lobe parameter name ("ggx#2.alpha" -> "alpha").
std::string BaseName(const std::string& name) {
  const auto dot = name.rfind('.');
  return dot == std::string::npos ? name : name.substr(dot + 1);
}

}  // namespace

const char* MethodName(Method method) {
  switch (method) {
    case Method::kUniform: return "uniform";
    case Method::kCosine: return "cosine";
    case Method::kImportance: return "importance";
    case Method::kSobol: return "sobol";
    case Method::kGaussLegendre: return "gauss_legendre";
    case Method::kAdaptive: return "adaptive";
  }
  return "unknown";
}

const std::vector<Method>& AllMethods() {
  static const std::vector<Method> kAll = {Method::kUniform, Method::kCosine,        Method::kImportance,
                                           Method::kSobol,   Method::kGaussLegendre, Method::kAdaptive};
  return kAll;
}

Method ParseMethod(const std::string& text) {
  std::string known;
  for (Method m : AllMethods()) {
    if (text == MethodName(m)) return m;
    known += (known.empty() ? "" : ", ") + std::string(MethodName(m));
  }
  throw std::invalid_argument("unknown integration method '" + text + "' (expected one of: " + known + ")");
}

// Roughness of the narrowest lobe along x and y (0 if none).
void LobeRoughness(const ModelInfo& info, const double* params, double& ax, double& ay) {
  ax = ay = 0;
  auto take = [](double& cur, double v) { cur = cur > 0 ? std::min(cur, v) : v; };
  for (std::size_t i = 0; i < info.params.size(); ++i) {
    const ParamInfo& p = info.params[i];
    if (p.colour) continue;
    const std::string b = BaseName(p.name);
    const double v = params[info.Offset(i)];
    if (!(v > 0) || !std::isfinite(v)) continue;
    if (b == "alpha" || b == "m") {
      take(ax, v);
      take(ay, v);
    } else if (b == "alpha_x") {
      take(ax, v);
    } else if (b == "alpha_y") {
      take(ay, v);
    } else if (b == "n" && p.upper > 10) {
      // Phong-type exponent: cos^n ~ exp(-n theta^2 / 2), the Beckmann lobe
      // with alpha^2 = 2 / (n + 2) (Walter 2007, sec. 5.2).
      const double a = std::sqrt(2.0 / (v + 2.0));
      take(ax, a);
      take(ay, a);
    }
  }
  if (ax > 0 && !(ay > 0)) ay = ax;
  if (ay > 0 && !(ax > 0)) ax = ay;
}

double LobeWidth(const ModelInfo& info, const double* params) {
  double ax, ay;
  LobeRoughness(info, params, ax, ay);
  return std::min(ax, ay);
}

Estimate DirectionalAlbedo(const Bxdf<double>& bxdf, const double* params, const Vector3d& wo_in, Method method,
                           const IntegrateOptions& options) {
  if (!(wo_in.norm() > 0) || !wo_in.allFinite())
    throw std::invalid_argument("DirectionalAlbedo: wo must be a finite non-zero direction");
  const Vector3d wo = wo_in.normalized();
  Estimate zero;
  if (!(wo.z() > 0)) return zero;  // f = 0 for wo at or below the horizon
  Problem pb;
  pb.g = [&bxdf, params, wo](const Vector3d& wi) -> Array3d {
    if (!(wi.z() > 0)) return Array3d::Zero();
    return bxdf.Eval(params, wi, wo) * wi.z();
  };
  pb.sample = [&bxdf, params, wo](double u1, double u2) {
    const BsdfSample<double> s = bxdf.Sample(params, wo, u1, u2);
    DirSample d;
    d.wi = s.wi;
    d.pdf = s.pdf;
    d.valid = s.valid && s.wi.z() > 0;
    return d;
  };
  pb.bxdf = &bxdf;
  pb.params = params;
  pb.wo = wo;
  LobeRoughness(bxdf.Info(), params, pb.alpha_x, pb.alpha_y);
  if (pb.alpha_x > 0) {
    pb.peak = Reflect<double>(wo);
    pb.width = 2.0 * std::max(pb.alpha_x, pb.alpha_y);
    // A half-vector lobe of solid angle pi ax ay maps to 4 (wo.h) pi ax ay
    // around the mirror direction (dwi = 4 |wo.h| dwh, Walter 2007 eq. 14).
    pb.lobe_solid_angle = std::min(2.0 * kPi, 4.0 * wo.z() * kPi * pb.alpha_x * pb.alpha_y);
  }
  return Run(pb, method, options);
}

Estimate IntegrateHemisphere(const std::function<Array3d(const Vector3d&)>& g, Method method,
                             const IntegrateOptions& options, const Vector3d& peak, double width) {
  Problem pb;
  pb.g = [&g](const Vector3d& w) -> Array3d {
    if (!(w.z() > 0)) return Array3d::Zero();
    return g(w);
  };
  if (!peak.isZero() && peak.allFinite() && width > 0 && std::isfinite(width)) {
    pb.peak = peak.normalized();
    pb.width = width;
    pb.lobe_solid_angle = std::min(2.0 * kPi, kPi * width * width);
  }
  return Run(pb, method, options);
}

}  // namespace brdfkit::validate
