// Pieces of the subcommands that `brdfkit run` reuses for scene tasks.
#pragma once

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace brdfkit::validate {
struct CheckResult;
struct AlbedoTable;
struct Preset;
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
// --loss text ("none", "huber", "cauchy:0.5") into the options; throws UsageError.
void ParseFitLoss(const std::string& text, fit::Options& o);

// cmd_albedo.cpp: the JSON of `brdfkit albedo --json`.
nlohmann::json AlbedoTableJson(const validate::AlbedoTable& t);
// cmd_albedo.cpp: the JSON of `brdfkit albedo --preset NAME --json`.
nlohmann::json PresetJson(const validate::Preset& p);

// cmd_stress.cpp: the JSON of `brdfkit stress --json` for registered model
// names (empty: every model), an optional MERL file for the merl model, and
// the stiff integrals and fits unless sweep_only (or models are named).
// Measured models and their files (merl, rgl, utia, astm); an empty path skips the model.
using MeasuredFiles = std::vector<std::pair<std::string, std::string>>;
nlohmann::json StressJson(const std::vector<std::string>& models, const MeasuredFiles& files, bool sweep_only);

// cmd_convergence.cpp: writes convergence.csv, convergence.svg and
// convergence_summary.md into out_dir.
struct ConvergenceOutcome {
  std::string summary_markdown;
  std::size_t rows = 0, cases = 0;
};
ConvergenceOutcome RunConvergence(const std::string& out_dir, const std::vector<std::string>& method_names, bool quick,
                                  bool all_cases, bool quiet);

}  // namespace brdfkit::cli
