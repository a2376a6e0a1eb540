// The fitter's parts, shared by its source files (not installed):
//   data.cpp         datasets from tables and files
//   metrics.cpp      the samples a fit uses, metric residuals, robust losses,
//                    RMSE and relative errors
//   engine.cpp       residuals and Jacobians of a model (Engine)
//   constraints.cpp  fixed, tied and bounded parameters (Layout)
//   solve.cpp        the Ceres problem and solver settings
//   starts.cpp       starting points: multi-start and nested sub-sums
//   uncertainty.cpp  covariance and identifiability
//   fit.cpp          Fit: the steps in order
#pragma once

#include <ceres/ceres.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <type_traits>
#include <vector>

#include "brdf/batch.h"
#include "data_synth/forward_model.h"
#include "fit/fit.h"
#include "fit/jet_models.h"

namespace brdfkit::fit {

// "a, b, c or d" of every name of an enumeration.
template <typename E, typename NameOf>
std::string Expected(const std::vector<E>& all, NameOf name_of) {
  std::string s;
  for (std::size_t i = 0; i < all.size(); ++i)
    s += (i == 0 ? "" : i + 1 == all.size() ? " or " : ", ") + name_of(all[i]);
  return s;
}

// ---------------------------------------------------------------------------
// Samples and metrics (metrics.cpp).

// Samples prepared for one metric: rows of a dataset, which must outlive
// it (its directions and values are read there, not copied), and for each
// row the metric's target and weights.
struct Prepared {
  const Dataset* data = nullptr;
  std::vector<std::size_t> index;        // rows of data->samples
  std::vector<Eigen::Array3d> target;    // G(reference)
  // Weights of the fitted residuals; empty: every weight is 1 (no sigma and
  // a metric of unit weights), which spares a sample 24 bytes and a product.
  std::vector<Eigen::Array3d> w_fit;
  std::vector<Eigen::Array3d> w_metric;  // weights of the metric (no sigma); empty: those of w_fit
  // Every direction of the rows has unit length to rounding (the readers'
  // do); else each is normalised where it is read.
  bool unit = true;
  // index is first, first + 1, ...: a range's rows lie one after another in
  // data->samples, and batch evaluations read their directions in place.
  bool consecutive = false;
  // A subset's own copy of its rows (data then points at it): its passes
  // read them one after another, not scattered over the whole table.
  std::shared_ptr<const Dataset> rows;
  std::size_t size() const { return index.size(); }
  const Sample& Row(std::size_t q) const { return data->samples[index[q]]; }
  Eigen::Vector3d Wi(std::size_t q) const { return unit ? Row(q).wi : Row(q).wi.normalized(); }
  Eigen::Vector3d Wo(std::size_t q) const { return unit ? Row(q).wo : Row(q).wo.normalized(); }
  const Eigen::Array3d& Reference(std::size_t q) const { return Row(q).f; }  // the data's f_r
  Eigen::Array3d WFit(std::size_t q) const { return w_fit.empty() ? Eigen::Array3d::Ones() : w_fit[q]; }
  Eigen::Array3d WMetric(std::size_t q) const { return w_metric.empty() ? WFit(q) : w_metric[q]; }
};

struct Selection {
  std::vector<std::size_t> index;  // samples used
  std::size_t dropped_angle = 0;
};

// The samples within the options' angle cut.
Selection Select(const Dataset& data, const Options& o);
Prepared Prepare(const Dataset& data, std::vector<std::size_t> index, const Options& o);
// The rows of p at positions `rows`, with p's targets and weights.
Prepared Rows(const Prepared& p, const std::vector<std::size_t>& rows);

// Below this, cbrt is continued by its tangent: the derivative of cbrt is
// infinite at 0 and Jets must stay finite.
constexpr double kCbrtKnee = 1e-12;

// cbrt(x) for x in [1e-300, 1e300], without branches: the exponent divided
// by 3 in the bits (through a double, which GCC vectorises where it does not
// a 64-bit integer division) gives a start within 10 %, two Halley steps
// (cubic convergence) and a Newton step reach the rounding level (within 4
// ulp of std::cbrt over 1e-12 to 1e300, 0.55 ulp on average), 2.5x faster
// than std::cbrt, which calls out of line for frexp and scalbn (a quarter
// of a cbrt-metric fit's time went there).
[[gnu::always_inline]] inline double CbrtSteps(double x) {
  const double bits = double(std::bit_cast<std::int64_t>(x));
  double y = std::bit_cast<double>(std::int64_t(bits * (1.0 / 3)) + 0x2a9f7893782da1ceLL);
  for (int k = 0; k < 2; ++k) {
    const double y3 = y * y * y;
    y *= (y3 + 2 * x) / (2 * y3 + x);
  }
  const double y2 = y * y;
  return y - (y2 * y - x) / (3 * y2);
}

// cbrt(x) for x > 0; outside 1e-300 to 1e300 (y^3 could overflow) std::cbrt.
inline double CbrtPositive(double x) {
  if (!(x >= 1e-300 && x <= 1e300)) return std::cbrt(x);
  return CbrtSteps(x);
}

// cbrt at the knee, and the cube root's tangent there, which continues it below.
inline const double kCbrtKneeRoot = std::cbrt(kCbrtKnee);
template <class T>
T CbrtTangent(const T& x) {
  return T(kCbrtKneeRoot) + (x - T(kCbrtKnee)) / T(3 * kCbrtKneeRoot * kCbrtKneeRoot);
}

template <class T>
T CbrtSafe(const T& x) {
  if (x < T(kCbrtKnee)) return CbrtTangent(x);
  if constexpr (std::is_same_v<T, double>) {
    return CbrtPositive(x);
  } else {
    // d cbrt(a) = da / (3 cbrt(a)^2).
    const double y = CbrtPositive(x.a);
    return T(y, x.v / (3 * y * y));
  }
}

// CbrtSafe(f cos_i) for rows of samples, as a kernel of RunBatchKernel
// (brdf/batch.h): wi's row gives cos_i (wi[2]), wo's row three values f,
// out their transforms. Branch-free, so GCC vectorises it: CbrtSteps on x
// within [knee, 1e300]; beyond 1e300 (y^3 could overflow there) on x 2^-300,
// the root scaled back by 2^100 (exact); infinity kept; the tangent
// selected below the knee; a NaN stays NaN.
struct CbrtKernel {
  [[gnu::always_inline]] void operator()(const double* wi, const double* f, double* out) const {
    using brdfkit::Select;
    for (int ch = 0; ch < 3; ++ch) {
      const double x = f[ch] * wi[2];
      const bool big = x > 1e300;
      const double scaled = Select(big, x * 0x1p-300, x);
      const double low = Select(scaled < kCbrtKnee, kCbrtKnee, scaled);
      const double root = CbrtSteps(Select(low > 1e300, 1e300, low));  // only infinity is clamped here
      const double y = Select(x == std::numeric_limits<double>::infinity(), x, Select(big, root * 0x1p100, root));
      out[ch] = Select(x < kCbrtKnee, CbrtTangent(x), y);
    }
  }
};

// CbrtSafe(f[3 k + ch] cos_i) of n rows into out[3 k + ch], cos_i of row k
// at wi[k * stride + 2] (stride 0: one row for all).
inline void CbrtRows(const double* wi, std::size_t stride, const double* f, std::size_t n, double* out) {
  RunBatchKernel(CbrtKernel{}, wi, stride, f, 3, n, out);
}

// log1p(f[3 k + ch] cos_i) of n rows into out[3 k + ch], cos_i of row k at
// wi[k * stride + 2] (stride 0: one row for all): std::log1p's values
// through glibc's vector math library (libmvec: 8 or 4 values a call, to 4
// ulp, on the instruction set of brdf/batch.h in use) where the build found
// it, else std::log1p value by value.
void Log1pRows(const double* wi, std::size_t stride, const double* f, std::size_t n, double* out);

// The metric's transform G of a value v = f (l2, relative, cosine) or v = f cos_i.
template <class T>
T MetricTransform(Metric m, const T& f, double cos_i) {
  using std::log1p;
  switch (m) {
    case Metric::kLog: return log1p(f * T(cos_i));
    case Metric::kCbrt: return CbrtSafe(T(f * T(cos_i)));
    default: return f;
  }
}

// Robust loss applied per residual as r -> sign(r) sqrt(rho(r^2)), so that
// the sum of squares is sum rho(r^2) while residuals stay grouped in blocks
// (a Ceres LossFunction would act on a whole block's squared norm).
template <class T>
T Robust(Loss loss, double a, const T& r) {
  using std::abs;
  using std::log1p;
  using std::sqrt;
  if (loss == Loss::kNone) return r;
  const T ar = abs(r);
  if (loss == Loss::kHuber) {
    if (ar <= T(a)) return r;
    const T v = sqrt(T(2 * a) * ar - T(a * a));
    return r < T(0) ? T(-v) : v;
  }
  // Cauchy: rho(s) = a^2 log(1 + s / a^2). Near 0 it is r itself to
  // O(r^3), and the sqrt's derivative would be infinite at r = 0.
  if (ar < T(1e-6 * a)) return r;
  const T v = T(a) * sqrt(log1p(r * r / T(a * a)));
  return r < T(0) ? T(-v) : v;
}

// ---------------------------------------------------------------------------
// Fixed, tied and bounded parameters (constraints.cpp).

// Which packed parameters the optimiser moves. Packed slot k is free slot
// free_of[k] (tied slots share their leader's) or held at value[k]; the
// free slots' bounds (user space) are the intersection of the bounds of the
// packed slots they feed.
struct Layout {
  std::vector<int> free_of;           // packed -> free slot, -1: fixed
  std::vector<double> value;          // packed: the value of a fixed slot
  std::vector<int> leader;            // packed -> packed slot it follows (tie), -1
  std::vector<double> lo, hi;         // packed bounds, user space
  std::vector<std::size_t> rep;       // free -> first packed slot it feeds
  std::size_t Free() const { return rep.size(); }
  // Numbers the free slots in packed order.
  void Renumber();
};

Layout AllFree(const ModelInfo& info);
// Options::fix, tie and bounds applied to the model's table; throws
// std::invalid_argument as CheckConstraints.
Layout MakeLayout(const ModelInfo& info, const Options& o);

// ---------------------------------------------------------------------------
// Residuals of a model (engine.cpp).

class Engine {
 public:
  Engine(const Evaluators& model, const Options& o, double loss_scale, const Layout& layout);

