// brdfkit stress: every registered model over extreme parameters and
// directions (validate/stress.h), stiff integrals, and stiff fits.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <optional>
#include <sstream>

#include "brdf/atomic_file.h"
#include "brdf/merl.h"
#include "cli/common.h"
#include "cli/tasks.h"
#include "fit/fit.h"
#include "validate/stress.h"

namespace brdfkit::cli {

namespace {

// A fit whose parameters differ by 1e8 in scale: a GGX peak of 1e5 1/sr
// (alpha = 1 / sqrt(4 pi 1e5), D(normal) / 4 at normal incidence with F = 1)
// over a Lambertian 0.01 1/sr. Samples: in-plane, four incidences, every 5
// degrees plus offsets from 1e-4 to 0.1 rad about the mirror direction.
struct StiffFit {
  std::string name;
  std::string start;   // "" for brdfkit's multi-start
  std::string metric;
  fit::Result result;
  double alpha_rel_error = 0, albedo_rel_error = 0;
  bool finite = false;
};

fit::Dataset SharpPeakData(const Model& model, const std::vector<double>& truth) {
  const std::unique_ptr<Bxdf<double>> b = model.Make<double>();
  fit::Dataset d;
  d.source = "sharp-peak synthetic";
  std::vector<double> offsets;
  for (double o : {1e-4, 3e-4, 1e-3, 2e-3, 5e-3, 1e-2, 3e-2, 1e-1}) {
    offsets.push_back(o);
    offsets.push_back(-o);
  }
  offsets.push_back(0);
  for (double ti_deg : {5.0, 20.0, 40.0, 60.0}) {
    const double ti = ti_deg * kPi / 180;
    std::vector<double> to_list;  // signed theta_o in the plane; > 0 on the mirror side
    for (int k = -16; k <= 16; ++k) to_list.push_back(k * 5.0 * kPi / 180);
    for (double o : offsets) to_list.push_back(ti + o);
    for (double to : to_list) {
      if (std::abs(to) >= kPi / 2) continue;
      fit::Sample s;
      s.wi = Eigen::Vector3d(std::sin(ti), 0, std::cos(ti));
      s.wo = Eigen::Vector3d(-std::sin(to), 0, std::cos(to));
      s.f = b->Eval(truth.data(), s.wi, s.wo);
      s.sigma = Eigen::Array3d::Zero();
      d.samples.push_back(s);
    }
  }
  return d;
}

std::vector<StiffFit> RunStiffFits() {
  const Model model = Model::Parse("lambert+ggx");
  const double alpha = 1.0 / std::sqrt(4 * kPi * 1e5);
  const std::string truth_text = "lambert.albedo=" + FormatDouble(0.01 * kPi) + ",ggx.alpha=" + FormatDouble(alpha);
  const std::vector<double> truth = ParseParams(model.Info(), truth_text);
  const fit::Dataset data = SharpPeakData(model, truth);
  struct Case {
    const char* name;
    const char* start;
    fit::Metric metric;
  };
  const Case cases[] = {
      {"sharp peak 1e5 over diffuse 0.01, multi-start", "", fit::Metric::kRelative},
      {"sharp peak, started far (alpha 0.5, albedo 0.9)", "lambert.albedo=0.9,ggx.alpha=0.5", fit::Metric::kRelative},
      {"sharp peak, started far, plain L2", "lambert.albedo=0.9,ggx.alpha=0.5", fit::Metric::kL2},
      {"sharp peak, started at the mirror bound (alpha 1e-7)", "lambert.albedo=0.9,ggx.alpha=1e-7", fit::Metric::kRelative},
  };
  std::vector<StiffFit> out;
  for (const Case& c : cases) {
    fit::Options o;
    o.metric = c.metric;
    o.num_threads = 2;
    if (*c.start) o.initial = ParseParams(model.Info(), c.start);
    StiffFit r;
    r.name = c.name;
    r.start = c.start;
    r.metric = fit::MetricName(c.metric);
    r.result = fit::Fit(model, data, o);
    const std::vector<double>& p = r.result.params;
    const std::size_t ia = model.Info().Offset(1);  // ggx.alpha after the 3 albedo slots
    r.alpha_rel_error = std::abs(p[ia] / alpha - 1);
    r.albedo_rel_error = std::abs(p[1] / truth[1] - 1);
    r.finite = std::isfinite(r.result.cost);
    for (double v : p) r.finite = r.finite && std::isfinite(v);
    out.push_back(std::move(r));
  }
  return out;
}

nlohmann::json RowJson(const validate::StressRow& r) {
  nlohmann::json j = {{"model", r.model},
                      {"type", r.type},
                      {"skipped", r.skipped}};
  if (r.skipped) {
    j["skip_reason"] = r.skip_reason;
    return j;
  }
  j.update({{"evaluations", r.evaluations},
            {"nonfinite_count", r.nonfinite_count},
            {"negative_count", r.negative_count},
            {"horizon_nonzero_count", r.horizon_nonzero_count},
            {"nonfinite_derivative_count", r.nonfinite_derivative_count},
            {"sample_failures", r.sample_failures},
            {"reciprocity_max_rel_error", r.reciprocity_max_rel_error},
            {"bound_checks", r.bound_checks},
            {"bound_failures", r.bound_failures}});
  if (r.type == "float") {
    j["float_double_max_rel_diff"] = r.float_double_max_rel_diff;
    j["float_double_worst_case"] = r.worst_float_case;
  } else {
    j["float_double_max_rel_diff"] = nullptr;
  }
  if (!r.first_failure.empty()) j["first_failure"] = r.first_failure;
  return j;
}

bool Clean(const validate::StressRow& r) {
  return r.skipped || (r.nonfinite_count == 0 && r.negative_count == 0 && r.horizon_nonzero_count == 0 &&
                       r.nonfinite_derivative_count == 0 && r.sample_failures == 0 && r.bound_failures == 0);
}

struct StressRun {
  std::vector<validate::StressRow> rows;
  double sweep_seconds = 0;
  std::vector<validate::StiffIntegral> integrals;
  std::vector<StiffFit> fits;
  bool clean = true;
};

StressRun RunAll(const std::vector<std::string>& models, const MeasuredFiles& files, bool sweep_only) {
  validate::StressOptions so;
  // Measured tables by their file, from the options (--rgl FILE) and from
  // the model text (rgl:FILE, as every other command takes it).
  MeasuredFiles tables = files;
  for (const std::string& spec : models) {
    const std::size_t colon = spec.find(':');
    const std::string m = spec.substr(0, colon);
    std::optional<ModelInfo> info;
    for (const ModelInfo& i : RegisteredModelInfos())
      if (i.name == m) info = i;
    if (!info)
      throw UsageError("stress: unknown model '" + m + "' (known models: " + Model::KnownNames() + ")" +
                       DidYouMean(m, Model::KnownModelNames()));
    if (colon != std::string::npos) {
      if (info->settings.empty())
        throw UsageError("stress: model '" + m + "' takes no ':' argument (got '" + spec + "')");
      tables.push_back({m, spec.substr(colon + 1)});
    }
    so.models.push_back(m);
  }
  for (const auto& [name, file] : tables)
    if (!file.empty()) {
      Settings settings;
      for (const ModelInfo& i : RegisteredModelInfos())
        if (i.name == name) settings[i.settings.front()] = file;  // the file's setting, as in "name:FILE"
      (void)Model::Parse(name, settings);  // a bad file is named here, before the sweep
      so.settings.push_back({name, settings});
    }
  const auto t0 = std::chrono::steady_clock::now();
  StressRun run;
  run.rows = validate::RunStress(so);
  run.sweep_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!sweep_only && models.empty()) {
    run.integrals = validate::RunStiffIntegrals();
    run.fits = RunStiffFits();
  }
  for (const auto& r : run.rows) run.clean = run.clean && Clean(r);
  return run;
}

nlohmann::json RunJson(const StressRun& run) {
  nlohmann::json j;
  j["models"] = nlohmann::json::array();
  for (const auto& r : run.rows) j["models"].push_back(RowJson(r));
  j["sweep_seconds"] = run.sweep_seconds;
  j["clean"] = run.clean;
  j["stiff_integrals"] = nlohmann::json::array();
  for (const auto& s : run.integrals)
    j["stiff_integrals"].push_back({{"model", s.model},
                                    {"params", s.params},
                                    {"mu", s.mu},
                                    {"albedo", s.value},
                                    {"error", s.error},
                                    {"evals", s.evals},
                                    {"reference", s.reference},
                                    {"reference_error", s.reference_error},
                                    {"reference_evals", s.reference_evals},
                                    {"seconds", s.seconds},
                                    {"finite", s.finite},
                                    {"agree", s.agree}});
  j["stiff_fits"] = nlohmann::json::array();
  for (const auto& f : run.fits)
    j["stiff_fits"].push_back({{"case", f.name},
                               {"start", f.start.empty() ? nlohmann::json("multi-start") : nlohmann::json(f.start)},
                               {"metric", f.metric},
                               {"params", FormatParams(f.result.model.Info(), f.result.params)},
                               {"alpha_rel_error", f.alpha_rel_error},
                               {"albedo_rel_error", f.albedo_rel_error},
                               {"converged", f.result.converged},
                               {"iterations", f.result.iterations},
                               {"rmse", f.result.rmse},
                               {"message", f.result.message},
                               {"seconds", f.result.seconds},
                               {"finite", f.finite}});
  return j;
}

}  // namespace

