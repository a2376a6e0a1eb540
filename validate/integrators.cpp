#include "validate/integrators.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "brdf/quadrature.h"
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
// g at n directions: out[k] = g(w[k]).
using BatchIntegrand = std::function<void(const Vector3d* w, std::size_t n, Array3d* out)>;

BatchIntegrand PointByPoint(const std::function<Array3d(const Vector3d&)>& g) {
  return [&g](const Vector3d* w, std::size_t n, Array3d* out) {
    for (std::size_t k = 0; k < n; ++k) out[k] = g(w[k]);
  };
}

struct Problem {
  std::function<Array3d(const Vector3d&)> g;
  BatchIntegrand g_batch;  // g on many directions at once (optional)
  std::function<DirSample(double, double)> sample;  // empty: cosine or lobe mixture
  Vector3d peak = Vector3d::Zero();                  // zero: no peak known
  double width = 0;                                  // angular width of the peak (radians)
  double width_y = 0;                                // along y, for a peak at the normal
  Vector3d cut = Vector3d::Zero();                   // g = 0 where cut.w <= 0 (zero: none)
  double lobe_solid_angle = 0;                       // solid angle holding most of the peak's mass
  // Adaptive rule: a BRDF with a glossy lobe is integrated over the half
  // vector, one without in (phi, cos theta).
  const Bxdf<double>* bxdf = nullptr;
  const double* params = nullptr;
  Vector3d wo = Vector3d::UnitZ();
  bool lobe = false;
  LobeShape shape;
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

// GGX-shaped lobe around the frame's axis with widths (wx, wy) along its
// tangents (heavy tails, so it covers both GGX and lighter-tailed peaks):
// density D_GGX(local; wx, wy) cos(local theta), sampled through unit-width
// slopes (tan^2 = u1 / (1 - u1)) stretched by the widths.
Vector3d SampleLobe(const Frame& f, double wx, double wy, double u1, double u2) {
  const double tan_t = std::sqrt(u1 / (1.0 - u1));
  const double phi = 2.0 * kPi * u2;
  const Vector3d local = Vector3d(wx * tan_t * std::cos(phi), wy * tan_t * std::sin(phi), 1.0).normalized();
  return f.ToWorld(local);
}

double LobePdf(const Frame& f, double wx, double wy, const Vector3d& d) {
  const Vector3d l = f.ToLocal(d);
  if (l.z() <= 0) return 0;  // the lobe covers the hemisphere around its axis only
  const double e = l.x() * l.x() / (wx * wx) + l.y() * l.y() / (wy * wy) + l.z() * l.z();
  return l.z() / (kPi * wx * wy * e * e);
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
  const double wx = std::min(pb.width, 1e3), wy = std::min(pb.width_y > 0 ? pb.width_y : pb.width, 1e3);
  return [frame, wx, wy](double u1, double u2) {
    DirSample s;
    if (u1 < 0.5) {
      s.wi = SampleCosineHemisphere<double>(2.0 * u1, u2);
    } else {
      // 2 u1 - 1 stays below 1 for u1 < 1.
      s.wi = SampleLobe(frame, wx, wy, 2.0 * u1 - 1.0, u2);
    }
    if (!(s.wi.z() > 0)) return s;
    s.pdf = 0.5 * s.wi.z() * kInvPi + 0.5 * LobePdf(frame, wx, wy, s.wi);
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

// Worst-case rounding of a sum of n terms: n machine epsilons of the value.
Array3d RoundingFloor(const Array3d& value, std::int64_t n) {
  return value.abs() * (double(std::max<std::int64_t>(n, 1)) * std::numeric_limits<double>::epsilon());
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
  // Rounding of the running sums bounds what a zero-variance estimator
  // (exact importance sampling) can claim.
  e.error = e.error.max(RoundingFloor(e.value, n));
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
  e.error = (StudentT99(replicates - 1) * st.StdError()).max(RoundingFloor(st.mean, per));
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
    if (spacing > std::min(pb.width, pb.width_y > 0 ? pb.width_y : pb.width) && pb.lobe_solid_angle > 0)
      e.error = e.error.max(pb.g(pb.peak).abs() * pb.lobe_solid_angle);
  }
  e.seconds = Seconds(t0);
  return e;
}

// ---------------------------------------------------------------------------
// Deterministic adaptive rule: globally adaptive Gauss-Kronrod (7, 15)
// cubature (Piessens et al. 1983, QUADPACK QAG; product form on rectangles)
// on coordinates in which a narrow lobe has unit width and the horizon is an
// end of every inner range.

struct AdaptiveResult {
  Array3d value = Array3d::Zero();
  Array3d error = Array3d::Zero();
  std::int64_t evals = 0;
};

using PointValue = QuadValue;

struct Counter {
  std::int64_t evals = 0;
  std::int64_t budget = 0;
  bool Spent() const { return evals >= budget; }
};

// Globally adaptive quadrature over [-1, 1] split at `breaks` (at most
// max_segments segments) until the total error meets the tolerance or the
// evaluation budget is spent.
template <typename F>
PointValue Adapt(F& f, const std::vector<double>& breaks, double abs_tol, double rel_tol, const Counter& counter,
                 int max_segments = 400) {
  return AdaptiveKronrod(f, -1.0, 1.0, breaks, abs_tol, rel_tol, max_segments - int(breaks.size()) - 1,
                         [&counter] { return counter.Spent(); });
}

// Maps sigma in [-1, 1] onto [lo, hi] by a cubic whose derivative vanishes at
// both ends: an integrand with a square-root type end point (the horizon, or
// a chord of the valid region shrinking to zero) becomes smooth in sigma.
struct EndMap {
  double mid = 0, half = 0;
  EndMap(double lo, double hi) : mid(0.5 * (lo + hi)), half(0.5 * (hi - lo)) {}
  double operator()(double s) const { return mid + half * 0.5 * s * (3.0 - s * s); }
  double Derivative(double s) const { return half * 1.5 * (1.0 - s * s); }
  // sigma for a point u of [lo, hi] (trigonometric root of the cubic).
  double Inverse(double u) const {
    const double z = std::clamp((u - mid) / half, -1.0, 1.0);
    return 2.0 * std::sin(std::asin(z) / 3.0);
  }
};

// Chart of the upper hemisphere by slopes: direction (p, 1) / |(p, 1)| with
// p = pc + X a + Y b; dw = |a x b| dX dY / (1 + |p|^2)^(3/2).
struct SlopeChart {
  Eigen::Vector2d pc = Eigen::Vector2d::Zero(), a = Eigen::Vector2d(1, 0), b = Eigen::Vector2d(0, 1);
  double Jacobian() const { return std::abs(a.x() * b.y() - a.y() * b.x()); }
  // Direction and solid-angle density per unit dX dY.
  Vector3d Direction(double x, double y, double& dw) const {
    const Eigen::Vector2d p = pc + x * a + y * b;
    const double r2 = 1.0 + p.squaredNorm();
    const double r = std::sqrt(r2);
    dw = Jacobian() / (r2 * r);
    return Vector3d(p.x() / r, p.y() / r, 1.0 / r);
  }
};

// Coordinate along one axis of the slope chart: x = s tan(t), which turns a
// GGX-like peak of unit width into a trigonometric polynomial (its slope
// density (s^2 + x^2)^-2 dx becomes cos^2(t) dt / s^3) and reaches infinity
// at t = +-pi/2, composed with EndMap to smooth end points.
struct AxisMap {
  double s;
  EndMap end;
  AxisMap(double scale, double lo, double hi) : s(scale), end(std::atan(lo / scale), std::atan(hi / scale)) {}
  // x and dx/dsigma at sigma.
  double Map(double sigma, double& jac) const {
    const double t = end(sigma);
    const double c = std::cos(t);
    jac = s * end.Derivative(sigma) / (c * c);
    return s * std::tan(t);
  }
  // Break point at the peak's centre x = 0 when it is well inside the range.
  std::vector<double> Breaks() const {
    const double lo = end.mid - end.half, hi = end.mid + end.half;
    const double margin = 0.05 * (hi - lo);
    if (!(lo + margin < 0.0 && 0.0 < hi - margin)) return {};
    return {end.Inverse(0.0)};
  }
};

// One rectangle [y0, y1] x [x0, x1] of the (sigma_y, sigma_x) square with
// its 15 x 15 Gauss-Kronrod product estimate and per-axis error indicators.
struct Rect {
  double y0 = -1, y1 = 1, x0 = -1, x1 = 1;
  Array3d value = Array3d::Zero();
  Array3d err_x = Array3d::Zero(), err_y = Array3d::Zero();
  double key = 0;
  bool operator<(const Rect& o) const { return key < o.key; }
  Array3d Error() const { return err_x + err_y; }
};

// Globally adaptive cubature over a slope chart (Genz & Malik 1980 strategy,
// with a product Gauss-Kronrod 15 x 15 rule): the rectangle with the largest
// error is halved along the axis whose embedded Gauss rule disagrees most.
// The outer coordinate Y runs over [y_lo, y_hi]; for each Y the inner X runs
// over range_x(Y) (false: empty), mapped onto sigma_x in [-1, 1], so the
// valid region is always the full square and the integrand is smooth in it.
template <typename RangeX, typename G>
AdaptiveResult AdaptiveSlope(const SlopeChart& chart, double y_lo, double y_hi, RangeX&& range_x, G&& g,
                             const IntegrateOptions& o) {
  AdaptiveResult out;
  if (!(y_hi > y_lo)) return out;
  const AxisMap my(1.0, y_lo, y_hi);
  std::int64_t evals = 0;
  const auto& nodes = kGk15.x;
  const auto& wk = kGk15.wk;
  const auto& wg = kGk15.wg;
  auto evaluate = [&](Rect r) {
    const double cy = 0.5 * (r.y0 + r.y1), hy = 0.5 * (r.y1 - r.y0);
    const double cx = 0.5 * (r.x0 + r.x1), hx = 0.5 * (r.x1 - r.x0);
    Array3d f[15][15];
    for (int i = 0; i < 15; ++i) {
      double jy;
      const double y = my.Map(cy + hy * nodes[i], jy);
      double x_lo, x_hi;
      const bool row = jy > 0 && std::isfinite(y) && range_x(y, x_lo, x_hi);
      const AxisMap mx(std::sqrt(1.0 + y * y), row ? x_lo : 0.0, row ? x_hi : 1.0);
      for (int j = 0; j < 15; ++j) {
        f[i][j] = Array3d::Zero();
        ++evals;
        if (!row) continue;
        double jx;
        const double x = mx.Map(cx + hx * nodes[j], jx);
        if (!(jx > 0) || !std::isfinite(x)) continue;
        double dw;
        const Vector3d d = chart.Direction(x, y, dw);
        f[i][j] = g(d) * (dw * jx * jy);
      }
    }
    Array3d k = Array3d::Zero(), gy = Array3d::Zero(), gx = Array3d::Zero(), abs_k = Array3d::Zero();
    for (int i = 0; i < 15; ++i)
      for (int j = 0; j < 15; ++j) {
        k += wk[i] * wk[j] * f[i][j];
        gy += wg[i] * wk[j] * f[i][j];
        gx += wk[i] * wg[j] * f[i][j];
        abs_k += wk[i] * wk[j] * f[i][j].abs();
      }
    const double area = hx * hy;
    const Array3d mean = k / 4.0;
    Array3d resasc = Array3d::Zero();
    for (int i = 0; i < 15; ++i)
      for (int j = 0; j < 15; ++j) resasc += wk[i] * wk[j] * (f[i][j] - mean).abs();
    r.value = k * area;
    r.err_y = QuadpackError(((k - gy) * area).abs(), resasc * area, abs_k * area);
    r.err_x = QuadpackError(((k - gx) * area).abs(), resasc * area, abs_k * area);
    r.key = r.Error().maxCoeff();
    return r;
  };
  std::vector<Rect> heap;
  {
    std::vector<double> ys = {-1.0, 1.0};
    for (double b : my.Breaks()) ys.push_back(b);
    std::sort(ys.begin(), ys.end());
    for (std::size_t i = 0; i + 1 < ys.size(); ++i) {
      Rect r;
      r.y0 = ys[i];
      r.y1 = ys[i + 1];
      heap.push_back(evaluate(r));
    }
  }
  std::make_heap(heap.begin(), heap.end());
  Array3d value, error;
  auto totals = [&] {
    value = error = Array3d::Zero();
    for (const Rect& r : heap) {
      value += r.value;
      error += r.Error();
    }
  };
  totals();
  const std::int64_t per_rect = 225;
  while (evals + 2 * per_rect <= o.budget) {
    const Array3d target = (o.rel_tolerance * value.abs()).max(o.abs_tolerance);
    if ((error <= target).all()) break;
    std::pop_heap(heap.begin(), heap.end());
    const Rect worst = heap.back();
    if (worst.key < 0) break;  // nothing left that can be split
    Rect a = worst, b = worst;
    const bool split_y = worst.err_y.maxCoeff() >= worst.err_x.maxCoeff();
    if (split_y) {
      a.y1 = b.y0 = 0.5 * (worst.y0 + worst.y1);
    } else {
      a.x1 = b.x0 = 0.5 * (worst.x0 + worst.x1);
    }
    // Rectangles this thin cannot be split further in double precision.
    if ((split_y ? worst.y1 - worst.y0 : worst.x1 - worst.x0) < 1e-13) {
      heap.back().key = -1;
      std::push_heap(heap.begin(), heap.end());
      continue;
    }
    heap.pop_back();
    heap.push_back(evaluate(a));
    std::push_heap(heap.begin(), heap.end());
    heap.push_back(evaluate(b));
    std::push_heap(heap.begin(), heap.end());
    totals();
  }
  out.value = value;
  out.error = error;
  out.evals = evals;
  return out;
}

// Breakpoints width * 4^k (k >= -1) below `limit`.
void GeometricBreaks(double width, double limit, std::vector<double>& out) {
  for (double x = width / 4; x < limit; x *= 4) out.push_back(x);
}

// The directions of a quadrature rule's nodes, gathered for one EvalBatch
// call with a fixed partner direction, and their Jacobians; nodes without a
// direction (outside the integration domain) stay zero.
class NodeBatch {
 public:
  void Clear() {
    rows_.clear();
    at_.clear();
    jacobian_.clear();
  }
  void Add(std::size_t node, const Vector3d& dir, double jacobian) {
    rows_.insert(rows_.end(), {dir.x(), dir.y(), dir.z()});
    at_.push_back(node);
    jacobian_.push_back(jacobian);
  }
  // nodes[k].value = f_r * jacobian for every added node: f_r(dir, fixed) or,
  // with fixed_first, f_r(fixed, dir).
  void Evaluate(const Bxdf<double>& bxdf, const double* p, const Vector3d& fixed, bool fixed_first,
                QuadValue* nodes) {
    if (at_.empty()) return;
    values_.resize(rows_.size());
    if (fixed_first) bxdf.EvalBatch(p, fixed.data(), 0, rows_.data(), 3, at_.size(), values_.data());
    else bxdf.EvalBatch(p, rows_.data(), 3, fixed.data(), 0, at_.size(), values_.data());
    for (std::size_t j = 0; j < at_.size(); ++j)
      nodes[at_[j]].value = Array3d(values_[3 * j], values_[3 * j + 1], values_[3 * j + 2]) * jacobian_[j];
  }

 private:
  std::vector<double> rows_, values_, jacobian_;
  std::vector<std::size_t> at_;
};

// Where w.m = c on the facet normals m = (theta, phi) about a fixed w =
// (s, 0, mu) (phi measured from w's azimuth): w.m = r cos(theta - theta_0),
// r = hypot(s cos(phi), mu), theta_0 = atan2(s cos(phi), mu). Inner
// breakpoints: the thetas in (0, tmax) on that curve for one phi.
void FacetKinkThetas(double s, double mu, double cp, double tmax, const std::vector<double>& kinks,
                     std::vector<double>& out) {
  const double a = s * cp, r = std::hypot(a, mu), t0 = std::atan2(a, mu);
  for (double c : kinks) {
    if (!(c < r)) continue;
    const double dt = std::acos(c / r);
    for (double tb : {t0 - dt, t0 + dt})
      if (tb > 0 && tb < tmax) out.push_back(tb);
  }
}
// Outer breakpoints: the phis in (0, phi_end) where the curve w.m = c
// leaves the range of theta (r(phi) = c), a kink of the inner integral.
void FacetKinkPhis(double s, double mu, double phi_end, const std::vector<double>& kinks, std::vector<double>& out) {
  for (double c : kinks) {
    if (!(c > mu) || !(s > 0)) continue;
    const double x = std::sqrt(c * c - mu * mu) / s;
    if (!(x < 1)) continue;
    const double a = std::acos(x);
    for (double phi : {a, kPi - a, kPi + a, 2 * kPi - a})
      if (phi > 0 && phi < phi_end) out.push_back(phi);
  }
}

// AdaptiveKronrod over [a, b] split at `breaks`, where the integrand may
// behave like sqrt(|x - r|) on one side of the points `roots` (a Fresnel
// reflectance reaching total internal reflection): each panel between
// breakpoints that ends at a root is integrated in s in [0, 1] with x = x0 +
// L w(s), w = s^2, 1 - (1 - s)^2 or 3 s^2 - 2 s^3 (a root at the left, the
// right or both ends), which turns sqrt(x - r) into a smooth function of s.
template <typename G, typename Stop>
QuadValue KronrodWithRoots(G& g, double a, double b, std::vector<double> breaks, const std::vector<double>& roots,
                           double abs_tol, double rel_tol, int max_splits, Stop&& stop) {
  if (roots.empty()) return AdaptiveKronrod(g, a, b, std::move(breaks), abs_tol, rel_tol, max_splits, stop);
  breaks.insert(breaks.end(), roots.begin(), roots.end());
  std::sort(breaks.begin(), breaks.end());
  std::vector<double> pts{a};
  for (double x : breaks)
    if (x > pts.back() && x < b) pts.push_back(x);
  pts.push_back(b);
  const std::size_t panels = pts.size() - 1;
  const auto is_root = [&](double x) { return std::find(roots.begin(), roots.end(), x) != roots.end(); };
  std::vector<int> kind(panels);  // bit 0: root at the left end, bit 1: at the right end
  for (std::size_t i = 0; i < panels; ++i) kind[i] = (is_root(pts[i]) ? 1 : 0) | (is_root(pts[i + 1]) ? 2 : 0);
  const auto map = [&](double sv, double& x, double& jac) {
    const std::size_t i = std::min(panels - 1, static_cast<std::size_t>(std::max(0.0, std::floor(sv))));
    const double t = sv - double(i), len = pts[i + 1] - pts[i];
    double w = t, dw = 1;
    if (kind[i] == 1) w = t * t, dw = 2 * t;
    else if (kind[i] == 2) w = 1 - (1 - t) * (1 - t), dw = 2 * (1 - t);
    else if (kind[i] == 3) w = t * t * (3 - 2 * t), dw = 6 * t * (1 - t);
    x = pts[i] + len * w;
    jac = len * dw;
  };
  std::vector<double> panel_breaks;
  for (std::size_t i = 1; i < panels; ++i) panel_breaks.push_back(double(i));
  if constexpr (QuadBatchIntegrand<G>) {
    std::vector<double> xs, jacs;
    auto warped = [&](const double* sv, std::size_t n, QuadValue* out) {
      xs.resize(n);
      jacs.resize(n);
      for (std::size_t k = 0; k < n; ++k) map(sv[k], xs[k], jacs[k]);
      g(xs.data(), n, out);
      for (std::size_t k = 0; k < n; ++k) {
        out[k].value *= jacs[k];
        out[k].error *= jacs[k];
      }
    };
    return AdaptiveKronrod(warped, 0.0, double(panels), std::move(panel_breaks), abs_tol, rel_tol, max_splits, stop);
  } else {
    auto warped = [&](double sv) {
      double x, jac;
      map(sv, x, jac);
      QuadValue v = g(x);
      v.value *= jac;
      v.error *= jac;
      return v;
    };
    return AdaptiveKronrod(warped, 0.0, double(panels), std::move(panel_breaks), abs_tol, rel_tol, max_splits, stop);
  }
}

// Directional albedo over the half vector wm = (theta_m, phi_m), dwi = 4
// (wo.wm) dwm (Walter 2007 eq. 14): a specular lobe of any width sits at
// wm = z for every wo, and the horizon wi.z = 0 is the exact curve
// theta_m = theta_max(phi_m), the end of every inner range, so the
// integrand is smooth on the integration domain. Both angles by globally
// adaptive Gauss-Kronrod (7, 15) with breakpoints at multiples of the lobe
// width and where wi.z = wo.z; phi_m over [0, pi] only for a
// mirror-symmetric model with wo in the xz plane. The error is the outer estimate plus the integral of the
// inner ones; the evaluation budget stops refinement of both levels.
AdaptiveResult AdaptiveHalfVector(const Bxdf<double>& bxdf, const double* p, const Vector3d& wo, const LobeShape& shape,
                                  const IntegrateOptions& o) {
  AdaptiveResult out;
  const double mu_o = wo.z();
  if (!(mu_o > 0)) return out;
  const double sin_o = std::sqrt(std::max(0.0, wo.x() * wo.x() + wo.y() * wo.y()));
  const double phi_o = sin_o > 0 ? std::atan2(wo.y(), wo.x()) : 0.0;
  const bool half = shape.mirror_symmetric && wo.y() == 0;
  const double w = std::max(shape.width, 1e-12);  // a zero width would put every breakpoint at 0
  constexpr double kHalfPi = 0.5 * kPi;

  // theta_max(phi): wi.z = mu_o cos(2 theta) + sin_o cos(phi) sin(2 theta) > 0.
  const auto theta_max = [&](double phi) { return 0.5 * (kHalfPi + std::atan2(sin_o * std::cos(phi), mu_o)); };

  std::int64_t evals = 0, inner_calls = 0;
  const double phi_end = half ? kPi : 2 * kPi;
  const double factor = half ? 2.0 : 1.0;
  // Where the horizon cuts a narrow lobe: phi = pi/2 + asin(s) with the cut
  // at theta ~ mu_o / (2 s), s from mu_o / w upwards; and on the other side
  // of pi/2, where theta_max rises from pi/4 towards pi/2 over the same
  // scale of phi.
  std::vector<double> breaks{kHalfPi};
  if (!half) breaks.push_back(1.5 * kPi);
  for (double s = mu_o / w / 16; s < 1; s *= 4) {
    for (double side : {1.0, -1.0}) {
      breaks.push_back(kHalfPi + side * std::asin(s));
      if (!half) breaks.push_back(1.5 * kPi - side * std::asin(s));
    }
  }
  std::vector<double> phi_roots;
  FacetKinkPhis(sin_o, mu_o, phi_end, o.facet_kinks, phi_roots);
  std::sort(breaks.begin(), breaks.end());
  breaks.erase(std::unique(breaks.begin(), breaks.end()), breaks.end());
  // The budget: refinement at either level stops when one more bisection
  // (30 evaluations, or 30 inner integrals) would pass it, keeping enough
  // for the inner integrals the outer rule's first pass still needs.
  const std::int64_t first_pass = 15 * static_cast<std::int64_t>(breaks.size() + phi_roots.size() + 1);
  std::int64_t inner_min_cost = 15;
  const auto reserve = [&] { return std::max<std::int64_t>(0, first_pass - inner_calls) * inner_min_cost; };
  // Each inner integral gets a share of the tolerance such that their
  // integral over phi is at most half of it; the outer rule carries the
  // inner error estimates (integrated with its weights) and adds its own.
  const double inner_abs = o.abs_tolerance / (2 * factor * phi_end), inner_rel = 0.5 * o.rel_tolerance;
  const auto inner_spent = [&] { return evals + 30 + reserve() > o.budget; };
  const auto outer_spent = [&] {
    const double per_inner = inner_calls > 0 ? double(evals) / double(inner_calls) : 15.0;
    return double(evals) + 30 * per_inner > double(o.budget);
  };
  NodeBatch batch;
  const auto inner = [&](double phi) -> QuadValue {
    ++inner_calls;
    const double tmax = theta_max(phi);
    const double cp = std::cos(phi);
    const double ca = std::cos(phi + phi_o), sa = std::sin(phi + phi_o);
    // The rule's nodes in one EvalBatch call (a model's vectorised kernel,
    // one Python call for a model defined in Python).
    const auto g = [&](const double* ts, std::size_t n, QuadValue* nodes) {
      evals += static_cast<std::int64_t>(n);
      batch.Clear();
      for (std::size_t k = 0; k < n; ++k) {
        nodes[k] = QuadValue{};
        const double t = ts[k], st = std::sin(t), ct = std::cos(t);
        const Vector3d wm(st * ca, st * sa, ct);
        const double o_dot_m = sin_o * st * cp + mu_o * ct;
        // wi.z from the double-angle form: no cancellation at grazing;
        // cos(2t) = (cos t - sin t)(cos t + sin t), sin(2t) = 2 sin t cos t.
        const double wi_z = mu_o * ((ct - st) * (ct + st)) + sin_o * cp * (2 * st * ct);
        if (!(wi_z > 0) || !(o_dot_m > 0)) continue;
        Vector3d wi = 2 * o_dot_m * wm - wo;
        wi.z() = wi_z;
        batch.Add(k, wi, wi_z * 4 * o_dot_m * st);
      }
      batch.Evaluate(bxdf, p, wo, false, nodes);
    };
    std::vector<double> inner_breaks;
    GeometricBreaks(w, tmax, inner_breaks);
    // wi.z = wo.z at theta_m = atan2(sin_o cos(phi), mu_o) (cos(phi) > 0): the
    // kink of models with max or min(cos theta_i, cos theta_o) (as the
    // spherical rule's break at cos theta = mu_o).
    if (cp > 0) inner_breaks.push_back(std::atan2(sin_o * cp, mu_o));
    std::vector<double> roots;
    FacetKinkThetas(sin_o, mu_o, cp, tmax, o.facet_kinks, roots);
    inner_min_cost = 15 * static_cast<std::int64_t>(inner_breaks.size() + roots.size() + 1);
    return KronrodWithRoots(g, 0.0, tmax, std::move(inner_breaks), roots, inner_abs, inner_rel, o.max_subdivisions,
                            inner_spent);
  };
  const QuadValue v = KronrodWithRoots(inner, 0.0, phi_end, std::move(breaks), phi_roots, o.abs_tolerance / factor,
                                      o.rel_tolerance, o.max_subdivisions, outer_spent);
  out.value = v.value * factor;
  out.error = v.error * factor;
  out.evals = evals;
  return out;
}

// Generic integrand near a peak: the slope chart centred on the peak's slope,
// stretched by the peak's width (radially by 1/cos^2, tangentially by 1/cos,
// the growth of slopes with the polar angle); the whole plane is the open
// hemisphere, reached through the tan warp.
AdaptiveResult AdaptivePeak(const std::function<Array3d(const Vector3d&)>& g, const Vector3d& peak, double width,
                            double width_y, const Vector3d& cut, const IntegrateOptions& o) {
  const double cz = std::max(peak.z(), 1e-6);  // a peak on the horizon: chart it just above
  SlopeChart chart;
  chart.pc = Eigen::Vector2d(peak.x(), peak.y()) / cz;
  const double inf = std::numeric_limits<double>::infinity();
  double x_min = -inf;
  if (chart.pc.norm() > 0) {
    const Eigen::Vector2d n = chart.pc.normalized();
    chart.a = n * (width / (cz * cz));
    chart.b = Eigen::Vector2d(-n.y(), n.x()) * (width / cz);
  } else {
    // Peak at the normal: inner axis along the cut's normal in the stretched
    // plane, so cut.(p, 1) > 0 reads X > x_min for every Y.
    Eigen::Vector2d n(width * cut.x(), width_y * cut.y());
    const bool has_cut = n.norm() > 0;
    n = has_cut ? Eigen::Vector2d(n.normalized()) : Eigen::Vector2d(1, 0);
    const Eigen::Vector2d m(-n.y(), n.x());
    chart.a = Eigen::Vector2d(width * n.x(), width_y * n.y());
    chart.b = Eigen::Vector2d(width * m.x(), width_y * m.y());
    if (has_cut) x_min = -cut.z() / (cut.x() * chart.a.x() + cut.y() * chart.a.y());
  }
  auto range_x = [x_min, inf](double, double& lo, double& hi) {
    lo = x_min;
    hi = inf;
    return true;
  };
  return AdaptiveSlope(chart, -inf, inf, range_x, g, o);
}

// No lobe: directions by (phi, cos theta), phi measured from `phi0`, with
// break points at phi0 + {-pi/2, 0, pi/2} and cos theta = `mu_break` (where
// diffuse models such as Oren-Nayar have kinks).
AdaptiveResult AdaptiveSpherical(const BatchIntegrand& g, double phi0, double mu_break, const IntegrateOptions& o) {
  Counter counter{0, o.budget};
  const EndMap mu_map(0.0, 1.0);
  std::vector<double> mu_breaks;
  if (mu_break > 0.01 && mu_break < 0.99) mu_breaks.push_back(mu_map.Inverse(mu_break));
  const double inner_rel = 0.1 * o.rel_tolerance, inner_abs = 0.05 * o.abs_tolerance;
  auto outer = [&](double sp) -> PointValue {
    const double phi = phi0 + kPi * sp;
    const double c = std::cos(phi), s = std::sin(phi);
    // The rule's nodes in one call of g.
    std::vector<Vector3d> dirs;
    std::vector<double> jacobian;
    std::vector<std::size_t> at;
    std::vector<Array3d> values;
    auto inner = [&](const double* su, std::size_t n, PointValue* out) {
      counter.evals += static_cast<std::int64_t>(n);
      dirs.clear();
      jacobian.clear();
      at.clear();
      for (std::size_t k = 0; k < n; ++k) {
        out[k] = PointValue{};
        const double u = mu_map(su[k]);
        const double ju = mu_map.Derivative(su[k]);
        if (!(u > 0) || !(ju > 0)) continue;
        const double r = std::sqrt(std::max(0.0, 1.0 - u * u));
        dirs.emplace_back(r * c, r * s, u);
        jacobian.push_back(ju * kPi);
        at.push_back(k);
      }
      if (at.empty()) return;
      values.resize(at.size());
      g(dirs.data(), at.size(), values.data());
      for (std::size_t j = 0; j < at.size(); ++j) out[at[j]].value = values[j] * jacobian[j];
    };
    return Adapt(inner, mu_breaks, inner_abs, inner_rel, counter);
  };
  const PointValue r = Adapt(outer, {-0.5, 0.0, 0.5}, o.abs_tolerance, o.rel_tolerance, counter);
  return AdaptiveResult{r.value, r.error, counter.evals};
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
      if (pb.bxdf && pb.lobe) {
        r = AdaptiveHalfVector(*pb.bxdf, pb.params, pb.wo, pb.shape, o);
      } else if (pb.bxdf) {
        r = AdaptiveSpherical(pb.g_batch ? pb.g_batch : PointByPoint(pb.g), std::atan2(pb.wo.y(), pb.wo.x()),
                              pb.wo.z(), o);
      } else if (!pb.peak.isZero() && pb.width > 0) {
        r = AdaptivePeak(pb.g, pb.peak, pb.width, pb.width_y, pb.cut, o);
      } else {
        r = AdaptiveSpherical(pb.g_batch ? pb.g_batch : PointByPoint(pb.g), 0.0, 0.0, o);
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

LobeShape EstimateLobeShape(const Bxdf<double>& bxdf, const double* p) {
  LobeShape shape;
  // The model's declared lobe width; a model without a glossy lobe is broad.
  const LobeWidth lobe = bxdf.Width(p);
  shape.width = lobe.Any() ? std::min(1.0, lobe.Min()) : 1.0;
  // Mirror symmetry about the xz plane, tested at fixed pairs spread over the
  // hemisphere with wo in the plane.
  shape.mirror_symmetric = true;
  for (int k = 0; k < 24 && shape.mirror_symmetric; ++k) {
    const double to = 0.07 + 1.45 * ((k * 7) % 24) / 24.0, ti = 0.05 + 1.5 * ((k * 11) % 24) / 24.0;
    const double phi = 0.3 + 2.6 * ((k * 5) % 24) / 24.0;
    const Vector3d wo(std::sin(to), 0, std::cos(to));
    const Vector3d wi(std::sin(ti) * std::cos(phi), std::sin(ti) * std::sin(phi), std::cos(ti));
    const Vector3d wi_m(wi.x(), -wi.y(), wi.z());
    const Array3d a = bxdf.Eval(p, wi, wo), b = bxdf.Eval(p, wi_m, wo);
    const double scale = std::max(a.abs().maxCoeff(), b.abs().maxCoeff());
    if ((a - b).abs().maxCoeff() > 1e-12 * scale) shape.mirror_symmetric = false;
    if (bxdf.Kind() & LobeKind::kTransmission) {
      // Refraction pairs as well: wi on the other side.
      const Vector3d below(wi.x(), wi.y(), -wi.z()), below_m(wi.x(), -wi.y(), -wi.z());
      const Array3d c = bxdf.Eval(p, below, wo), d = bxdf.Eval(p, below_m, wo);
      if ((c - d).abs().maxCoeff() > 1e-12 * std::max(c.abs().maxCoeff(), d.abs().maxCoeff()))
        shape.mirror_symmetric = false;
    }
  }
  return shape;
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
  // The same in one EvalBatch call per set of directions.
  pb.g_batch = [&bxdf, params, wo](const Vector3d* wi, std::size_t n, Array3d* out) {
    static_assert(sizeof(Vector3d) == 3 * sizeof(double), "directions are packed rows of 3");
    std::vector<double> f(3 * n);
    bxdf.EvalBatch(params, wi[0].data(), 3, wo.data(), 0, n, f.data());
    for (std::size_t k = 0; k < n; ++k)
      out[k] = wi[k].z() > 0 ? Array3d(Array3d::Map(f.data() + 3 * k) * wi[k].z()) : Array3d::Zero();
  };
  // A model without its own sampling is importance-sampled by the default
  // sampler (cosine, or a lobe mixture about the mirror direction).
  if (bxdf.CanSample()) pb.sample = [&bxdf, params, wo](double u1, double u2) {
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
  const LobeWidth lobe = bxdf.Width(params);
  if (lobe.Any() && std::isfinite(lobe.x) && std::isfinite(lobe.y)) {
    pb.lobe = true;
    // Only the adaptive rule reads the shape; its symmetry test costs 48 evaluations.
    if (method == Method::kAdaptive) pb.shape = options.shape ? *options.shape : EstimateLobeShape(bxdf, params);
    pb.peak = Reflect<double>(wo);
    pb.width = 2.0 * std::max(lobe.x, lobe.y);
    // A half-vector lobe of solid angle pi ax ay maps to 4 (wo.h) pi ax ay
    // around the mirror direction (dwi = 4 |wo.h| dwh, Walter 2007 eq. 14).
    pb.lobe_solid_angle = std::min(2.0 * kPi, 4.0 * wo.z() * kPi * lobe.x * lobe.y);
  }
  return Run(pb, method, options);
}

Estimate IntegrateHemisphere(const std::function<Array3d(const Vector3d&)>& g, Method method,
                             const IntegrateOptions& options, const Vector3d& peak, double width, double width_y,
                             const Vector3d& cut) {
  Problem pb;
  pb.g = [&g, cut](const Vector3d& w) -> Array3d {
    if (!(w.z() > 0) || !(cut.isZero() || cut.dot(w) > 0)) return Array3d::Zero();
    return g(w);
  };
  pb.cut = cut.allFinite() ? cut : Vector3d::Zero();
  if (!peak.isZero() && peak.allFinite() && width > 0 && std::isfinite(width)) {
    pb.peak = peak.normalized();
    pb.width = width;
    pb.width_y = width_y > 0 && std::isfinite(width_y) ? width_y : width;
    pb.lobe_solid_angle = std::min(2.0 * kPi, kPi * width * pb.width_y);
  }
  return Run(pb, method, options);
}

namespace {

// The model seen from light on one side: Eval(a, b) = f(S(b), S(a)), S
// turning the upper side to that side (the identity for the upper side).
class LightSideView final : public Bxdf<double> {
 public:
  LightSideView(const Bxdf<double>& inner, bool below) : inner_(inner), below_(below) {}
  const ModelInfo& Info() const override { return inner_.Info(); }
  Array3d Eval(const double* p, const Vector3d& wi, const Vector3d& wo) const override {
    return inner_.Eval(p, Side(wo), Side(wi));
  }
  void EvalBatch(const double* p, const double* wi, std::size_t wi_stride, const double* wo, std::size_t wo_stride,
                 std::size_t n, double* out) const override {
    if (!below_) return inner_.EvalBatch(p, wo, wo_stride, wi, wi_stride, n, out);
    std::vector<double> a(3 * n), b(3 * n);
    for (std::size_t k = 0; k < n; ++k) {
      const double *u = wi + k * wi_stride, *v = wo + k * wo_stride;
      a[3 * k] = v[0], a[3 * k + 1] = v[1], a[3 * k + 2] = -v[2];
      b[3 * k] = u[0], b[3 * k + 1] = u[1], b[3 * k + 2] = -u[2];
    }
    inner_.EvalBatch(p, a.data(), 3, b.data(), 3, n, out);
  }
  BsdfSample<double> Sample(const double*, const Vector3d&, double, double) const override { return {}; }
  double Pdf(const double*, const Vector3d&, const Vector3d&) const override { return 0; }
  double SampleWeight(const double* p) const override { return inner_.SampleWeight(p); }
  bool CanSample() const override { return false; }
  unsigned Kind() const override { return inner_.Kind() & ~unsigned(LobeKind::kTransmission); }
  LobeWidth Width(const double* p) const override { return inner_.Width(p); }

 private:
  Vector3d Side(const Vector3d& w) const { return below_ ? Vector3d(w.x(), w.y(), -w.z()) : w; }
  const Bxdf<double>& inner_;
  bool below_;
};

// Power refracted to the other side from light along w, over the
// microfacet normal m (upper frame: w's side up), as AdaptiveHalfVector does
// for reflection: the refracted lobe sits at m = z for every w, and
// t = refract(w, m) with k = n_w / n_v (Snell: n_w sin = n_v sin), dw_t =
// (k (w.m) + t.m)^2 / |t.m| dw_m (the inverse of Walter et al. 2007, eq. 16). The integrand
// is zero where w.m <= 0, where m reflects w totally and where t would leave
// on w's side. Both angles by adaptive Gauss-Kronrod, breakpoints at
// multiples of the lobe width, where t reaches the horizon and at the
// options' facet kinks (ScatteredPower adds total internal reflection); the
// budget stops refinement of both levels.
AdaptiveResult AdaptiveRefracted(const Bxdf<double>& bxdf, const double* p, const Vector3d& w, double k,
                                 const LobeShape& shape, const IntegrateOptions& o) {
  const double width = std::min(1.0, shape.width);
  // phi over [0, pi] only for a mirror-symmetric model with w in the xz plane.
  const bool half = shape.mirror_symmetric && w.y() == 0;
  const double phi_end = half ? kPi : 2 * kPi, factor = half ? 2.0 : 1.0;
  AdaptiveResult out;
  const bool below = w.z() < 0;
  const double mu = std::abs(w.z());
  if (!(mu > 0)) return out;
  const double sin_w = std::sqrt(std::max(0.0, w.x() * w.x() + w.y() * w.y()));
  const double phi_w = sin_w > 0 ? std::atan2(w.y(), w.x()) : 0.0;
  const Vector3d wu(w.x(), w.y(), mu);
  const double wd = std::max(width, 1e-12);  // a zero width would put every breakpoint at 0
  constexpr double kHalfPi = 0.5 * kPi;
  std::int64_t evals = 0, inner_calls = 0;
  const auto inner_spent = [&] { return evals + 30 > o.budget; };
  const auto outer_spent = [&] {
    const double per_inner = inner_calls > 0 ? double(evals) / double(inner_calls) : 15.0;
    return double(evals) + 30 * per_inner > double(o.budget);
  };
  const double inner_abs = o.abs_tolerance / (2 * factor * phi_end), inner_rel = 0.5 * o.rel_tolerance;
  const std::vector<double>& kinks = o.facet_kinks;
  NodeBatch batch;
  const auto inner = [&](double phi) -> QuadValue {
    ++inner_calls;
    const double cp = std::cos(phi), ca = std::cos(phi + phi_w), sa = std::sin(phi + phi_w);
    // w.m > 0: theta_m below atan(mu / (-sin_w cos(phi))) where cos(phi) < 0.
    const double tmax = cp >= 0 ? kHalfPi : std::atan2(mu, -sin_w * cp);
    const auto g = [&](const double* ts, std::size_t n, QuadValue* nodes) {
      evals += static_cast<std::int64_t>(n);
      batch.Clear();
      for (std::size_t j = 0; j < n; ++j) {
        nodes[j] = QuadValue{};
        const double st = std::sin(ts[j]), ct = std::cos(ts[j]);
        const Vector3d m(st * ca, st * sa, ct);
        const double c = sin_w * st * cp + mu * ct;  // w.m
        if (!(c > 0)) continue;
        const double s2 = k * k * (1 - c * c);
        if (!(s2 < 1)) continue;  // total internal reflection at m
        const double ct_t = std::sqrt(1 - s2);  // -t.m
        Vector3d t = (k * c - ct_t) * m - k * wu;
        if (!(t.z() < 0)) continue;
        const double den = k * c - ct_t;  // k (w.m) + t.m
        if (!(den != 0)) continue;
        const double jacobian = -t.z() * den * den / ct_t * st;
        if (below) t.z() = -t.z();  // the other side of the actual w
        batch.Add(j, t, jacobian);
      }
      batch.Evaluate(bxdf, p, w, true, nodes);
    };
    std::vector<double> inner_breaks;
    GeometricBreaks(wd, tmax, inner_breaks);
    std::vector<double> roots;
    FacetKinkThetas(sin_w, mu, cp, tmax, kinks, roots);
    if (k > 1) {
      // Where t reaches the horizon, the cosine factor |t.z| ends at 0 with
      // a kink: m ~ t + k w with t = (cos psi, sin psi, 0), so along the
      // azimuth phi, tan(theta) = rho / (k mu) with rho (cos phi, sin phi)
      // on the unit circle about (k sin_w, 0).
      const double sp = std::sin(phi), disc = 1 - k * k * sin_w * sin_w * sp * sp;
      if (disc >= 0)
        for (double sign : {-1.0, 1.0}) {
          const double rho = k * sin_w * cp + sign * std::sqrt(disc);
          const double tb = std::atan2(rho, k * mu);
          if (rho > 0 && tb < tmax) inner_breaks.push_back(tb);
        }
    }
    return KronrodWithRoots(g, 0.0, tmax, std::move(inner_breaks), roots, inner_abs, inner_rel, o.max_subdivisions,
                            inner_spent);
  };
  std::vector<double> outer_breaks{kHalfPi}, phi_roots;
  if (!half) outer_breaks.insert(outer_breaks.end(), {kPi, 1.5 * kPi});
  FacetKinkPhis(sin_w, mu, phi_end, kinks, phi_roots);
  if (k * sin_w > 1) {
    // Where that circle's two crossings with the azimuth merge.
    const double a = std::asin(1 / (k * sin_w));
    for (double phi : {a, kPi - a, kPi + a, 2 * kPi - a})
      if (phi < phi_end) outer_breaks.push_back(phi);
  }
  const QuadValue v = KronrodWithRoots(inner, 0.0, phi_end, std::move(outer_breaks), phi_roots, o.abs_tolerance / factor,
                                      o.rel_tolerance, o.max_subdivisions, outer_spent);
  out.value = v.value * factor;
  out.error = v.error * factor;
  out.evals = evals;
  return out;
}

Estimate Sum(const Estimate& a, const Estimate& b) {
  Estimate e;
  e.value = a.value + b.value;
  e.error = a.error + b.error;
  e.evals = a.evals + b.evals;
  e.seconds = a.seconds + b.seconds;
  return e;
}

}  // namespace

Estimate ScatteredEstimate::Total() const { return Sum(reflected, transmitted); }

ScatteredEstimate ScatteredPower(const Bxdf<double>& bxdf, const double* params, const Vector3d& w_in,
                                 const IntegrateOptions& options, ScatteredParts parts) {
  if (!(w_in.norm() > 0) || !w_in.allFinite())
    throw std::invalid_argument("ScatteredPower: w must be a finite non-zero direction");
  const Vector3d w = w_in.normalized();
  ScatteredEstimate out;
  if (w.z() == 0) return out;  // f = 0 on the horizon
  const bool below = w.z() < 0;
  const Vector3d w_up(w.x(), w.y(), std::abs(w.z()));
  // v on the other side of the surface for u in the upper hemisphere.
  const auto other = [below](const Vector3d& u) { return Vector3d(u.x(), u.y(), below ? u.z() : -u.z()); };
  // Snell: n_w sin(theta_w) = n_v sin(theta_v), RelativeIndex(w, v) = n_w / n_v.
  const bool transmits = bxdf.Kind() & LobeKind::kTransmission;
  const double k = transmits ? bxdf.RelativeIndex(params, w, other(Vector3d::UnitZ())) : 1.0;
  // The onset of total internal reflection, w.m = sqrt(1 - 1 / k^2): past it
  // facets reflect all, and F reaches 1 (1 - F falls to 0) like a square
  // root. A kink of both the reflected and the refracted integrand.
  IntegrateOptions ko = options;
  if (k > 1) ko.facet_kinks.push_back(std::sqrt(1 - 1 / (k * k)));
  if (parts != ScatteredParts::kTransmitted) {
    IntegrateOptions ro = ko;
    ro.shape.reset();  // the view's lobe facts, not the model's
    out.reflected = DirectionalAlbedo(LightSideView(bxdf, below), params, w_up, Method::kAdaptive, ro);
  }
  if (!transmits || parts == ScatteredParts::kReflected) return out;
  const LobeWidth lobe = bxdf.Width(params);
  // Near k = 1 the map m -> t collapses (every m refracts w straight on, the
  // Jacobian vanishes and f_r is a delta): the generic rule about the refracted peak takes over.
  if (lobe.Any() && std::abs(k - 1) > 1e-6) {
    const auto t0 = std::chrono::steady_clock::now();
    const AdaptiveResult r =
        AdaptiveRefracted(bxdf, params, w, k, options.shape ? *options.shape : EstimateLobeShape(bxdf, params), ko);
    out.transmitted.value = r.value;
    out.transmitted.error = r.error;
    out.transmitted.evals = r.evals;
    out.transmitted.seconds = Seconds(t0);
    return out;
  }
  const auto g = [&](const Vector3d& u) -> Array3d { return bxdf.Eval(params, w, other(u)) * u.z(); };
  const double s2 = k * k * (1 - w.z() * w.z());
  Vector3d peak = Vector3d::Zero();
  if (s2 < 1) peak = Vector3d(-k * w.x(), -k * w.y(), std::sqrt(1 - s2));
  out.transmitted =
      IntegrateHemisphere(g, Method::kAdaptive, options, peak, lobe.Any() ? std::min(1.0, lobe.Min()) : 0.0);
  return out;
}

}  // namespace brdfkit::validate