  std::size_t n() const { return nf_; }  // free parameters
  std::size_t packed() const { return n_; }
  int jet() const { return jet_; }
  const std::vector<bool>& log_mask() const { return log_; }
  const Layout& layout() const { return layout_; }

  // Internal (optimised, free) -> user parameters (packed).
  std::vector<double> ToUser(const std::vector<double>& u) const;
  std::vector<double> ToInternal(const std::vector<double>& p) const;

  // The model's value for sample q at user parameters p: f_r, or f_r
  // through the instrument's apertures.
  Eigen::Array3d Predict(const std::vector<double>& p, const Prepared& d, std::size_t q) const;
  // The model's values (user parameters p) of samples [begin, end) into out[3 (q - begin) + c].
  void PredictRange(const std::vector<double>& p, const Prepared& d, std::size_t begin, std::size_t end,
                    double* out) const;

  // Residuals (3 per sample) over [begin, end), internal parameters u. fit:
  // fit weights and robust loss; else the plain metric.
  bool EvalDouble(const double* u, const Prepared& d, std::size_t begin, std::size_t end, bool fit,
                  double* r) const;

  // Residuals and their Jacobian (row-major, 3 (end - begin) x free parameters).
  bool EvalJacobian(const double* u, const Prepared& d, std::size_t begin, std::size_t end, double* r,
                    double* jac) const;

