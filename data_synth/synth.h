// Synthetic gonioreflectometer measurements: expands an instrument's
// sampling plan, pushes a BRDF through the forward model (forward_model.h)
// over every planned pair, in parallel, and adds the instrument's
// imperfections (sensor noise model in noise.h).
//
// Every random draw of sample n comes from a counter-based generator keyed by
// (seed, n), so a data set is bit-for-bit reproducible from its seed whatever
// the number of threads.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "brdf/model.h"
#include "data_synth/forward_model.h"
#include "data_synth/instrument.h"
#include "data_synth/noise.h"

namespace brdfkit::synth {

// A plan turned into the list of nominal direction pairs, in measurement
// order, with the image layout of grid plans.
struct ExpandedPlan {
  std::vector<PlannedPair> pairs;
  // Grid plans: pixel (row * image_width + col) of each pair; empty otherwise.
  int image_width = 0, image_height = 0;
  std::vector<std::int64_t> pixel;
  std::string image_layout;  // what rows and columns are
  // MERL plan: the cell index MerlTable::Index(i, j, k) of each pair.
  std::vector<std::int64_t> merl_cell;
};

// Throws std::runtime_error naming the file and line for a bad list file.
ExpandedPlan ExpandPlan(const SamplingPlan& plan);

struct SynthSample {
  Eigen::Array3d f = Eigen::Array3d::Zero();      // reported f_hat, 1/sr
  Eigen::Array3d sigma = Eigen::Array3d::Zero();  // standard uncertainty from the noise model
  bool valid = false;      // false: a nominal direction at or below the horizon (not measured)
  bool saturated = false;  // every exposure saturated in some channel (f is a lower bound)
};

struct SynthReport {
  int order = 1;                    // aperture quadrature order (automatic: the order whose degree covers both below)
  int source_degree = 0, detector_degree = 0;  // highest rule degree of each cone (0: a point cone)
  double quadrature_error = 0;      // estimated relative error (max over the checked pairs)
  std::size_t checked_pairs = 0;    // pairs used to choose the order and estimate its error
  std::size_t horizon_crossing = 0; // pairs with a cone cut by the horizon (integrated over its part above it)
  // Automatic order: each pair raises its source and detector rules
  // separately (MeasureAdaptive in forward_model.h) up to source_degree and
  // detector_degree. mean_evaluations is the mean count of BRDF evaluations
  // per pair; pairs_at_max_order counts the pairs that stopped without
  // meeting the tolerance, and pair_error is the largest error estimate of
  // the others (below the tolerance).
  double mean_evaluations = 0;
  double pair_error = 0;
  std::size_t pairs_at_max_order = 0;
  double max_order_error = 0;  // largest error estimate of those pairs
  std::size_t measured = 0, not_measured = 0, saturated = 0;
  double seconds = 0;
};

struct SynthResult {
  ExpandedPlan plan;
  std::vector<SynthSample> samples;  // parallel to plan.pairs
  SynthReport report;
  bool noisy = false;  // the sensor noise model was on (sigma is meaningful)
};

// Chooses the quadrature orders on up to `max_checked` pairs spread through
// the plan.
// Automatic order (settings order 0): each checked pair runs MeasureAdaptive
// up to the degree of the settings' max_order; the result holds the source
// and detector degrees 99 % of them needed (the caps for the whole plan) and
// the largest error estimate among those. Fixed order n: the product rule of
// order n (degree 4 n - 1), with the error estimated as
// max |I_n - I_(n+1)| / |I_(n+1)| (relative, max over channels).
struct OrderChoice {
  int order = 1;
  int source_degree = 0, detector_degree = 0;  // 0: a point cone
  double error = 0;
  std::size_t checked = 0, horizon_crossing = 0;
};
OrderChoice ChooseApertureOrder(const Instrument& inst, const Bxdf<double>& bxdf, const double* params,
                                const ExpandedPlan& plan, std::size_t max_checked = 2048);

// Called from the worker threads with the pairs done and the total; an
// exception it throws stops the measurement and propagates (a user's Ctrl-C).
using SynthProgress = std::function<void(std::size_t done, std::size_t total)>;

// Runs the whole virtual measurement.
SynthResult Synthesize(const Instrument& inst, const Model& model, const std::vector<double>& params,
                       std::uint64_t seed, const SynthProgress& progress = {});
// As above on an already expanded plan.
SynthResult Synthesize(const Instrument& inst, const Model& model, const std::vector<double>& params,
                       std::uint64_t seed, ExpandedPlan plan, const SynthProgress& progress = {});
// As above for a model given as an evaluator (one outside the registry, such
// as a Python function).
SynthResult Synthesize(const Instrument& inst, const Bxdf<double>& model, const std::vector<double>& params,
                       std::uint64_t seed, ExpandedPlan plan, const SynthProgress& progress = {});

// Pointing error of one arm: a Gaussian tangent offset (std `sigma` along
// e_theta and e_phi) applied through the exponential map of the sphere.
inline Eigen::Vector3d JitterDirection(const Eigen::Vector3d& w, double sigma, SampleRng& rng) {
  if (!(sigma > 0)) return w;
  const double a = sigma * SensorModel::Normal(rng), b = sigma * SensorModel::Normal(rng);
  const double rho = std::hypot(a, b);
  if (rho == 0) return w;  // no offset drawn: the direction of the tangent step is undefined
  const Eigen::Matrix3d f = ArmFrame(w);
  return std::cos(rho) * w + (std::sin(rho) / rho) * (a * f.col(0) + b * f.col(1));
}

}  // namespace brdfkit::synth
