// brdfkit convergence: every hemisphere integrator at increasing budgets on
// reference integrals with exact values; error against time as CSV, an SVG
// log-log plot and a summary of the time needed to reach 1e-3, 1e-6, 1e-9.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <map>
#include <sstream>

#include "brdf/atomic_file.h"
#include "cli/common.h"
#include "cli/progress.h"
#include "cli/tasks.h"
#include "validate/integrators.h"
#include "validate/plot.h"
#include "validate/references.h"

namespace brdfkit::cli {

namespace {

using validate::Estimate;
using validate::IntegrateOptions;
using validate::Method;
using validate::ReferenceCase;

struct Row {
  Method method;
  std::string case_name;
  std::int64_t budget = 0;
  Estimate estimate;
  double abs_error = 0;
  double est_error = 0;
};

// Cases of the default study: smooth and diffuse, grazing, narrow lobes
// (alpha 1e-3, n = 1e6), a kinked diffuse model and an average albedo.
const std::vector<std::string>& DefaultCases(bool quick) {
  static const std::vector<std::string> kFull = {
      "lambert_mu0.5",          "ggx_alpha1_mu0.5",          "ggx_alpha1_mu0.01",
      "ggx_separable_alpha1_mu0.1", "furnace_ggx_alpha0.1_mu0.5", "furnace_beckmann_alpha0.01_mu0.1",
      "furnace_ggx_alpha0.001_mu0.5", "cosine_power_n10000",     "phong_original_n1e+06_mu0.5",
      "oren_nayar_fujii_mu1",   "oren_nayar_fujii_avg"};
  static const std::vector<std::string> kQuick = {"ggx_alpha1_mu0.5", "furnace_ggx_alpha0.1_mu0.5",
                                                  "oren_nayar_fujii_mu1"};
  return quick ? kQuick : kFull;
}

std::vector<std::int64_t> Budgets(Method m, bool quick) {
  std::vector<std::int64_t> out;
  // Adaptive and Gauss-Legendre budgets start where their rules start
  // (one 15 x 15 product rule; a 2 x 4 grid).
  const std::int64_t first = m == Method::kAdaptive ? 450 : m == Method::kGaussLegendre ? 32 : 256;
  // Sampling methods stop at 2^18 samples: their 1/sqrt(N) slope is plain by then.
  const bool sampling = m != Method::kAdaptive && m != Method::kGaussLegendre;
  const int steps = quick ? 4 : sampling ? 6 : 7;
  std::int64_t b = first;
  for (int i = 0; i < steps; ++i, b *= 4) out.push_back(b);
  return out;
}

}  // namespace

ConvergenceOutcome RunConvergence(const std::string& out_dir, const std::vector<std::string>& method_names, bool quick,
                                  bool all_cases, bool quiet) {
  std::vector<Method> methods;
  try {
    for (const std::string& n : method_names) methods.push_back(validate::ParseMethod(n));
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("--methods: ") + e.what());
  }
  if (methods.empty()) methods = validate::AllMethods();

  std::vector<ReferenceCase> cases;
  {
    std::vector<ReferenceCase> all = validate::ReferenceCases();
    if (all_cases) {
      cases = std::move(all);
    } else {
      for (const std::string& name : DefaultCases(quick))
        for (ReferenceCase& c : all)
          if (c.name == name) cases.push_back(c);
    }
  }
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  if (!fs::is_directory(out_dir)) throw UsageError("--out: cannot create directory '" + out_dir + "'");

  std::vector<Row> rows;
  std::size_t total = 0;
  for (Method m : methods) total += cases.size() * Budgets(m, quick).size();
  Progress progress("convergence", double(total), quiet);
  for (Method m : methods) {
    for (const ReferenceCase& c : cases) {
      for (std::int64_t budget : Budgets(m, quick)) {
        ThrowIfInterrupted();
        progress.Update(double(rows.size()), validate::MethodName(m));
        IntegrateOptions o;
        o.budget = budget;
        o.seed = 1;
        // Adaptive: spend the budget (tolerances below double precision).
        o.abs_tolerance = 0;
        o.rel_tolerance = 1e-15;
        Row r;
        r.method = m;
        r.case_name = c.name;
        r.budget = budget;
        r.estimate = c.integrate(m, o);
        r.abs_error = validate::TrueError(c, r.estimate);
        r.est_error = validate::EstimatedError(r.estimate);
        rows.push_back(r);
      }
    }
  }