  // Adds J^T J (n x n), J^T r and |r|^2 of the residuals over [begin, end)
  // to jtj, jtr and rr, formed per channel in the Jet's derivative slots
  // without writing the Jacobian out; false where a residual or a sum is
  // not finite.
  bool NormalOfRange(const double* u, const Prepared& d, std::size_t begin, std::size_t end, Eigen::MatrixXd& jtj,
                     Eigen::VectorXd& jtr, double& rr) const;

 private:
  template <class T>
  void ToUser(const T* u, T* p) const;
  template <class T>
  void SampleResiduals(const Bxdf<T>& b, const T* p, const Prepared& d, std::size_t q, bool fit, T* out) const;
  template <class T>
  void ResidualsOf(const Rgb<T>& f, const Prepared& d, std::size_t q, double cos_i, bool fit, T* out) const;
  // The same from g = G(f), the metric's transform already applied.
  template <class T>
  void ResidualsOfTransformed(const Rgb<T>& g, const Prepared& d, std::size_t q, bool fit, T* out) const;
  // ResidualsOfTransformed for samples [begin, end) at once, in place: r
  // holds G(f) of the range (3 per sample) and receives the residuals.
  void ResidualsOfRange(const Prepared& d, std::size_t begin, std::size_t end, bool fit, double* r) const;
  template <class T>
  Rgb<T> Prediction(const Bxdf<T>& b, const T* p, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) const;
  // The residuals over [begin, end) on Jets, each handed to
  // sink(row, channel, residual) (row: q - begin), which returns false to stop.
  template <int N, class Sink>
  bool EvalJet(const Bxdf<Jet<N>>& b, const double* u, const Prepared& d, std::size_t begin, std::size_t end,
               Sink&& sink) const;
  // Whether free parameter j acts on channel c: a scalar, or a colour
  // parameter's c entry (its shared slot carries channel c's derivative).
  bool Acts(std::size_t j, int c) const { return channel_[j] < 0 || channel_[j] == c; }
  template <int N>
  bool JacobianOfRange(const Bxdf<Jet<N>>& b, const double* u, const Prepared& d, std::size_t begin,
                       std::size_t end, double* r, double* jac) const;
  template <int N>
  bool NormalOfRange(const Bxdf<Jet<N>>& b, const double* u, const Prepared& d, std::size_t begin, std::size_t end,
                     Eigen::MatrixXd& jtj, Eigen::VectorXd& jtr, double& rr) const;
  // A lobe of a sum differentiated on a Jet of its own derivative slots: a
  // lobe depends on a few of the sum's parameters, and a Jet of all of them
  // carries zeros through every operation of every lobe.
  struct LobeJet {
    std::size_t offset = 0, size = 0;  // the lobe's packed parameters
    std::ptrdiff_t weight = -1;        // packed index of its weight in the sum, or -1
    std::vector<std::size_t> lanes;    // the sum's derivative slot of each of the lobe's own
    int jet = 4;
    std::unique_ptr<Bxdf<Jet<4>>> b4;
    std::unique_ptr<Bxdf<Jet<8>>> b8;
    std::unique_ptr<Bxdf<Jet<16>>> b16;
    std::unique_ptr<Bxdf<Jet<32>>> b32;
  };
  // The parameters of every lobe on its own Jets, from the sum's (pj).
  struct LobeParams {
    std::vector<Jet<4>> p4;
    std::vector<Jet<8>> p8;
    std::vector<Jet<16>> p16;
    std::vector<Jet<32>> p32;
    std::vector<std::size_t> base;  // of each lobe, in the vector of its Jet size
  };
  template <int N>
  LobeParams ToLobes(const Jet<N>* pj) const;
  // f_r of the sum at user parameters pj, lobe by lobe.
  template <int N>
  Rgb<Jet<N>> SumOfLobes(const LobeParams& lp, const Jet<N>* pj, const Eigen::Vector3d& wi,
                         const Eigen::Vector3d& wo) const;

