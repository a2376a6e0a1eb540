// Directional albedo tables for renderers: E(mu, p) over mu = cos(theta_o)
// and one or two model parameters, the average albedo
// E_avg(p) = 2 int_0^1 E(mu) mu dmu, and the terms of Kulla & Conty's
// multiple-scattering energy compensation (Kulla & Conty 2017, "Revisiting
// Physically Based Shading at Imageworks", SIGGRAPH course, slides 17-21):
//
//   f_ms(wi, wo) = (1 - E(mu_i)) (1 - E(mu_o)) / (pi (1 - E_avg)),
//   and with Fresnel: f_ms * F_avg^2 E_avg / (1 - F_avg (1 - E_avg)),
//   F_avg = 2 int_0^1 F(mu) mu dmu.
//
// Quadrature. E(wo) = int f_r(wi, wo) cos(theta_i) dwi is the adaptive rule
// of validate/integrators.h (DirectionalAlbedo, Method::kAdaptive): over the
// half vector for a model with a glossy lobe, where the lobe sits at wm = z
// for every wo and the horizon is the exact end of every inner range, and
// in (phi, cos theta) for one without; nested adaptive Gauss-Kronrod (7/15)
// whose QUADPACK-scaled error estimate is conservative for smooth integrands.
//
// Grazing limit. f_r = 0 at mu = 0 by convention, but E(mu) has a limit as
// mu -> 0 (GGX alpha = 1: E(mu) = 1 - mu ln(1 + 1/mu) -> 1). The entry at
// mu = 0 holds E(mu_0) with mu_0 = max(1e-15, min(kGrazingMu, 1e-9 w)) for a
// lobe of angular width w: E(mu) - E(0) = O((mu / w) ln(w / mu)), so the
// limit is reached within 1e-7 for every w >= 1e-6 (GGX alpha >= 1.6e-6);
// AlbedoTable::limit_error reports |E(mu_0) - E(10 mu_0)|.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "brdf/model.h"
#include "validate/integrators.h"

