// Residual metrics and robust losses: the samples a fit uses, their
// targets and weights, and the RMSE and relative errors of a solution.
#include <tbb/blocked_range.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <iterator>
#include <span>
#include <stdexcept>
#include <utility>

#include "fit/fit_internal.h"

#if BRDFKIT_HAVE_LIBMVEC
#include <immintrin.h>
// glibc's vector variants of log1p (libmvec, the x86-64 vector function ABI;
// declared with their instruction sets, which clang requires of __m512d arguments).
extern "C" __attribute__((target("avx512f"))) __m512d _ZGVeN8v_log1p(__m512d);
extern "C" __attribute__((target("avx2"))) __m256d _ZGVdN4v_log1p(__m256d);
#endif

namespace brdfkit::fit {

#if BRDFKIT_HAVE_LIBMVEC
namespace {
// In place over n values; returns how many it did (a multiple of the width).
[[gnu::target("avx512f,avx512vl,avx512dq,avx2,fma")]] std::size_t Log1pAvx512(double* v, std::size_t n) {
  std::size_t k = 0;
  for (; k + 8 <= n; k += 8) _mm512_storeu_pd(v + k, _ZGVeN8v_log1p(_mm512_loadu_pd(v + k)));
  return k;
}
[[gnu::target("avx2,fma")]] std::size_t Log1pAvx2(double* v, std::size_t n) {
  std::size_t k = 0;
  for (; k + 4 <= n; k += 4) _mm256_storeu_pd(v + k, _ZGVdN4v_log1p(_mm256_loadu_pd(v + k)));
  return k;
}
}  // namespace
#endif

void Log1pRows(const double* wi, std::size_t stride, const double* f, std::size_t n, double* out) {
  for (std::size_t k = 0; k < n; ++k)
    for (int ch = 0; ch < 3; ++ch) out[3 * k + ch] = f[3 * k + ch] * wi[k * stride + 2];
  std::size_t done = 0;
#if BRDFKIT_HAVE_LIBMVEC
  switch (ActiveBatchIsa()) {
    case BatchIsa::kAvx512: done = Log1pAvx512(out, 3 * n); break;
    case BatchIsa::kAvx2: done = Log1pAvx2(out, 3 * n); break;
    case BatchIsa::kBaseline: break;
  }
#endif
  for (std::size_t k = done; k < 3 * n; ++k) out[k] = std::log1p(out[k]);
}

const std::vector<Metric>& AllMetrics() {
  static const std::vector<Metric> kAll = {Metric::kL2, Metric::kRelative, Metric::kCosine, Metric::kLog,
                                           Metric::kCbrt};
  return kAll;
}

Metric ParseMetric(const std::string& name) {
  for (Metric m : AllMetrics())
    if (name == MetricName(m)) return m;
  throw std::invalid_argument("unknown metric '" + name + "' (expected " + Expected(AllMetrics(), MetricName) + ")");
}

std::string MetricName(Metric m) {
  switch (m) {
    case Metric::kL2: return "l2";
    case Metric::kRelative: return "relative";
    case Metric::kCosine: return "cosine";
    case Metric::kLog: return "log";
    case Metric::kCbrt: return "cbrt";
  }
  return "?";
}

const std::vector<Loss>& AllLosses() {
  static const std::vector<Loss> kAll = {Loss::kNone, Loss::kHuber, Loss::kCauchy};
  return kAll;
}

std::string LossName(Loss l) {
  switch (l) {
    case Loss::kNone: return "none";
    case Loss::kHuber: return "huber";
    case Loss::kCauchy: return "cauchy";
  }
  return "?";
}

Loss ParseLoss(const std::string& name) {
  for (Loss l : AllLosses())
    if (name == LossName(l)) return l;
  throw std::invalid_argument("unknown loss '" + name + "' (expected " + Expected(AllLosses(), LossName) + ")");
}

namespace {

// dG/df at f, for propagating sigma.
double MetricSlope(Metric m, double f, double cos_i) {
  switch (m) {
    case Metric::kLog: return cos_i / (1.0 + f * cos_i);
    case Metric::kCbrt: {
      const double x = std::max(f * cos_i, kCbrtKnee);
      const double c = std::cbrt(x);
      return cos_i / (3 * c * c);
    }
    default: return 1.0;
  }
}

double MaxThetaRad(const Options& o) {
  const double deg = o.max_theta_deg > 0 ? o.max_theta_deg : (o.metric == Metric::kCosine ? 80.0 : 90.0);
  return deg * kPi / 180.0;
}

}  // namespace

Selection Select(const Dataset& data, const Options& o) {
  Selection s;
  const double cos_max = std::cos(MaxThetaRad(o));
  s.index.reserve(data.samples.size());
  // 1e-12 of slack keeps samples written at exactly the cut.
  for (std::size_t k = 0; k < data.samples.size(); ++k) {
    const Sample& x = data.samples[k];
    if (x.wi.z() < cos_max - 1e-12 || x.wo.z() < cos_max - 1e-12 || !(x.wi.z() > 0 && x.wo.z() > 0)) {
      ++s.dropped_angle;
      continue;
    }
    s.index.push_back(k);
  }
  return s;
}

Prepared Prepare(const Dataset& data, std::vector<std::size_t> index, const Options& o) {
  Prepared p;
  const std::size_t n = index.size();
  const bool sigma = data.has_sigma && o.use_sigma;
  const bool unit_weights = !sigma && o.metric != Metric::kRelative && o.metric != Metric::kCosine;
  p.data = &data;
  p.index = std::move(index);
  // Unit to a few ulp (a direction from angles is): read as they are.
  const auto unit = [](const Eigen::Vector3d& w) { return std::abs(w.squaredNorm() - 1) <= 1e-14; };
  p.unit = std::all_of(p.index.begin(), p.index.end(),
                       [&](std::size_t k) { return unit(data.samples[k].wi) && unit(data.samples[k].wo); });
  p.consecutive = true;
  for (std::size_t q = 1; q < n && p.consecutive; ++q) p.consecutive = p.index[q] == p.index[0] + q;
  p.target.resize(n);
  if (!unit_weights) {
    p.w_fit.resize(n);
  }
  if (sigma) {
    p.w_metric.resize(n);
  }
  // Relative metric: a floor keeps near-zero reference values from
  // dominating (and from dividing by zero).
  Eigen::Array3d floor = Eigen::Array3d::Zero();
  if (o.metric == Metric::kRelative) {
    Eigen::Array3d mean = Eigen::Array3d::Zero();
    for (std::size_t k : p.index) mean += data.samples[k].f.abs();
    mean /= std::max<std::size_t>(n, 1);
    floor = (1e-3 * mean).max(1e-300);
  }
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t q = r.begin(); q < r.end(); ++q) {
      const Sample& s = data.samples[p.index[q]];
      const double c = p.Wi(q).z();
      for (int ch = 0; ch < 3; ++ch) {
        const double g = s.f[ch];
        p.target[q][ch] = MetricTransform(o.metric, g, c);
        double w = 1;
        if (o.metric == Metric::kRelative) w = 1.0 / std::max(std::abs(g), floor[ch]);
        if (o.metric == Metric::kCosine) w = c;
        if (sigma) p.w_metric[q][ch] = w;
        // Standard deviation of the metric residual, to first order in sigma.
        if (!unit_weights) p.w_fit[q][ch] = sigma ? 1.0 / (std::abs(MetricSlope(o.metric, g, c)) * s.sigma[ch]) : w;
      }
    }
  });
  return p;
}