  Metric metric_;
  Loss loss_;
  double loss_scale_;
  Layout layout_;
  std::size_t n_ = 0;   // packed parameters
  std::size_t nf_ = 0;  // free parameters
  std::vector<std::size_t> slot_;  // derivative slot of each free parameter
  std::vector<int> channel_;       // its channel when the slot is shared by r, g, b; else -1
  std::size_t n_slots_ = 0;
  int jet_ = 8;
  std::vector<bool> log_;
  std::unique_ptr<Bxdf<double>> b_;
  std::unique_ptr<Bxdf<Jet<4>>> b4_;
  std::unique_ptr<Bxdf<Jet<8>>> b8_;
  std::unique_ptr<Bxdf<Jet<16>>> b16_;
  std::unique_ptr<Bxdf<Jet<32>>> b32_;
  std::vector<LobeJet> lobes_;  // a sum whose lobes need smaller Jets than the sum; else empty
  std::unique_ptr<synth::ApertureQuadrature> quad_;  // a fixed aperture order
  std::unique_ptr<synth::ApertureLadder> ladder_;    // the automatic order: per-pair rules (MeasureAdaptive)
  double tolerance_ = 0;                              // of the automatic order
};

// ---------------------------------------------------------------------------
// One fit (fit.cpp).

// Everything a fit's steps share: the options, the samples used, the
// constraints, the engine without a robust loss, and the result so far.
struct FitState {
  const Evaluators& model;
  const Dataset& data;
  const Options& o;
  const Prepared& full;
  const Layout& layout;
  const Engine& plain;
  bool sigma = false;
  std::size_t chunk = 1;
  std::function<double()> elapsed;  // seconds since the start of Fit
  Result& res;
};

// ---------------------------------------------------------------------------
// Sums over the samples (metrics.cpp).

// The sum of part(begin, end) over [0, n) cut into chunks of at most
// `grain`, on the TBB pool (the caller's arena sets the thread count); the
// chunks and the order of their sums do not depend on the thread count.
template <typename T, typename F>
T ChunkedSum(std::size_t n, std::size_t grain, T zero, F&& part) {
  return tbb::parallel_deterministic_reduce(
      tbb::blocked_range<std::size_t>(0, n, std::max<std::size_t>(1, grain)), zero,
      [&](const tbb::blocked_range<std::size_t>& r, T acc) { return T(acc + part(r.begin(), r.end())); },
      [](const T& a, const T& b) { return T(a + b); });
}

// Root mean square of the plain metric residuals.
double Rmse(const Engine& e, const Prepared& d, const std::vector<double>& u);
// The same at internal parameters u whose cost over d is `cost`: where the
// fit's weights are the metric's (no sigma, no robust loss) that cost is
// the metric's sum of squares / 2 and no pass over the samples is needed.
double RmseAt(const Engine& e, const Prepared& d, const std::vector<double>& u, double cost, bool weights_are_metric);
// Cost (half the sum of squared fit residuals) of internal parameters u
// over d; infinite where a residual is not finite.
double CostOf(const Engine& e, const Prepared& d, const std::vector<double>& u);
// Relative errors of the fitted model (user parameters p) against the data,
// over all samples and by theta_h band (Result::relative_error).
void RelativeErrors(const Engine& e, const Prepared& d, const std::vector<double>& p, Result& res);

// The robust loss's scale: Options::loss_scale, or when that leaves it to
// the fit, from the data's sigma or the residuals at internal parameters u.
double LossScale(const FitState& s, const std::vector<double>& u);

// ---------------------------------------------------------------------------
// The Ceres problem (solve.cpp).

// Bounds of the internal (free) parameters: the intersection of the bounds
// of the packed slots each one feeds.
void Bounds(const Layout& layout, const std::vector<bool>& log_mask, std::vector<double>& lo,
            std::vector<double>& hi);

// Calls f at every iteration; with `stop`, ends the solve (successfully)
// once stop returns true.
class TraceCallback final : public ceres::IterationCallback {
 public:
  TraceCallback(std::function<void(const ceres::IterationSummary&)> f,
                std::function<bool(const ceres::IterationSummary&)> stop = nullptr)
      : f_(std::move(f)), stop_(std::move(stop)) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& s) override {
    f_(s);
    return stop_ && stop_(s) ? ceres::SOLVER_TERMINATE_SUCCESSFULLY : ceres::SOLVER_CONTINUE;
  }