namespace brdfkit::validate {

inline constexpr double kGrazingMu = 1e-13;

// --- one directional albedo ----------------------------------------------

struct AlbedoQuadratureOptions {
  double abs_tolerance = 1e-6;  // on each channel of E and E_avg: the accuracy contract of the tables
  int max_subdivisions = 400;   // per adaptive level
  // Evaluations per directional albedo after which no interval is split
  // further: below alpha ~ 1e-4 at grazing, rounding in f_r (the half
  // vector of two nearly opposite tangential components) is above the
  // tolerance and refinement cannot converge; the error estimate says so.
  std::int64_t max_evals = 1000000;
  // A transmitting model (LobeKind::kTransmission) tabulates the power
  // scattered from light arriving along wo (ScatteredPower): the reflected
  // part E_R, the transmitted part E_T, or their sum E_R + E_T (<= 1). The
  // inside of the interface is the outside of the model with 1 / eta, so an
  // eta axis across 1 covers both sides. A non-reciprocal reflection model
  // (a measured table, Phong's original) tabulates the power reflected from
  // light along wo as well (E_R; E_T = 0). Other models ignore it (E).
  enum class Part { kTotal, kReflected, kTransmitted } part = Part::kTotal;
  // The largest error estimate the caller accepts. E_avg stops refining once
  // its estimate is sure to end above it (a node of its rule missed its own
  // target by too much): such a table is refused, and a measured table's
  // average at 1e-6 would otherwise refine for minutes first.
  double accepted_error = std::numeric_limits<double>::infinity();
  // The same as options of the adaptive rule of validate/integrators.h.
  IntegrateOptions Integrate(const LobeShape& shape) const {
    IntegrateOptions o;
    o.budget = max_evals;
    o.abs_tolerance = abs_tolerance;
    o.rel_tolerance = 0;
    o.max_subdivisions = max_subdivisions;
    o.shape = shape;
    return o;
  }
};

// One directional albedo: value and error estimate per channel, evaluations.
using AlbedoValue = Estimate;

// E at mu (phi_o = 0); mu <= kGrazingMu gives the grazing limit E(kGrazingMu).
AlbedoValue AlbedoAtMu(const Bxdf<double>& bxdf, const double* params, double mu, const LobeShape& shape,
                       const AlbedoQuadratureOptions& options = {});

// E_avg = 2 int_0^1 E(mu) mu dmu by adaptive Gauss-Kronrod in v = sqrt(ln(1 / mu))
// (stretched about the critical angle of a transmitting model seen from its
// denser side), with its own evaluations of E (not the table's nodes).
AlbedoValue AverageAlbedo(const Bxdf<double>& bxdf, const double* params, const LobeShape& shape,
                          const AlbedoQuadratureOptions& options = {});

// One-dimensional adaptive Gauss-Kronrod (7/15) of a vector-valued function
// on [a, b] with initial breakpoints (inside (a, b), any order). Returns the
// integral and stores the error estimate (max over components) in *error.
// stop, when given, ends the refinement early (checked before each split).
Eigen::Array3d AdaptiveGaussKronrod(const std::function<Eigen::Array3d(double)>& f, double a, double b,
                                    std::vector<double> breakpoints, double abs_tolerance, int max_subdivisions,
                                    double* error, std::int64_t* evals, const std::function<bool()>& stop = {});

// --- tables ----------------------------------------------------------------

enum class NodeRule {
  kUniform,  // mu uniform on [0, 1]; roughness uniform in sqrt(p); other parameters uniform; ends included
  kGauss,    // Gauss-Legendre nodes in the same coordinates (ends excluded); weights given
};

struct AxisSpec {
  // "mu", a scalar (or colour, all channels together) model parameter, or
  // "roughness" for a model with an alpha parameter (alpha = roughness^2).
  std::string name;
  int count = 0;
  double lower = 0, upper = 0;  // range; lower == upper == 0 means the parameter's bounds
};

struct Axis {
  std::string name;
  std::size_t param_index = 0;  // into ModelInfo::params (unused for mu)
  bool sqrt_spacing = false;    // nodes uniform in sqrt(value)
  // A "roughness" axis: nodes are roughness r, uniform in r, and the model's
  // alpha parameter (param_index) is r^2 (at least alpha's lower bound).
  bool squared = false;
  std::vector<double> nodes;
  std::vector<double> weights;  // Gauss weights over the axis range in the value coordinate (kGauss)
};

// The model parameter an axis sets: its index in info.params ("roughness"
// sets "alpha"); throws ModelError naming the model's parameters.
std::size_t AxisParameter(const ModelInfo& info, const std::string& axis_name);

// "total", "reflected" or "transmitted" (the part of a transmitting model's
// scattered power a table holds); throws ModelError naming the choices.
AlbedoQuadratureOptions::Part ParsePart(const std::string& text);
// The names ParsePart takes, in the order of the Part enumeration.
std::vector<std::string> PartNames();

// Parses "mu:32,alpha:32,f0:8" or "alpha:16:0.001:1" (name:count[:lower:upper]).
std::vector<AxisSpec> ParseAxes(const std::string& text);

struct AlbedoTableRequest {
  std::vector<AxisSpec> axes;  // first "mu", then up to two parameters (none: E(mu) of the model as given)
  NodeRule rule = NodeRule::kUniform;
  AlbedoQuadratureOptions quadrature;
  int channel = 0;  // RGB channel tabulated (the models' grey parameters make all three equal)
  // Only nodes [slice_begin, slice_end) of the first parameter axis: a slice
  // of the full table with the same node values, so that one table can be
  // computed in pieces and the pieces joined along that axis.
  std::size_t slice_begin = 0, slice_end = static_cast<std::size_t>(-1);
  // Called from the worker threads after each cell or average with the
  // number done and the total; an exception it throws stops the table and
  // propagates (a user's Ctrl-C).
  std::function<void(std::size_t done, std::size_t total)> progress;
};

struct AlbedoTable {
  std::string model;
  std::vector<double> base_params;  // fixed parameter values (packed)
  std::string params_text;          // the parameters held fixed (not on an axis) as name=value,...
  // What a transmitting model's entries hold: "E_R", "E_T" or "E_R+E_T"
  // (AlbedoQuadratureOptions::part); empty for other models (E).
  std::string part;
  Axis mu;
  std::vector<Axis> params;  // none, one or two
  // E[(i1 * n2 + i2) * n_mu + i_mu], n2 = 1 when there is one parameter axis
  // (the layout of the EXR image and the C arrays: mu runs fastest).
  std::vector<double> E, E_error;
  // E_avg[i1 * n2 + i2].
  std::vector<double> E_avg, E_avg_error;
  // Compensation normalisation 1 / (pi (1 - E_avg)); 0 where E_avg >= 1 (no
  // energy is lost there and the compensation lobe vanishes).
  std::vector<double> ms_norm;
  // With an f0 axis: F_avg (per f0 node), the F = 1 tables
  // E1[i_other * n_mu + i_mu] and E1_avg[i_other] over the other parameter axis
  // (one entry when there is none), and the Fresnel factor
  // F_ms[i1 * n2 + i2] = F_avg^2 E1_avg / (1 - F_avg (1 - E1_avg)).
  int f0_axis = -1;  // index into params, or -1
  std::vector<double> F_avg, E1, E1_avg, F_ms;
  std::vector<double> E1_error, E1_avg_error;  // error estimates of E1 and E1_avg
  double max_error = 0;    // largest quadrature error estimate over all entries
  double limit_error = 0;  // largest |E(kGrazingMu) - E(10 kGrazingMu)| over the mu = 0 entries
  double seconds = 0;