Prepared Rows(const Prepared& p, const std::vector<std::size_t>& rows) {
  Prepared out;
  auto own = std::make_shared<Dataset>();
  own->has_sigma = p.data->has_sigma;
  own->source = p.data->source;
  own->samples.reserve(rows.size());
  out.unit = p.unit;
  out.consecutive = true;  // its own rows, in order
  out.index.reserve(rows.size());
  out.target.reserve(rows.size());
  if (!p.w_fit.empty()) out.w_fit.reserve(rows.size());
  if (!p.w_metric.empty()) out.w_metric.reserve(rows.size());
  for (std::size_t q : rows) {
    out.index.push_back(own->samples.size());
    own->samples.push_back(p.Row(q));
    out.target.push_back(p.target[q]);
    if (!p.w_fit.empty()) out.w_fit.push_back(p.w_fit[q]);
    if (!p.w_metric.empty()) out.w_metric.push_back(p.w_metric[q]);
  }
  out.data = own.get();
  out.rows = std::move(own);
  return out;
}

// Cost (half the sum of squared residuals) of internal parameters u over d;
// infinite where a residual is not finite.
double CostOf(const Engine& e, const Prepared& d, const std::vector<double>& u) {
  constexpr std::size_t chunk = 256;
  return ChunkedSum(d.size(), chunk, 0.0, [&](std::size_t begin, std::size_t end) {
    double r[3 * chunk];
    // A non-finite residual makes the point unusable.
    if (!e.EvalDouble(u.data(), d, begin, end, true, r)) return std::numeric_limits<double>::infinity();
    double sum = 0;
    for (std::size_t k = 0; k < 3 * (end - begin); ++k) sum += 0.5 * r[k] * r[k];
    return sum;
  });
}