  // CSV.
  {
    std::ostringstream csv;
    csv << "integrator,case,budget,evals,seconds,abs_error,est_error\n";
    for (const Row& r : rows)
      csv << validate::MethodName(r.method) << ',' << r.case_name << ',' << r.budget << ',' << r.estimate.evals
          << ',' << FormatShort(r.estimate.seconds) << ',' << FormatShort(r.abs_error) << ','
          << FormatShort(r.est_error) << '\n';
    WriteFileAtomic(fs::path(out_dir) / "convergence.csv", csv.str());
  }

  // One series per integrator: at each budget step, the mean time per case
  // against the worst error over the cases (floored at 1e-17 for the log axis).
  std::vector<validate::Series> series;
  for (Method m : methods) {
    validate::Series s;
    s.label = validate::MethodName(m);
    for (std::int64_t budget : Budgets(m, quick)) {
      double t = 0, worst = 0;
      int n = 0;
      for (const Row& r : rows)
        if (r.method == m && r.budget == budget) {
          t += r.estimate.seconds;
          worst = std::max(worst, r.abs_error);
          ++n;
        }
      if (n == 0) continue;
      s.x.push_back(std::max(t / n, 1e-7));
      s.y.push_back(std::max(worst, 1e-17));
    }
    series.push_back(s);
  }
  validate::LinePlot((fs::path(out_dir) / "convergence.svg").string(),
                     "hemisphere integrators: worst error over " + std::to_string(cases.size()) + " reference integrals",
                     "mean time per integral [s]", "absolute error", series, true, true);

  // Summary: per integrator and threshold, the time of the first budget
  // meeting it, on every case (the slowest case decides).
  const double thresholds[3] = {1e-3, 1e-6, 1e-9};
  std::ostringstream md;
  md << "# Hemisphere integrators: time to reach an absolute error\n\n"
     << "Time of the smallest budget whose error is below the threshold, for the slowest of "
     << cases.size() << " reference integrals (";
  for (std::size_t i = 0; i < cases.size(); ++i) md << (i ? ", " : "") << cases[i].name;
  md << ").\n\n| integrator | 1e-3 | 1e-6 | 1e-9 |\n|---|---|---|---|\n";
  for (Method m : methods) {
    md << "| " << validate::MethodName(m);
    for (double thr : thresholds) {
      double worst_time = 0;
      int reached = 0;
      for (const ReferenceCase& c : cases) {
        double t = -1;
        for (const Row& r : rows)
          if (r.method == m && r.case_name == c.name && r.abs_error <= thr) {
            t = r.estimate.seconds;
            break;
          }
        if (t >= 0) {
          ++reached;
          worst_time = std::max(worst_time, t);
        }
      }
      if (reached == int(cases.size())) {
        md << " | " << FormatShort(worst_time) << " s";
      } else {
        md << " | not reached (" << reached << "/" << cases.size() << " cases)";
      }
    }
    md << " |\n";
  }
  WriteFileAtomic(fs::path(out_dir) / "convergence_summary.md", md.str());
  ConvergenceOutcome outcome;
  outcome.summary_markdown = md.str();
  outcome.rows = rows.size();
  outcome.cases = cases.size();
  return outcome;
}

void RegisterConvergence(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "convergence", "error against time of every hemisphere integrator on reference integrals with exact values");
  static std::string out_dir = ".";
  static std::vector<std::string> method_names;
  static bool quick = false, all_cases = false;
  cmd->add_option("--out", out_dir, "output directory (created if missing)");
  cmd->add_option("--methods", method_names,
                  "integrators to run (default all): uniform, cosine, importance, sobol, gauss_legendre, adaptive")
      ->delimiter(',');
  cmd->add_flag("--quick", quick, "three cases and four budgets per integrator (a few seconds)");
  cmd->add_flag("--all-cases", all_cases, "every reference integral instead of the default selection");
  cmd->callback([] {
    const ConvergenceOutcome o = RunConvergence(out_dir, method_names, quick, all_cases, false);
    std::cout << o.summary_markdown;
    std::cout << "wrote " << (std::filesystem::path(out_dir) / "convergence.csv").string() << ", convergence.svg, "
              << "convergence_summary.md\n";
  });
}

}  // namespace brdfkit::cli
