// Shared pieces of the command-line tool: model and parameter options,
// direction parsing, errors.
#pragma once

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <string>
#include <vector>

#include "brdf/model.h"
#include "brdf/params.h"

namespace brdfkit::cli {

// An error the user caused (bad option value, bad file): reported as
// "brdfkit: error: <message>" with exit code 2.
class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A result that misses its own accuracy contract (an albedo table whose
// error estimates exceed the tolerance): reported as "brdfkit: error:
// <message>" with exit code 1, and nothing is written.
class ResultError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The thread count of `--threads N`, the same for every command: 0 means
// every core TBB sees (affinity and cgroup limits included); more than that
// is capped at it, with a note on stderr; a negative count is a UsageError.
int ThreadCount(int requested);

struct ModelArgs {
  std::string model;
  std::string params;
};

void AddModelOptions(CLI::App* cmd, ModelArgs& args, bool required = true);

struct LoadedModel {
  Model model;
  std::vector<double> params;
  Settings settings;  // those given with the parameters (e.g. path=)
};

// Parses --model and --params (settings such as path= go to the model).
LoadedModel LoadModel(const ModelArgs& args);

// "x,y,z" (normalised) or, with degrees = true, "theta,phi" in degrees.
Eigen::Vector3d ParseDirection(const std::string& text, bool degrees, const std::string& option);

// The prefix of an albedo header's arrays named after `name` (a model
// specification or a material): name_albedo as a C identifier, other
// characters '_', "m_" before a leading digit.
std::string AlbedoHeaderPrefix(const std::string& name);

nlohmann::json ModelInfoJson(const ModelInfo& info);
// The README's table of registered models (`brdfkit models --markdown`).
std::string ModelTableMarkdown();

// Subcommands; each file cli/cmd_<name>.cpp defines one.
void RegisterModels(CLI::App& app);
void RegisterEval(CLI::App& app);
void RegisterRun(CLI::App& app);
void RegisterFit(CLI::App& app);  LoadedModel LoadFitModel(const std::string& path);  // cmd_fit.cpp
void RegisterSynth(CLI::App& app);
void RegisterConvergence(CLI::App& app);  // cmd_convergence.cpp
void RegisterCheck(CLI::App& app);   // cmd_check.cpp
void RegisterAlbedo(CLI::App& app);  // cmd_albedo.cpp
void RegisterStress(CLI::App& app);  // cmd_stress.cpp
void RegisterConvert(CLI::App& app);  // cmd_convert.cpp
void RegisterView(CLI::App& app);    // cmd_view.cpp

}  // namespace brdfkit::cli
