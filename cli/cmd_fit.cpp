// brdfkit fit: least-squares fit of a model to tabulated reflectance.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>

#include <tbb/task_arena.h>

#include "brdf/atomic_file.h"
#include "cli/common.h"
#include "cli/tasks.h"
#include "data_synth/instrument.h"
#include "fit/fit.h"
#include "validate/plot.h"

namespace brdfkit::cli {
namespace {

nlohmann::json Number(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

// name -> value, or [r, g, b] for colour parameters.
nlohmann::json ParamsJson(const ModelInfo& info, const std::vector<double>& packed) {
  nlohmann::json j = nlohmann::json::object();
  std::size_t k = 0;
  for (const ParamInfo& p : info.params) {
    if (p.colour) {
      j[p.name] = {Number(packed[k]), Number(packed[k + 1]), Number(packed[k + 2])};
      k += 3;
    } else {
      j[p.name] = Number(packed[k++]);
    }
  }
  return j;
}

nlohmann::json ResultJson(const fit::Result& r, const fit::Options& o) {
  const ModelInfo& info = r.model.Info();
  nlohmann::json j;
  j["model"] = r.model.Spec();
  j["params"] = ParamsJson(info, r.params);
  j["stddev"] = ParamsJson(info, r.stddev);
  if (r.covariance_ok) {
    nlohmann::json m = nlohmann::json::array();
    for (Eigen::Index i = 0; i < r.correlation.rows(); ++i) {
      nlohmann::json row = nlohmann::json::array();
      for (Eigen::Index k = 0; k < r.correlation.cols(); ++k) row.push_back(Number(r.correlation(i, k)));
      m.push_back(row);
    }
    j["correlation"] = {{"names", r.packed_names}, {"matrix", m}};
  } else {
    j["correlation"] = nullptr;
  }
  j["uncertainty"] = r.covariance_message.empty() ? "ok" : r.covariance_message;
  j["metric"] = fit::MetricName(o.metric);
  j["solver"] = fit::LinearSolverName(o.solver);
  j["loss"] = fit::LossName(o.loss);
  if (o.loss != fit::Loss::kNone) j["loss_scale"] = r.loss_scale;
  j["cost"] = r.cost;
  j["rmse"] = r.rmse;
  j["chi2_reduced"] = Number(r.chi2_reduced);
  if (!std::isfinite(r.chi2_reduced))
    j["chi2_note"] = "null: the data carry no sigma, so there is no stated noise to compare the residuals with";
  const auto stats = [](const fit::ErrorStats& e) {
    return nlohmann::json{{"count", e.count}, {"median", Number(e.median)}, {"p95", Number(e.p95)}, {"max", Number(e.max)}};
  };
  j["relative_error"] = stats(r.relative_error);
  nlohmann::json bands = nlohmann::json::array();
  for (const fit::BandStats& b : r.relative_error_bands) {
    nlohmann::json e = stats(b.stats);
    e["theta_h_deg"] = {b.theta_h_min_deg, b.theta_h_max_deg};
    bands.push_back(e);
  }
  j["relative_error_bands"] = bands;
  j["relative_error_definition"] =
      "|f_fit - f_data| / max(f_data, 1e-3 x the channel's mean), per sample and channel, over the samples used";
  j["stddev_meaning"] =
      "statistical given the model: how well the data determine this model's parameters, not how far the model is "
      "from the material";
  std::vector<std::string> fixed;
  nlohmann::json tied = nlohmann::json::object();
  for (std::size_t i = 0, k = 0; i < info.params.size(); k += info.params[i].colour ? 3 : 1, ++i) {
    if (k < r.fixed.size() && r.fixed[k]) fixed.push_back(info.params[i].name);
    if (k < r.tied_to.size() && !r.tied_to[k].empty()) {
      std::string leader = r.tied_to[k];
      if (info.params[i].colour) leader = leader.substr(0, leader.rfind('.'));  // "ggx.f0.r" -> "ggx.f0"
      tied[info.params[i].name] = leader;
    }
  }
  j["fixed"] = fixed;
  j["tied"] = tied;
  nlohmann::json optima = nlohmann::json::array();
  for (const fit::LocalOptimum& l : r.local_optima)
    optima.push_back({{"cost", l.cost}, {"params", ParamsJson(info, l.params)}, {"origin", l.origin}});
  j["local_optima"] = optima;
  j["kept"] = r.kept;
  j["warnings"] = r.warnings;
  j["iterations"] = r.iterations;
  j["starts"] = r.starts;
  j["seconds"] = r.seconds;
  j["converged"] = r.converged;
  j["message"] = r.message;
  j["samples"] = r.used;
  j["missing"] = r.missing;
  j["dropped_angle"] = r.dropped_angle;
  nlohmann::json trace = nlohmann::json::array();
  for (const fit::TracePoint& t : r.trace)
    trace.push_back({{"iteration", t.iteration}, {"seconds", t.seconds}, {"cost", t.cost}, {"rmse", t.rmse},
                     {"start", t.start}, {"stage", t.stage}});
  j["trace"] = trace;
  return j;
}

std::string TraceCsv(const fit::Result& r) {
  std::string s = "iteration,seconds,cost,rmse,start,stage\n";
  char buf[160];
  for (const fit::TracePoint& t : r.trace) {
    std::snprintf(buf, sizeof buf, "%d,%.9g,%.17g,%.17g,%d,", t.iteration, t.seconds, t.cost, t.rmse, t.start);
    s += buf;
    s += "\"" + t.stage + "\"\n";  // stage names hold no quotes
  }
  return s;
}

// "huber", "cauchy:0.5".
void ParseLoss(const std::string& text, fit::Options& o) {
  const std::string name = text.substr(0, text.find(':'));
  try {
    o.loss = fit::ParseLoss(name);
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("--loss: ") + e.what() + ", optionally with :scale");
  }
  if (text.find(':') != std::string::npos) {
    const std::string v = text.substr(text.find(':') + 1);
    if (!ParseDouble(v, o.loss_scale) || !(o.loss_scale > 0) || !std::isfinite(o.loss_scale))
      throw UsageError("--loss: scale '" + v + "' is not a positive number");
  }
}

// Metric RMSE against seconds (initialisation included), log-log: each
// multi-start solve (on its subset) and, for a sum, each sub-sum's solve in
// grey, the final solve in colour.
void WriteTracePlot(const std::string& path, const fit::Result& r) {
  std::vector<validate::Series> series;
  int last_start = -1;
  for (const fit::TracePoint& t : r.trace) {
    if (!(t.seconds > 0 && t.rmse > 0)) continue;  // log axes
    if (t.start != last_start) {
      const bool first_start = t.start > 0 && last_start < 0;
      const bool sum = r.model.LobeCount() > 1;
      std::string label = t.start == 0 ? "final, all samples"
                          : !first_start ? ""
                          : sum ? std::to_string(r.starts) + " starts and sub-sums"
                                : std::to_string(r.starts) + " starts, subset";
      series.push_back({label, {}, {}});
      series.back().colour = t.start == 0 ? 0 : validate::kGrey;
      last_start = t.start;
    }
    series.back().x.push_back(t.seconds);
    series.back().y.push_back(t.rmse);
  }
  validate::LinePlot(path, "fit " + r.model.Spec() + ": error against run time", "run time [s]",
                     fit::MetricName(r.metric) + " RMSE", series, true, true);
}

}  // namespace

nlohmann::json FitResultJson(const fit::Result& r, const fit::Options& o) { return ResultJson(r, o); }
std::string FitTraceCsv(const fit::Result& r) { return TraceCsv(r); }
void WriteFitTracePlot(const std::string& path, const fit::Result& r) { WriteTracePlot(path, r); }
void ParseFitLoss(const std::string& text, fit::Options& o) { ParseLoss(text, o); }

LoadedModel LoadFitModel(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw UsageError("cannot read fit result '" + path + "'");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(in);
  } catch (const nlohmann::json::exception& e) {
    throw UsageError("fit result '" + path + "' is not valid JSON: " + e.what());
  }
  if (!j.is_object() || !j.contains("model") || !j["model"].is_string() || !j.contains("params") ||
      !j["params"].is_object())
    throw UsageError("fit result '" + path + "' lacks \"model\" (string) and \"params\" (object)");
  LoadedModel out{Model::Parse(j["model"].get<std::string>()), {}, {}};
  const ModelInfo& info = out.model.Info();
  out.params = info.Defaults();
  for (std::size_t i = 0; i < info.params.size(); ++i) {
    const ParamInfo& p = info.params[i];
    if (!j["params"].contains(p.name)) {
      // A lobe weight of a sum is 1 (its default) in results written before sums had weights.
      if (p.name.size() > 7 && p.name.compare(p.name.size() - 7, 7, ".weight") == 0) continue;
      throw UsageError("fit result '" + path + "': no value for '" + p.name + "'");
    }
    const nlohmann::json& v = j["params"][p.name];
    const std::size_t off = info.Offset(i);
    if (p.colour && v.is_array() && v.size() == 3 && v[0].is_number() && v[1].is_number() && v[2].is_number()) {
      for (int c = 0; c < 3; ++c) out.params[off + c] = v[c].get<double>();
    } else if (v.is_number()) {
      for (int c = 0; c < (p.colour ? 3 : 1); ++c) out.params[off + c] = v.get<double>();
    } else {
      throw UsageError("fit result '" + path + "': '" + p.name + "' must be " +
                       (p.colour ? "a number or [r, g, b]" : "a number"));
    }
  }
  try {
    ValidateParams(info, out.params);
  } catch (const ModelError& e) {
    throw UsageError("fit result '" + path + "': " + e.what());
  }
  return out;
}