 private:
  std::function<void(const ceres::IterationSummary&)> f_;
  std::function<bool(const ceres::IterationSummary&)> stop_;
};

// J^T J and J^T r of each residual block where its Jacobian was last
// evaluated, and the parameters it was evaluated at (filled by the solver's
// threads, each block its own slot).
struct NormalCache {
  std::vector<Eigen::MatrixXd> jtj;
  std::vector<Eigen::VectorXd> jtr;
  std::vector<std::vector<double>> at;
  // J^T J and J^T r of the whole problem at the point where it was last evaluated.
  struct Normal {
    Eigen::MatrixXd jtj;
    std::vector<double> at;
    Eigen::VectorXd jtr;
  };
  // The sum over blocks, when every block was last evaluated at one point.
  std::optional<Normal> Last() const;
};

// The end of a Levenberg-Marquardt solve that converges linearly, as
// Gauss-Newton does where the residuals stay large (it leaves out
// S = sum r_k grad^2 r_k). From the last point (its J^T J, J^T r and cost)
// and the one before it (`previous`, its J^T r), steps solve
// (J^T J + A + lambda D) d = -J^T r, A the structured secant estimate of S
// (Dennis, Gay and Welsch 1981, "An adaptive nonlinear least-squares
// algorithm", NL2SOL, with its sizing), over the entries not held on a
// bound (one the gradient or the step presses against), projected onto the
// bounds and accepted when it lowers the cost; ends when a step lowers
// the cost by at most ftol of it. Each accepted step costs one Jacobian
// pass, a rejected one a cost pass; `accepted` is called with each new
// point's iteration, cost and parameters. Where the cost creeps (Creeps)
// and pause(u) says so, the phase ends there (`paused`).
//
// The cost creeps where, over the last kCreepSteps accepted steps, it fell
// by at most kCreep of it, and the last half of them lowered it by at least
// kCreepRatio times the first half: steps that no longer shrink, as along a
// flat valley (converging linearly, by 0.87 or more a step). Measured:
// hazy_red_dielectric under cbrt with three lobes, 190 steps of 1e-9 to
// 1.6e-6 each (bench/RESULTS.md). costs: at each accepted point.
constexpr int kCreepSteps = 10;
constexpr double kCreep = 1e-4, kCreepRatio = 0.5;
bool Creeps(const std::vector<double>& costs);
// Whether a solve pauses at parameters p (internal in SecantTail and
// SolveToEnd, user parameters in Start); empty: never.
using Pause = std::function<bool(const std::vector<double>& p)>;
struct Tail {
  std::vector<double> u;
  double cost = 0;
  NormalCache::Normal normal;  // J^T J and J^T r at u
  int iterations = 0, accepted = 0;
  bool converged = false, paused = false;
  double change = 0;  // the relative decrease of the cost at the last accepted step
};
Tail SecantTail(const Engine& e, const Prepared& d, std::size_t chunk, const NormalCache::Normal& last, double cost,
                const std::optional<NormalCache::Normal>& previous, double ftol, int max_iterations,
                const std::function<void(int, double, const std::vector<double>&)>& accepted,
                const Pause& pause = {});