double RmseAt(const Engine& e, const Prepared& d, const std::vector<double>& u, double cost, bool weights_are_metric) {
  return weights_are_metric ? std::sqrt(2 * cost / (3.0 * d.size())) : Rmse(e, d, u);
}

// Root mean square of the plain metric residuals.
double Rmse(const Engine& e, const Prepared& d, const std::vector<double>& u) {
  if (d.size() == 0) return 0;
  constexpr std::size_t chunk = 256;
  const double sum = ChunkedSum(d.size(), chunk, 0.0, [&](std::size_t begin, std::size_t end) {
    double s = 0;
    for (std::size_t b = begin; b < end; b += chunk) {
      // Plain double evaluation of the metric residuals, a chunk at a time.
      double r[3 * chunk];
      const std::size_t e_end = std::min(end, b + chunk);
      e.EvalDouble(u.data(), d, b, e_end, false, r);
      for (std::size_t k = 0; k < 3 * (e_end - b); ++k) s += r[k] * r[k];
    }
    return s;
  });
  return std::sqrt(sum / (3.0 * d.size()));
}

namespace {

// Quantile q, linear between order statistics (position q (n - 1), the
// usual sample quantile), found by selection in linear time; v is
// reordered. `from`, at most that position, says that every element before
// it is at most every element from it on (a lower quantile's selection), so
// the selection runs in the part above it only.
double Quantile(std::span<double> v, double q, std::size_t from = 0) {
  const double pos = q * double(v.size() - 1);
  const std::size_t i = static_cast<std::size_t>(pos);
  const auto at = v.begin() + static_cast<std::ptrdiff_t>(i);
  std::nth_element(v.begin() + static_cast<std::ptrdiff_t>(from), at, v.end());
  if (i + 1 >= v.size()) return *at;
  const double next = *std::min_element(at + 1, v.end());
  return *at + (pos - double(i)) * (next - *at);
}

// The statistics of v (reordered).
ErrorStats StatsOf(std::span<double> v) {
  ErrorStats s;
  s.count = v.size();
  if (v.empty()) return s;
  s.max = *std::max_element(v.begin(), v.end());
  s.median = Quantile(v, 0.5);
  s.p95 = Quantile(v, 0.95, static_cast<std::size_t>(0.5 * double(v.size() - 1)));
  return s;
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  const std::size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid), v.end());
  return v[mid];
}

}  // namespace