nlohmann::json StressJson(const std::vector<std::string>& models, const MeasuredFiles& files, bool sweep_only) {
  return RunJson(RunAll(models, files, sweep_only));
}

void RegisterStress(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "stress", "sweep every model over extreme parameters and directions in float, double and Jet; stiff "
                "integrals and fits");
  static std::vector<std::string> models;
  static std::string merl, output;
  static bool json = false, sweep_only = false;
  cmd->add_option("--model,-m", models,
                  "registered model name (repeat for several), a measured table with its file (merl:FILE, rgl:FILE, "
                  "utia:FILE, astm:FILE); default: every model");
  cmd->add_option("--merl", merl, "a MERL .binary file to sweep the merl model over (otherwise it is skipped)");
  static std::string rgl, utia, astm;
  cmd->add_option("--rgl", rgl, "an RGL .bsdf file for the rgl model (otherwise it is skipped)");
  cmd->add_option("--utia", utia, "a UTIA file for the utia model (otherwise it is skipped)");
  cmd->add_option("--astm", astm, "an ASTM E1392 table for the astm model (otherwise it is skipped)");
  cmd->add_flag("--json", json, "print JSON: one object per model and type, plus the stiff cases");
  cmd->add_flag("--sweep-only", sweep_only, "skip the stiff integrals and fits");
  cmd->add_option("--output,-o", output, "also write the JSON report to this file (written atomically)");
  cmd->callback([] {
    const StressRun run = RunAll(models, {{"merl", merl}, {"rgl", rgl}, {"utia", utia}, {"astm", astm}}, sweep_only);
    const nlohmann::json j = RunJson(run);
    const auto& rows = run.rows;
    const auto& integrals = run.integrals;
    const auto& fits = run.fits;
    const bool clean = run.clean;
    const double sweep_seconds = run.sweep_seconds;
    if (!output.empty()) WriteFileAtomic(output, j.dump(2) + "\n");
    if (json) {
      std::cout << j.dump(2) << "\n";
    } else {
      std::printf("%-20s %-6s %8s %9s %8s %8s %9s %7s %11s %11s %7s\n", "model", "type", "evals", "nonfinite",
                  "negative", "horizon", "d/dp!fin", "sample", "reciprocity", "float/dbl", "bounds");
      for (const auto& r : rows) {
        if (r.skipped) {
          std::printf("%-20s %-6s skipped: %s\n", r.model.c_str(), r.type.c_str(), r.skip_reason.c_str());
          continue;
        }
        char fd[32] = "-";
        if (r.type == "float") std::snprintf(fd, sizeof fd, "%.3g", r.float_double_max_rel_diff);
        std::printf("%-20s %-6s %8lld %9lld %8lld %8lld %9lld %7lld %11.3g %11s %3lld/%-3lld\n", r.model.c_str(),
                    r.type.c_str(), static_cast<long long>(r.evaluations), static_cast<long long>(r.nonfinite_count),
                    static_cast<long long>(r.negative_count), static_cast<long long>(r.horizon_nonzero_count),
                    static_cast<long long>(r.nonfinite_derivative_count), static_cast<long long>(r.sample_failures),
                    r.reciprocity_max_rel_error, fd,
                    static_cast<long long>(r.bound_checks - r.bound_failures), static_cast<long long>(r.bound_checks));
        if (!r.first_failure.empty()) std::printf("    first failure: %s\n", r.first_failure.c_str());
      }
      std::printf("columns: non-finite and negative values, non-zero values at/below the horizon, non-finite\n"
                  "derivatives (Jet), bad samples/pdfs, max relative reciprocity error, max relative float-double\n"
                  "difference at the same float inputs, out-of-range values rejected / offered. Sweep: %.2f s\n",
                  sweep_seconds);
      if (!integrals.empty()) std::printf("\nstiff integrals (directional albedo, green channel):\n");
      for (const auto& s : integrals)
        std::printf("  %-10s %-26s mu=%g: E = %.9f +- %.1e (%lld evals), adaptive rule %.9f +- %.1e (%lld evals): %s\n",
                    s.model.c_str(), s.params.c_str(), s.mu, s.value, s.error, static_cast<long long>(s.evals),
                    s.reference, s.reference_error, static_cast<long long>(s.reference_evals),
                    !s.finite ? "NON-FINITE" : s.agree ? "agree" : "DISAGREE");
      if (!fits.empty()) std::printf("\nstiff fits (lambert+ggx, truth albedo 0.01 pi, alpha %.4g):\n", 1.0 / std::sqrt(4 * kPi * 1e5));
      for (const auto& f : fits)
        std::printf("  %s [%s]: %s after %d iterations, %.2f s; alpha off by %.2g, albedo by %.2g (relative); %s\n",
                    f.name.c_str(), f.metric.c_str(), f.result.converged ? "converged" : "NOT converged",
                    f.result.iterations, f.result.seconds, f.alpha_rel_error, f.albedo_rel_error,
                    f.finite ? FormatParams(f.result.model.Info(), f.result.params).c_str() : "NON-FINITE");
      std::printf("\n%s\n", clean ? "stress: clean (no non-finite or negative value, every bound enforced)"
                                  : "stress: FAILURES (see first failure lines)");
    }
    if (!clean) throw std::runtime_error("stress: some models produced non-finite or negative values");
  });
}

}  // namespace brdfkit::cli