// Ceres' solve (options so) over d from internal parameters u (updated in
// place) that hands over to SecantTail once its steps converge linearly:
// the last decrease of the cost below 1e-4 of it, and the last two ratios
// of successive decreases between 0.1 and 0.95. With `from` (J^T J and
// J^T r at u) the end phase runs alone. trace(iteration, cost, u) is called
// at every accepted point. The summary is Ceres', its cost, step counts,
// termination and message updated where the end phase ran; `normal` holds
// J^T J and J^T r at the solution, or at Ceres' last Jacobian.
//
// With a finite stop_above the solve ends early (`bounded`, without the end
// phase) at the first point whose cost less kGainBound times its
// Gauss-Newton gain lies above stop_above: from there the optimum cannot
// reach stop_above. With `pause` the end phase may end where the cost
// creeps (SecantTail; `paused`).
struct Solved {
  ceres::Solver::Summary summary;
  std::optional<NormalCache::Normal> normal;
  bool bounded = false, paused = false;
};
Solved SolveToEnd(const Engine& e, const Prepared& d, std::size_t chunk, std::vector<double>& u,
                  ceres::Solver::Options so, const NormalCache::Normal* from,
                  const std::function<void(int, double, const std::vector<double>&)>& trace,
                  double stop_above = std::numeric_limits<double>::infinity(),
                  const Pause& pause = {});

