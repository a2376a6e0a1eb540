// Physical plausibility of a BRDF at one parameter point, and over a grid of
// its parameter ranges.
//
// Properties and thresholds (a property fails when its test is violated):
//  - reciprocity: max over pairs of max_c |f_c(wi, wo) - f_c(wo, wi)| /
//    max_c max(f_c(wi, wo), f_c(wo, wi)) <= 1e-9. Pairs: normal against
//    every elevation, grazing (1e-6 rad from the horizon) against all, mirror,
//    near-retro-reflection, wi = wo, and uniformly random pairs.
//  - energy conservation: max over wo and channels of E(wo) <= 1 + 1e-6:
//    passes when every E's error bar lies below, fails when one lies wholly
//    above, and is inconclusive when a bar straddles the bound after that
//    E was integrated again with tighten_factor times the budget;
//    E by the adaptive half-vector cubature of validate/integrators.h, searched
//    over mu from 1 down to 1e-7 (grazing) with golden-section refinement, and
//    over phi_o in [0, pi) for models that are not rotation invariant.
//  - values: every f_r evaluated is finite and >= 0.
//  - sampling (only for models that sample; skipped with a note otherwise):
//    the pdf integrates to the fraction of valid samples (within
//    5 standard errors + 2e-3, quadrature of narrow lobes) and not above 1 +
//    2e-3; chi-square goodness of fit at wo = 0, 30, 60, 80 degrees (and a
//    rotated azimuth for anisotropic models), Sidak-corrected family p-value
//    1 - (1 - p_min)^m >= 0.01. Skipped (and said so) for lobes narrower than
//    kMinSampledLobeWidth.
//  - transmitting models (Kind() has LobeKind::kTransmission) over the whole
//    sphere: the reciprocity pairs also with wi, wo or both below the
//    surface, compared as f(wi, wo) eta_r^2 against f(wo, wi), eta_r =
//    Bxdf::RelativeIndex (Veach's generalised reciprocity); the values on
//    both sides; energy as the power scattered from light along w over the
//    sphere (ScatteredPower: reflected + transmitted <= 1 + 1e-6), searched
//    over w on both sides (albedo_max_at_mu < 0: light from below); the
//    sampling directions also below, binned over the sphere.
//  - microfacet models: int D(m) cos(theta_m) dm = 1 and, with a Smith G1,
//    the weak white furnace int D G1(wo, m) max(0, wo.m) / cos(theta_o) dm = 1
//    (Heitz 2014 eq. 14 and 18), both within 1e-6 + their error estimates.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "brdf/model.h"

namespace brdfkit::validate {

// Lobes narrower than this (radians, the model's declared Bxdf::Width) are not sampled
// against the chi-square bins, which cannot resolve them.
inline constexpr double kMinSampledLobeWidth = 0.03;

struct CheckOptions {
  int random_pairs = 4000;
  std::uint64_t seed = 1;
  double reciprocity_tolerance = 1e-9;
  double albedo_slack = 1e-6;
  double normalisation_tolerance = 1e-6;
  bool sampling = true;
  std::int64_t sampling_samples = 100000;
  double significance = 0.01;  // family-wise, for the chi-square tests
  int golden_steps = 12;       // refinement of the albedo maximum in mu
  std::int64_t albedo_budget = 400000;  // evaluations per directional albedo (adaptive)
  // The ranges the command line, scenes and Python accept.
  static constexpr std::int64_t kMinSamples = 1000, kMaxSamples = 100000000;
  static constexpr std::int64_t kMinAlbedoBudget = 1000, kMaxAlbedoBudget = 1000000000;
  int tighten_factor = 16;  // budget factor for albedos whose error bar straddles 1
  int tighten_points = 8;   // at most this many of them, the highest bars first
};

struct CheckResult {
  // Reciprocity.
  double reciprocity_max_rel_error = 0;
  Eigen::Vector3d reciprocity_worst_wi = Eigen::Vector3d::UnitZ(), reciprocity_worst_wo = Eigen::Vector3d::UnitZ();
  std::int64_t pairs_checked = 0;
  // Energy conservation.
  double albedo_max = 0;        // max over wo and channels
  double albedo_max_error = 0;  // error estimate of that value
  double albedo_max_at_mu = 1;  // < 0: a direction below the surface (transmitting models)
  double albedo_max_at_phi = 0;
  Eigen::Array3d albedo_max_per_channel = Eigen::Array3d::Zero();
  double albedo_at_grazing = 0;  // max channel at the smallest mu searched
  double albedo_at_normal = 0;
  bool rotation_invariant = true;
  int albedo_evaluations = 0;           // directional albedos integrated
  std::int64_t albedo_integrand_evals = 0;  // the integrand evaluations they took
  int albedo_tightened = 0;  // albedos integrated again with the larger budget
  // Values.
  double min_value = 0;
  std::int64_t nonfinite_count = 0;
  std::int64_t values_checked = 0;
  // Sampling.
  bool sampling_checked = false;
  std::string sampling_note;  // why sampling was not checked
  double pdf_integral = 0;  // the one farthest from the valid fraction
  double valid_fraction = 0;
  double chi2_p_value = 1;  // Sidak-corrected family p-value
  double chi2_min_p = 1;
  int sampling_directions = 0;
  std::int64_t pdf_mismatch = 0;
  // Microfacet normalisation.
  bool microfacet = false;
  double d_normalisation = 0, d_normalisation_error = 0;
  bool has_smith_g1 = false;
  double furnace_min = 0, furnace_max = 0, furnace_error = 0;
  // Verdict: plausible when every property passes; implausible when one
  // fails; otherwise inconclusive (an error bar too wide to decide).
  bool plausible = true;
  std::vector<std::string> reasons;       // one per failed property, each starting with its name
  std::vector<std::string> inconclusive;  // one per undecided property, with why
  const char* Verdict() const { return !reasons.empty() ? "implausible" : (inconclusive.empty() ? "plausible" : "inconclusive"); }
  double seconds = 0;
};

CheckResult CheckPlausibility(const Bxdf<double>& bxdf, const double* params, const CheckOptions& options = {});

// Grid over the model's parameter ranges: `per_axis` values per scalar (or
// colour, all channels together) parameter, bounds included, log-spaced for
// log-scale parameters. Parameters in `fixed` (indices into ModelInfo::params)
// keep their base value. At most max_points points (fewer values per axis
// when the product would exceed it).
std::vector<std::vector<double>> SweepGrid(const ModelInfo& info, const std::vector<double>& base, int per_axis,
                                           const std::vector<std::size_t>& fixed = {}, std::size_t max_points = 400);

struct SweepResult {
  std::vector<std::vector<double>> points;
  std::vector<CheckResult> results;
};

// CheckPlausibility at every grid point, in parallel (TBB).
SweepResult SweepPlausibility(const Model& model, const std::vector<std::vector<double>>& points,
                              const CheckOptions& options);

}  // namespace brdfkit::validate
