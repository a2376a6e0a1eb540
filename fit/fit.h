// Fitting BRDF models to tabulated reflectance with Ceres.
//
// Residuals are differentiated automatically through the templated models
// (ceres::Jet), grouped in blocks of a few hundred samples; one model
// evaluation gives all three channels, and the r, g, b slots of a colour
// parameter share one Jet derivative (channel c depends only on slot c,
// checked numerically per model; full Jets otherwise). Parameters whose
// ParamInfo scale is kLog (roughness, exponents) are optimised as log(p) so
// that values spread over orders of magnitude converge; bounds from the
// ParamInfo table go to the problem (SetParameterLowerBound/UpperBound), in
// the transformed space. Uncertainties are (J^T J)^-1 (the estimator of
// ceres::Covariance) from the dense normal matrix of the few parameters,
// mapped back to the user's parameters through the Jacobian of the transform.
//
// Metrics (residual of one sample and channel, model f, reference g):
//   l2        f - g
//   relative  (f - g) / max(g, floor), floor = 1e-3 x the mean of g
//   cosine    (f - g) cos(theta_i), theta beyond 80 degrees dropped
//             (Ngan, Durand, Matusik 2005, "Experimental analysis of BRDF
//             models", sec. 4)
//   log       log(1 + f cos_i) - log(1 + g cos_i)
//             (Low, Kronander, Ynnerman, Unger 2012, "BRDF models for
//             accurate and efficient rendering of glossy surfaces", eq. 13)
//   cbrt      cbrt(f cos_i) - cbrt(g cos_i)
//             (Fores, Ferwerda, Gu 2012, "Toward a perceptually based metric
//             for BRDF modeling": the cube root follows perceived lightness)
// With per-sample standard deviations sigma, each residual is divided by its
// own standard deviation propagated through the metric (first order), so the
// cost is chi^2 / 2 and the covariance needs no rescaling; without them the
// covariance is scaled by the residual variance 2 cost / (m - n). Either way
// the standard deviations are statistical given the model: they say how well
// the data determine the parameters of this model, not how far the model is
// from the material (see Result::relative_error and Result::warnings).
#pragma once

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "brdf/model.h"

namespace ceres {
class CostFunction;
}

namespace brdfkit {
class MerlTable;
class RglBsdf;
class UtiaTable;
namespace synth {
struct BrdfTable;
struct Instrument;
}  // namespace synth
}  // namespace brdfkit

