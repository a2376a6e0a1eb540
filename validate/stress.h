// Robustness sweep: every registered model evaluated over extreme
// parameters and directions in float, double and ceres::Jet, counting
// non-finite and negative values, non-finite derivatives, the reciprocity
// error and the float/double disagreement.
//
// Parameter points (from each model's ParamInfo table, no model list):
//  - the defaults;
//  - one parameter at a time over its range: log-scale parameters
//    (roughness, exponents) at every decade from the lower to the upper
//    bound (roughness down to 1e-7, exponents up to 1e8), linear ones at
//    lower, middle and upper;
//  - every log-scale parameter at its lower bound together, and at its
//    upper bound together (a mirror-like lobe, the sharpest exponents);
//  - anisotropic pairs (names ending _x/_y, or nu/nv): ratios 1e4 and 1e-4
//    at the sharp end and at the rough end of the range, clipped to bounds;
//  - conductor-like eta/k pairs: eta in {lower, 0.2, 1, upper} times k in
//    {lower, 3, upper}.
// Directions: mu = cos(theta) in {1, 0.9, 0.5, 0.1, 1e-3, 1e-6, 1e-12, 0,
// -1e-6, -0.5} at azimuths 0, 2.1, pi and 2.1 + pi, all pairs (wi = wo, wi
// mirrored about the normal, opposite sides of the surface included) plus
// the exact normal against each and the tangential pairs at mu = 1e-12.
// A transmitting model (LobeKind::kTransmission) may be non-zero below the
// surface (only the horizon itself counts as a failure there) and its
// reciprocity error is that of f(wi, wo) eta_r^2 = f(wo, wi), eta_r =
// Bxdf::RelativeIndex.
// Sampling: Sample and Pdf at every wo with u in {0, 1e-12, 0.5, 1 - 1e-16}.
// Bounds: a value one ulp past each bound, and NaN, must be rejected by
// ValidateParams (the run-time check every entry point uses).
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "brdf/model.h"

namespace brdfkit::validate {

struct StressOptions {
  // Registered model names; empty: every registered model. A model that
  // needs settings (a file) is listed as skipped unless given in `settings`.
  std::vector<std::string> models;
  std::vector<std::pair<std::string, Settings>> settings;  // per model name
};

// One model evaluated in one scalar type ("float", "double" or "jet").
struct StressRow {
  std::string model;
  std::string type;
  std::int64_t evaluations = 0;      // f_r evaluations (each RGB)
  std::int64_t nonfinite_count = 0;  // values (channels) NaN or Inf
  std::int64_t negative_count = 0;   // values (channels) < 0
  std::int64_t horizon_nonzero_count = 0;  // values != 0 with wi or wo at or below the horizon (on it: transmitting models)
  std::int64_t nonfinite_derivative_count = 0;  // jet: derivative components not finite where the value is
  std::int64_t sample_failures = 0;  // Sample/Pdf: a non-finite or negative pdf, a non-unit wi, pdf mismatch
  double reciprocity_max_rel_error = 0;  // reciprocal and transmitting (generalised) models; 0 otherwise (floor kStressValueFloor)
  double float_double_max_rel_diff = 0;  // float row: against double at the same float inputs
  std::string worst_float_case;      // where that difference occurred
  std::string first_failure;         // first non-finite/negative case, empty when none
  std::int64_t bound_checks = 0;     // out-of-range values offered to ValidateParams
  std::int64_t bound_failures = 0;   // of those, accepted
  bool skipped = false;
  std::string skip_reason;
};

std::vector<StressRow> RunStress(const StressOptions& options = {});

// Floor (1/sr) of the relative differences (reciprocity, float/double):
// |a - b| / max(|a|, |b|, kStressValueFloor). Values below it are rounding
// residue (e.g. Fresnel at eta = 1, k = 0, which is 0 exactly), far below
// any measurable reflectance.
inline constexpr double kStressValueFloor = 1e-12;

// Stiff integrals: directional albedo of mirror-like lobes (alpha = 1e-4)
// at mu = 1e-6, by the adaptive rule the albedo tables use and, independently,
// by scrambled Sobol' points (2^20) through the model's own sampling.
struct StiffIntegral {
  std::string model;
  std::string params;
  double mu = 0;
  double value = 0, error = 0;          // AlbedoAtMu, green channel
  std::int64_t evals = 0;
  double reference = 0, reference_error = 0;  // DirectionalAlbedo (sobol)
  std::int64_t reference_evals = 0;
  double seconds = 0;
  bool finite = false;
  bool agree = false;  // |value - reference| <= 3 (error + reference_error) + 1e-9
};

std::vector<StiffIntegral> RunStiffIntegrals();

}  // namespace brdfkit::validate