// Relative errors of the fitted model (user parameters p) against the data,
// over all samples and by theta_h band (Result::relative_error).
void RelativeErrors(const Engine& e, const Prepared& d, const std::vector<double>& p, Result& res) {
  const std::size_t n = d.size();
  Eigen::Array3d mean = Eigen::Array3d::Zero();
  for (std::size_t q = 0; q < n; ++q) mean += d.Reference(q).abs();
  // The floor keeps reference values near zero from dominating (as the relative metric).
  const Eigen::Array3d floor = (1e-3 * mean / double(std::max<std::size_t>(n, 1))).max(1e-300);
  constexpr std::size_t kBands = std::size(kThetaHBandEdgesDeg) - 1;
  // Each sample's theta_h band, counted block by block; then its three
  // errors, written grouped by band (26 MB for a MERL table, in one buffer):
  // a block's samples of band b go after those of band b in earlier blocks.
  static_assert(kBands <= 256, "a band number fits a byte");
  constexpr std::size_t kBlock = 4096;
  const std::size_t blocks = (n + kBlock - 1) / kBlock;
  std::vector<std::uint8_t> band(n);
  std::vector<std::array<std::size_t, kBands>> at(blocks);
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t k) {
    at[k].fill(0);
    for (std::size_t q = k * kBlock; q < std::min(n, (k + 1) * kBlock); ++q) {
      const Eigen::Vector3d h = (d.Wi(q) + d.Wo(q)).normalized();
      const double theta_h = std::acos(std::clamp(h.z(), -1.0, 1.0)) * 180 / kPi;
      std::size_t b = 0;
      while (b + 1 < kBands && theta_h >= kThetaHBandEdgesDeg[b + 1]) ++b;
      band[q] = std::uint8_t(b);
      ++at[k][b];
    }
  });
  std::array<std::size_t, kBands + 1> first{};
  std::size_t next = 0;
  for (std::size_t b = 0; b < kBands; ++b) {
    first[b] = next;
    for (std::size_t k = 0; k < blocks; ++k) next += std::exchange(at[k][b], next);
  }
  first[kBands] = next;
  std::vector<double> grouped;
  grouped.resize(3 * n);
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t k) {
    const std::size_t begin = k * kBlock, end = std::min(n, begin + kBlock);
    std::vector<double> pred(3 * (end - begin));
    e.PredictRange(p, d, begin, end, pred.data());
    for (std::size_t q = begin; q < end; ++q) {
      double* out = grouped.data() + 3 * at[k][band[q]]++;
      for (int c = 0; c < 3; ++c) {
        const double g = d.Reference(q)[c];
        out[c] = std::abs(pred[3 * (q - begin) + std::size_t(c)] - g) / std::max(std::abs(g), floor[c]);
      }
    }
  });
  // The bands' selections reorder only within their bands, so the overall
  // statistics follow over the same buffer.
  std::array<ErrorStats, kBands> stats;
  tbb::parallel_for(std::size_t{0}, kBands, [&](std::size_t b) {
    stats[b] = StatsOf(std::span<double>(grouped).subspan(3 * first[b], 3 * (first[b + 1] - first[b])));
  });
  res.relative_error_bands.clear();
  for (std::size_t b = 0; b < kBands; ++b)
    if (first[b + 1] > first[b])
      res.relative_error_bands.push_back({kThetaHBandEdgesDeg[b], kThetaHBandEdgesDeg[b + 1], stats[b]});
  res.relative_error = StatsOf(grouped);
}

double LossScale(const FitState& s, const std::vector<double>& u) {
  double loss_scale = s.o.loss_scale;
  if (s.o.loss == Loss::kNone || loss_scale > 0) return loss_scale;
  if (s.sigma) return 3.0;
  std::vector<double> abs_r;
  abs_r.reserve(3 * s.full.size());
  double r[3];
  for (std::size_t q = 0; q < s.full.size(); ++q) {
    s.plain.EvalDouble(u.data(), s.full, q, q + 1, true, r);
    for (double x : r) abs_r.push_back(std::abs(x));
  }
  // 1.4826 MAD estimates a normal standard deviation; a zero MAD
  // (noiseless data) falls back to the RMS so the scale stays positive.
  loss_scale = 3.0 * 1.4826 * Median(abs_r);
  if (!(loss_scale > 0)) {
    double sum = 0;
    for (double x : abs_r) sum += x * x;
    loss_scale = std::max(3.0 * std::sqrt(sum / std::max<std::size_t>(abs_r.size(), 1)), 1e-300);
  }
  return loss_scale;
}

double MetricRmse(const Model& model, const std::vector<double>& params, const Dataset& data,
                  const Options& options) {
  Selection sel = Select(data, options);
  const Prepared d = Prepare(data, std::move(sel.index), options);
  const Engine e(ModelEvaluators(model), options, 1.0, AllFree(model.Info()));
  tbb::task_arena arena(std::clamp(options.num_threads, 1, std::max(1, tbb::info::default_concurrency())));
  return arena.execute([&] { return Rmse(e, d, e.ToInternal(params)); });
}

}  // namespace brdfkit::fit