// The decrease of the cost that the Gauss-Newton model with normal matrix
// jtj and gradient g = J^T r promises, without bounds (which can only
// lower it): g^T (J^T J)^+ g / 2, on the Jacobi-scaled matrix; infinite
// where they are not finite.
double GaussNewtonGain(const Eigen::MatrixXd& jtj, const Eigen::VectorXd& g);
// The same at internal parameters u of engine e over the parameters that
// HoldingBounds would leave free: those on a bound are held there unless
// the gradient pulls them inward.
double GainWithinBounds(const Engine& e, const std::vector<double>& u, const Eigen::MatrixXd& jtj,
                        const Eigen::VectorXd& g);
// Gauss-Newton underestimates the decrease of a problem with large
// residuals: where its iterations converge linearly at rate rho the true
// quadratic model's decrease is up to 1 / (1 - rho) times its own (rho =
// 0.35-0.7 in the measured final solves); this multiple covers rho up to
// 0.95. A point whose cost less kGainBound times its gain lies above a
// level has its optimum above that level.
constexpr double kGainBound = 20;

// Builds the problem over `d` with internal parameters `u` (updated in
// place); with `cache`, the blocks record their normal matrices there.
void BuildProblem(ceres::Problem& problem, const Engine& e, const Prepared& d, std::size_t chunk,
                  std::vector<double>& u, NormalCache* cache = nullptr);
ceres::Solver::Options SolverOptions(const Options& o, LinearSolver solver, int max_iterations);

// ---------------------------------------------------------------------------
// Starting points (starts.cpp).

// The internal parameters u the final solve starts from: Options::initial,
// or the best local optimum of the start search (Result::starts, trace,
// local_optima and kept record it). For a sum on a large table,
// after_final(p, paused) is then called with the final solve's user
// parameters p and whether it paused (`pause`): it solves on all samples
// the sub-sums that could still be better, tries the splits (with near
// copies merged where it paused), and returns the internal parameters of a
// new final solve when one is.
struct Start {
  std::vector<double> u;
  std::function<std::optional<std::vector<double>>(const std::vector<double>& p, bool paused)> after_final;
  // Whether a final solve whose cost creeps at user parameters p pauses
  // there for after_final (resumed when it returns nothing); empty: never.
  Pause pause;
};
Start StartingPoint(const FitState& s);

// ---------------------------------------------------------------------------
// Uncertainty (uncertainty.cpp).

// Result::stddev, correlation and covariance_message at the solution u of
// `engine` (internal parameters); residual_variance scales the covariance
// when the data carry no sigma.
// A solve over d from internal parameters u of `engine` (updated in place)
// as an active set: the parameters on a bound are held there and
// solve(engine', v) runs on the others (within their bounds). At its
// solution the gradient decides: when it would pull a held parameter
// inside (dC/du = J^T r < 0 at a lower bound, > 0 at an upper one),
// solve(engine, u, &normal) goes on with every parameter free within its
// bounds, `normal` being J^T J and J^T r there (the other calls pass null).
// While the bounds stay active, Ceres' bound-constrained steps (a projected
// line search costing several Jacobian passes per iteration) are avoided.
// Returns J^T J at the solution when that check computed it there.
using HeldSolve = std::function<void(const Engine&, std::vector<double>&, const NormalCache::Normal*)>;
std::optional<NormalCache::Normal> HoldingBounds(const Evaluators& model, const Options& o, double loss_scale,
                                                 const Engine& engine, const Prepared& d, std::size_t chunk,
                                                 std::vector<double>& u, const HeldSolve& solve);
// The Jacobi scaling of a normal matrix: 1 / sqrt of each diagonal entry, 0
// for a column without effect (the scaled matrix's diagonal is 1 or 0).
Eigen::VectorXd JacobiScale(const Eigen::MatrixXd& jtj);
// J^T J and J^T r (the cost's gradient) of engine e over d at internal parameters u.
void NormalEquations(const Engine& e, const Prepared& d, const std::vector<double>& u, std::size_t chunk,
                     Eigen::MatrixXd& jtj, Eigen::VectorXd& jtr);
// final_jtj: the final solve's last J^T J (used when its point is close enough to u).
void Uncertainty(const FitState& s, const Engine& engine, const std::vector<double>& u, double residual_variance,
                 const std::optional<NormalCache::Normal>& final_jtj);

}  // namespace brdfkit::fit