  std::size_t n_mu() const { return mu.nodes.size(); }
  std::size_t n1() const { return params.empty() ? 1 : params[0].nodes.size(); }
  std::size_t n2() const { return params.size() > 1 ? params[1].nodes.size() : 1; }
  std::size_t Index(std::size_t i_mu, std::size_t i1, std::size_t i2 = 0) const {
    return (i1 * n2() + i2) * n_mu() + i_mu;
  }
  double at(std::size_t i_mu, std::size_t i1, std::size_t i2 = 0) const { return E[Index(i_mu, i1, i2)]; }
};

// Builds the table with TBB across cells. Throws ModelError for unknown
// axes, colour parameters other than the tabulated channel's, or ranges
// outside the parameter bounds.
AlbedoTable BuildAlbedoTable(const Model& model, const std::vector<double>& base_params,
                             const AlbedoTableRequest& request);
// The same for a model given as an evaluator (one outside the registry, such
// as a Python function); spec names it in the table.
AlbedoTable BuildAlbedoTable(const Bxdf<double>& model, const std::string& spec,
                             const std::vector<double>& base_params, const AlbedoTableRequest& request);

// The accuracy contract: every entry's error estimate is at most the
// request's tolerance. An entry that misses it (E, E_avg, or the F = 1
// tables E1, E1_avg), with where it is.
struct AlbedoMiss {
  std::string table;  // "E", "E_avg", "E1" or "E1_avg"
  double mu = -1;     // the mu node, or -1 for averages
  std::vector<std::pair<std::string, double>> at;  // parameter axis values
  double error = 0;
};
std::vector<AlbedoMiss> EntriesAboveTolerance(const AlbedoTable& table, double tolerance);
// "N table entries miss the error tolerance T:" and the `shown` worst, one a line.
std::string DescribeMisses(const std::vector<AlbedoMiss>& misses, double tolerance, std::size_t shown = 8);
// What to change when entries miss: the parameter range, or (a table without
// parameter axes, such as a measured table's) the tolerance, written as the
// caller takes it (looser_tolerance: "--tolerance 1e-3", "tolerance=1e-3").
std::string MissAdvice(const AlbedoTable& table, const std::string& looser_tolerance = "--tolerance 1e-3");

// Writers (atomic: a failure leaves no file behind).
// CSV: "mu,<p1>[,<p2>],E" and beside it <stem>_avg.csv "<p1>[,<p2>],E_avg".
void WriteAlbedoCsv(const AlbedoTable& table, const std::string& path);
std::string AverageCsvPath(const std::string& path);
// EXR: part "E" (width n_mu, height n1 * n2, rows i1 * n2 + i2) and part
// "E_avg" (width n2, height n1), float32 channel "E"; header attributes
// brdfkit.model, brdfkit.params, brdfkit.axes and brdfkit.nodes.<axis>.
void WriteAlbedoExr(const AlbedoTable& table, const std::string& path);
// C header (C89 and C++, include guard) with float arrays and node arrays;
// every value is finite. Throws ModelError for a value with no float literal.
void WriteAlbedoHeader(const AlbedoTable& table, const std::string& path, const std::string& symbol_prefix);
// A C float literal that reads back to float(v): "0.0f", "1.0f",
// "0.123456789f", "1e-07f". Values below the smallest normal float are
// written as 0 (a subnormal literal is diagnosed by some compilers);
// non-finite values have no literal and are refused (ModelError naming what).
std::string FloatLiteral(double v, const std::string& what);

// --- energy compensation -------------------------------------------------

// E(mu, p) looked up in a table with one parameter axis: cubic
// (Catmull-Rom) in mu, linear in the parameter's node coordinate.
class AlbedoLookup {
 public:
  explicit AlbedoLookup(const AlbedoTable& table);
  double E(double mu, double p) const;
  double EAvg(double p) const;