void RegisterFit(CLI::App& app) {
  auto* cmd =
      app.add_subcommand("fit", "fit a model to tabulated reflectance (CSV table, MERL, RGL, UTIA or ASTM file) with Ceres");
  static std::string data, model, init, metric = "l2", loss = "none", solver = "dense_qr", instrument, out, trace,
                     trace_plot;
  static std::vector<std::string> fix, tie, bounds;
  static double max_theta = -1;
  static int threads = 0, max_iter = 200, starts = 5, aperture_order = 0, random_starts = 0;
  static std::uint64_t seed = 1;
  static bool json = false, no_cov = false, ignore_sigma = false;
  cmd->add_option("--data,-d", data,
                  "CSV table (theta_i,phi_i,theta_o,phi_o,f_r,f_g,f_b[,sigma_*]), MERL .binary, RGL .bsdf, UTIA "
                  ".utia/.bin or ASTM .astm (samples at the file's own nodes)")
      ->required();
  cmd->add_option("--model,-m", model, "model or sum of lobes (lambert+ggx), or fit:FILE to refine a previous fit")
      ->required();
  cmd->add_option("--init", init, "initial guess name=value,... (default: multi-start over roughness-like parameters)");
  cmd->add_option("--metric", metric,
                  "l2 (default), relative, cosine (Ngan 2005), log (Low 2012) or cbrt (Fores 2012); for measured "
                  "data without sigma, cbrt or log weight the specular peak and the diffuse tail alike");
  cmd->add_option("--max-theta-deg", max_theta, "drop samples with theta_i or theta_o above this (default 80 for cosine)");
  cmd->add_option("--loss", loss, "robust loss: none, huber or cauchy, with optional :scale");
  cmd->add_option("--solver", solver, "linear solver: dense_qr, dense_normal_cholesky, iterative_schur or cgnr");
  cmd->add_option("--threads", threads, "threads (default 0: every core; more than the cores are capped)");
  cmd->add_option("--max-iterations", max_iter, "iterations of the final solve (default 200)");
  cmd->add_option("--starts", starts, "starts per roughness-like parameter (default 5)");
  cmd->add_option("--random-starts", random_starts,
                  "replace the start search by N random starts, each solved to convergence (an independent check "
                  "of the global optimum; default 0: off)");
  cmd->add_option("--seed", seed, "seed of --random-starts (default 1)");
  cmd->add_option("--fix", fix, "hold parameters fixed: name=value (colour: v or r:g:b), repeatable or comma-separated");
  cmd->add_option("--tie", tie, "tie parameters: follower=leader (same kind and size), repeatable");
  cmd->add_option("--bounds", bounds, "narrow a parameter's range: name=lo:hi within the model's, repeatable");
  cmd->add_flag("--no-covariance", no_cov, "skip the uncertainty computation");
  cmd->add_flag("--ignore-sigma", ignore_sigma, "do not weight by the table's sigma columns");
  cmd->add_option("--instrument", instrument, "instrument JSON: fit through its finite apertures");
  cmd->add_option("--aperture-order", aperture_order, "aperture quadrature order for --instrument (default: its own; automatic: per-pair adaptive, as synth)");
  cmd->add_flag("--json", json, "print the result as JSON");
  cmd->add_option("--out,-o", out, "write the result JSON to FILE (usable as --model fit:FILE)");
  cmd->add_option("--trace", trace, "write the per-iteration trace (seconds, cost, rmse) as CSV");
  cmd->add_option("--trace-plot", trace_plot, "draw the trace (metric against time) as SVG");
  cmd->callback([] {
    fit::Options o;
    try {
      o.metric = fit::ParseMetric(metric);
      o.solver = fit::ParseLinearSolver(solver);
    } catch (const std::invalid_argument& e) {
      throw UsageError(e.what());
    }
    ParseLoss(loss, o);
    o.random_starts = random_starts;
    o.seed = seed;
    o.max_theta_deg = max_theta;
    o.num_threads = ThreadCount(threads);
    o.max_iterations = max_iter;
    o.starts_per_param = starts;
    o.covariance = !no_cov;
    o.use_sigma = !ignore_sigma;
    try {
      fit::CheckOptions(o, [](const std::string& field) {
        std::string flag = field == "starts_per_param" ? "starts" : field;
        std::replace(flag.begin(), flag.end(), '_', '-');
        return "--" + flag;
      });
    } catch (const std::invalid_argument& e) {
      throw UsageError(e.what());
    }

    Model m = Model::Parse("lambert");
    if (model.rfind("fit:", 0) == 0) {
      LoadedModel lm = LoadFitModel(model.substr(4));
      m = lm.model;
      if (init.empty()) o.initial = lm.params;
    } else {
      m = Model::Parse(model);
    }
    if (!init.empty()) o.initial = ParseParams(m.Info(), init);
    const auto join = [](const std::vector<std::string>& v) {
      std::string s;
      for (const std::string& x : v) s += (s.empty() ? "" : ",") + x;
      return s;
    };
    o.fix = join(fix);
    o.tie = join(tie);
    o.bounds = join(bounds);
    try {
      fit::CheckConstraints(m.Info(), o);
    } catch (const std::invalid_argument& e) {
      throw UsageError(std::string("--") + e.what());
    }

    synth::Instrument inst;
    if (!instrument.empty()) {
      inst = synth::LoadInstrument(instrument);
      o.instrument = &inst;
      o.aperture_order = aperture_order;
    }
    // Readers that convert in parallel (MERL) use the fit's threads.
    tbb::task_arena load_arena(o.num_threads);
    const fit::Dataset ds = load_arena.execute([&] { return fit::LoadDataset(data); });
    if (ds.missing > 0)
      std::fprintf(stderr, "brdfkit: %zu missing sample(s) in '%s' skipped\n", ds.missing, data.c_str());
    const fit::Result r = fit::Fit(m, ds, o);
    for (const std::string& w : r.warnings) std::fprintf(stderr, "brdfkit: warning: %s\n", w.c_str());
    const nlohmann::json j = ResultJson(r, o);
    if (!out.empty()) WriteFileAtomic(out, j.dump(2) + "\n");
    if (!trace.empty()) WriteFileAtomic(trace, TraceCsv(r));
    if (!trace_plot.empty()) WriteTracePlot(trace_plot, r);
    if (json) {
      std::cout << j.dump(2) << "\n";
      return;
    }
    std::printf("model    %s\n", r.model.Spec().c_str());
    const std::vector<std::string> names = r.packed_names;
    for (std::size_t k = 0; k < names.size(); ++k)
      std::printf("  %-24s %.9g +- %.3g%s\n", names[k].c_str(), r.params[k], r.stddev[k],
                  r.fixed[k] ? " (fixed)" : !r.tied_to[k].empty() ? (" (tied to " + r.tied_to[k] + ")").c_str() : "");
    if (r.local_optima.size() > 1)
      std::printf("optima   %zu distinct local optima on all samples; kept the one of cost %.6g\n",
                  r.local_optima.size(), r.local_optima[std::size_t(std::max(r.kept, 0))].cost);
    std::printf("metric   %s, rmse %.6g, cost %.6g, %d iterations (%d starts), %.3f s, %s\n",
                fit::MetricName(o.metric).c_str(), r.rmse, r.cost, r.iterations, r.starts, r.seconds,
                r.converged ? "converged" : "NOT converged");
    std::printf("samples  %zu used, %zu missing, %zu beyond the angle cut\n", r.used, r.missing, r.dropped_angle);
    if (std::isfinite(r.chi2_reduced)) std::printf("chi2     reduced chi-square %.6g (residuals weighted by the data's sigma)\n", r.chi2_reduced);
    else std::printf("chi2     not available: the data carry no sigma\n");
    const fit::ErrorStats& e = r.relative_error;
    std::printf("rel err  |f_fit - f_data| / f_data: median %.3g, 95th percentile %.3g, max %.3g\n", e.median, e.p95, e.max);
    for (const fit::BandStats& b : r.relative_error_bands)
      std::printf("         theta_h %2g-%2g deg: median %.3g, 95th percentile %.3g, max %.3g (%zu values)\n",
                  b.theta_h_min_deg, b.theta_h_max_deg, b.stats.median, b.stats.p95, b.stats.max, b.stats.count);
    std::printf("note     +- are standard deviations, statistical given the model (not the model's distance from the material)\n");
    if (!r.covariance_message.empty()) std::printf("note     %s\n", r.covariance_message.c_str());
    if (!r.converged) std::printf("solver   %s\n", r.message.c_str());

  });
}

}  // namespace brdfkit::cli
