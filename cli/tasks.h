// Pieces of the subcommands that `brdfkit run` reuses for scene tasks.
#pragma once

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace brdfkit::validate {
struct CheckResult;
}
namespace brdfkit::fit {
struct Result;
struct Options;
}  // namespace brdfkit::fit

namespace brdfkit::cli {

// cmd_check.cpp: the JSON keys of `brdfkit check --json`.
nlohmann::json CheckResultJson(const validate::CheckResult& r);

// cmd_fit.cpp: the JSON of `brdfkit fit --json` (readable by --model fit:FILE),
// the per-iteration trace as CSV, and its plot (metric against time).
nlohmann::json FitResultJson(const fit::Result& r, const fit::Options& o);
std::string FitTraceCsv(const fit::Result& r);
void WriteFitTracePlot(const std::string& path, const fit::Result& r);

// cmd_convergence.cpp: writes convergence.csv, convergence.svg and
// convergence_summary.md into out_dir.
struct ConvergenceOutcome {
  std::string summary_markdown;
  std::size_t rows = 0, cases = 0;
};
ConvergenceOutcome RunConvergence(const std::string& out_dir, const std::vector<std::string>& method_names, bool quick,
                                  bool all_cases, bool quiet);

}  // namespace brdfkit::cli