 private:
  double Interp1(const std::vector<double>& coords, double c, std::size_t& i0) const;
  // The parameter axis's node coordinate of a model parameter value p:
  // sqrt(p) for a roughness axis (nodes r, alpha = r^2) or one spaced in
  // sqrt(p), p otherwise.
  double Coordinate(double p) const {
    const Axis& a = t_.params[0];
    return a.sqrt_spacing || a.squared ? std::sqrt(std::max(p, 0.0)) : p;
  }
  AlbedoTable t_;
  std::vector<double> mu_coord_, p_coord_;
};

// The single-scattering model plus Kulla-Conty's compensation lobe, for a
// table whose parameter axis is param_name (F = 1). Not a registered model:
// a check of the table (white furnace) and a reference for renderers.
class CompensatedBxdf final : public Bxdf<double> {
 public:
  CompensatedBxdf(const Bxdf<double>& base, const AlbedoTable& table);
  const ModelInfo& Info() const override { return base_.Info(); }
  Rgb<double> Eval(const double* p, const Vec3<double>& wi, const Vec3<double>& wo) const override;
  BsdfSample<double> Sample(const double* p, const Vec3<double>& wo, double u1, double u2) const override {
    return base_.Sample(p, wo, u1, u2);
  }
  double Pdf(const double* p, const Vec3<double>& wo, const Vec3<double>& wi) const override {
    return base_.Pdf(p, wo, wi);
  }
  double SampleWeight(const double* p) const override { return base_.SampleWeight(p); }
  bool CanSample() const override { return base_.CanSample(); }
  unsigned Kind() const override { return base_.Kind(); }
  LobeWidth Width(const double* p) const override { return base_.Width(p); }
  bool ChannelsIndependent() const override { return base_.ChannelsIndependent(); }

 private:
  const Bxdf<double>& base_;
  AlbedoLookup lookup_;
  std::size_t offset_;
};

}  // namespace brdfkit::validate