namespace brdfkit::fit {

class Evaluators;  // fit/jet_models.h

enum class Metric { kL2, kRelative, kCosine, kLog, kCbrt };
enum class Loss { kNone, kHuber, kCauchy };

Metric ParseMetric(const std::string& name);  // throws std::invalid_argument
std::string MetricName(Metric m);
const std::vector<Metric>& AllMetrics();
// "none", "huber", "cauchy"; throws std::invalid_argument naming the text.
Loss ParseLoss(const std::string& name);
std::string LossName(Loss l);
const std::vector<Loss>& AllLosses();

// One measurement: directions in the local frame (unit, z = normal), f_r per
// channel in 1/sr, and its standard deviation (0 when unknown).
struct Sample {
  Eigen::Vector3d wi, wo;
  Eigen::Array3d f, sigma;
};

struct Dataset {
  std::vector<Sample> samples;
  bool has_sigma = false;
  std::size_t missing = 0;  // samples dropped because a value was missing
  std::string source;       // file name, for messages
  // Set when the data's sidecar (FILE.json) says they were measured through
  // finite apertures: what they were, and the sidecar (usable as the
  // instrument of an aperture-aware fit). A plain fit then warns.
  std::string apertures, sidecar;
};

Dataset FromTable(const synth::BrdfTable& table, const std::string& source = "");
// Bin centres of a MERL table (phi_h = 0); a cell missing in any channel or
// whose centre puts a direction at the horizon is counted in `missing`.
Dataset FromMerl(const MerlTable& table, const std::string& source = "");
// The nodes of an RGL file (cosine divided out) and every node pair of a UTIA file.
Dataset FromRgl(const RglBsdf& file, const std::string& source = "");
Dataset FromUtia(const UtiaTable& table, const std::string& source = "");
// Reads an RGL .bsdf (by its magic), a UTIA file (.utia, or .bin of the UTIA
// size), an ASTM E1392 table (.astm), a MERL binary (by the MERL header) or
// a CSV table, and the apertures from a synthetic measurement's sidecar
// FILE.json.
Dataset LoadDataset(const std::string& path);

inline constexpr int kMaxRandomStarts = 100000;

enum class LinearSolver { kDenseQr, kDenseNormalCholesky, kIterativeSchur, kCgnr };
LinearSolver ParseLinearSolver(const std::string& name);  // throws std::invalid_argument
std::string LinearSolverName(LinearSolver s);
const std::vector<LinearSolver>& AllLinearSolvers();

struct Options {
  Metric metric = Metric::kL2;
  // Samples with theta_i or theta_o above this are dropped. Negative: 80
  // degrees for the cosine metric (as Ngan et al.), no cut otherwise.
  double max_theta_deg = -1;
  Loss loss = Loss::kNone;
  // Robust loss scale in units of the residual. Non-positive: 3 when the data
  // has sigma (three standard deviations), otherwise 3 x 1.4826 x the median
  // absolute residual at the starting point (a robust standard deviation).
  double loss_scale = 0;
  bool use_sigma = true;  // weight by 1/sigma when the data has it
  LinearSolver solver = LinearSolver::kDenseQr;
  int num_threads = 2;  // capped at the hardware threads
  int max_iterations = 200;
  double function_tolerance = 1e-10;
  double gradient_tolerance = 1e-16;
  double parameter_tolerance = 1e-12;
  std::size_t chunk = 256;  // samples per residual block
  // Starting point (packed, user space). Empty: multi-start (below).
  std::vector<double> initial;
  // Multi-start: log-spaced starts of every log-scale parameter, each solved
  // on a random subset of at most `start_subset` samples for at most
  // `start_iterations` iterations; the best start is refined on all data.
  int starts_per_param = 5;
  std::size_t start_subset = 4096;
  int start_iterations = 20;
  bool covariance = true;
  // Fit through the instrument's finite apertures (data_synth forward model).
  const synth::Instrument* instrument = nullptr;
  // 0: the instrument's own setting. Its automatic order is synth's: each
  // pair's source and detector rules rise on their own until they meet its
  // tolerance (MeasureAdaptive), the derivatives taken at those rules.
  int aperture_order = 0;
  // Parameters held fixed, tied to another, or bounded more narrowly than
  // the model's table, each "name=...,name=..." over the model's parameter
  // names ("ggx.f0", "ggx#2.alpha"):
  //   fix     name=value (a colour parameter: one value or r:g:b)
  //   tie     follower=leader: the follower takes the leader's value; both
  //           colour or both scalar, on the same scale (log or linear)
  //   bounds  name=lo:hi within the model's range (all channels of a colour)
  std::string fix, tie, bounds;
  // Sums of lobes: also fit every nested sub-sum (each lobe switched off in
  // turn) and start from its optimum with the lobe seeded from the
  // residual, so that the fit is never worse than a sub-sum's (see Fit).
  bool nested = true;
  // An independent check of the start strategy: when positive, it is
  // replaced by this many random starts, each solved to convergence (on the
  // middle-sized subset of 16 x start_subset samples when the table has
  // more than 64 x start_subset), drawn with `seed`; every distinct optimum
  // goes to Result::local_optima and the best is refined on all samples.
  int random_starts = 0;  // at most kMaxRandomStarts
  std::uint64_t seed = 1;
  // Called after every iteration of the final solve (progress display).
  std::function<void(int iteration, double seconds, double cost)> progress;
};

// Checks Options::fix, tie and bounds against the model; throws
// std::invalid_argument naming the option and the parameter: an unknown
// name (with the nearest names), a value or bounds outside the model's
// range, inverted bounds, a parameter both fixed and tied or bounded, a tie
// between parameters of different kinds or sizes, a tie cycle, and a model
// with nothing left to fit.
void CheckConstraints(const ModelInfo& info, const Options& options);

// Checks the numeric options (max_theta_deg, max_iterations,
// starts_per_param, start_subset, start_iterations, random_starts); throws
// std::invalid_argument "<option> must be ...", the option spelled by
// `spell` (a front end's name for the Options field; default the field's
// own). Fit calls it.
void CheckOptions(const Options& options, const std::function<std::string(const std::string& field)>& spell = {});

// One accepted iteration. The multi-start solves (start = 1, 2, ...) run on
// their subset of the samples and report its RMSE; start = 0 is the final
// solve on all samples.
struct TracePoint {
  int iteration = 0;
  double seconds = 0;  // since the start of Fit (initialisation included)
  double cost = 0;
  double rmse = 0;     // root mean square of the metric's residuals
  int start = 0;
  // What the solve was: "start 3 (subset)", "lambert+ggx: refine (all
  // samples)" for the sub-sums and starts of a sum, "final".
  std::string stage;
};

// A distinct local optimum of the fit on all samples (without the robust
// loss): its cost, packed user parameters, and where its solve started.
struct LocalOptimum {
  double cost = 0;
  std::vector<double> params;
  std::string origin;
};

// Relative error of a fitted model against the data it was fitted to:
// |f - g| / max(g, floor) per sample and channel, g the data, f the fitted
// model (through the instrument when the fit used one), floor = 1e-3 x the
// channel's mean of g (as the relative metric), over the samples used.
struct ErrorStats {
  std::size_t count = 0;  // sample-channel values
  double median = 0, p95 = 0, max = 0;
};
// The same over a band of half-vector angles theta_h, [min, max) degrees.
struct BandStats {
  double theta_h_min_deg = 0, theta_h_max_deg = 0;
  ErrorStats stats;
};
// Band edges of Result::relative_error_bands, degrees.
inline constexpr double kThetaHBandEdgesDeg[] = {0, 2, 5, 10, 20, 40, 90};

struct Result {
  Model model;
  Metric metric = Metric::kL2;
  std::vector<double> params;  // packed, user space
  std::vector<double> stddev;  // packed; NaN where not determined
  Eigen::MatrixXd correlation; // packed x packed; empty when not computed
  std::vector<std::string> packed_names;  // "lambert.albedo.r", "ggx.alpha", ...
  bool covariance_ok = false;
  std::string covariance_message;  // plain words when uncertainties are missing
  double cost = 0;
  double rmse = 0;           // of the chosen metric, unweighted, over the samples used
  // 2 cost / (m - n) when the residuals are weighted by the data's sigma;
  // NaN when the data carry none (no stated noise to compare with).
  double chi2_reduced = 0;
  ErrorStats relative_error;
  std::vector<BandStats> relative_error_bands;  // non-empty bands of kThetaHBandEdgesDeg
  // Things a user should know about the result: a model that does not
  // describe the data (residuals far above the stated noise), and the like.
  std::vector<std::string> warnings;
  std::size_t residuals = 0;
  std::size_t used = 0;      // samples used
  std::size_t dropped_angle = 0;  // samples beyond max theta
  std::size_t missing = 0;
  int iterations = 0;
  int starts = 0;
  double init_seconds = 0;
  double seconds = 0;        // total, covariance included
  double solve_seconds = 0;  // initialisation and solve, without covariance
  bool converged = false;
  std::string message;
  double loss_scale = 0;
  std::vector<TracePoint> trace;
  // Every distinct local optimum found on all samples, by increasing cost;
  // the final solve started from local_optima[kept]. A fit from
  // Options::initial or a single-lobe multi-start solves on all samples
  // once: its one entry is the final result.
  std::vector<LocalOptimum> local_optima;
  int kept = -1;
  // Per packed slot: held fixed (stddev 0), and the name of the parameter a
  // tied one follows (empty otherwise; it reports that parameter's stddev).
  std::vector<bool> fixed;
  std::vector<std::string> tied_to;
};

Result Fit(const Model& model, const Dataset& data, const Options& options);
// The same for a model given by its evaluators (one outside the registry,
// such as a Python function); Result::model is then left empty.
Result Fit(const Evaluators& model, const Dataset& data, const Options& options);

// Names of the packed slots: colour parameters get .r, .g, .b.
std::vector<std::string> PackedNames(const ModelInfo& info);

// Metric residuals (unweighted) of packed parameters over the samples the
// options select; returns their root mean square.
double MetricRmse(const Model& model, const std::vector<double>& params, const Dataset& data,
                  const Options& options);

// The residual blocks Fit builds (chunks of samples over one parameter
// block of internal parameters: log of the log-scale ones), for checks.
class ResidualBlocks {
 public:
  ResidualBlocks(const Model& model, const Dataset& data, const Options& options, double loss_scale = 1.0);
  ~ResidualBlocks();
  std::size_t size() const;
  const ceres::CostFunction& block(std::size_t k) const;
  std::vector<double> ToInternal(const std::vector<double>& params) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace brdfkit::fit
