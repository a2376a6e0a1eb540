// `brdfkit run`: with no scene, a short demonstration of the model library
// and its checks over every registered model at default parameters.
#include <cstdio>

#include "cli/common.h"
#include "validate/check.h"

namespace brdfkit::cli {

namespace {

void Demo() {
  std::printf("brdfkit demonstration: plausibility of every model at its default parameters\n\n");
  std::printf("%-18s %11s %10s %8s %8s %9s  %s\n", "model", "recip.err", "E max", "at mu", "chi2 p", "seconds",
              "verdict");
  validate::CheckOptions opt;
  opt.random_pairs = 1000;
  opt.sampling_samples = 20000;
  opt.golden_steps = 6;
  for (const ModelInfo& info : RegisteredModelInfos()) {
    if (!info.settings.empty()) continue;  // needs a file (e.g. merl)
    const Model model = Model::Parse(info.name);
    const auto bxdf = model.Make<double>();
    const std::vector<double> p = info.Defaults();
    const validate::CheckResult r = validate::CheckPlausibility(*bxdf, p.data(), opt);
    std::string verdict = r.plausible ? "plausible" : "IMPLAUSIBLE:";
    for (const std::string& reason : r.reasons) verdict += " " + reason.substr(0, reason.find(' ')) + ";";
    std::printf("%-18s %11.2e %10.6f %8.2g %8.3f %9.2f  %s\n", info.name.c_str(), r.reciprocity_max_rel_error,
                r.albedo_max, r.albedo_max_at_mu, r.chi2_p_value, r.seconds, verdict.c_str());
  }
  std::printf("\nrecip.err: largest |f(wi,wo) - f(wo,wi)| / max f; E max: largest directional albedo over wo\n"
              "(any channel) and the mu where it occurs; chi2 p: sampling against the pdf (Sidak-corrected).\n"
              "Details: brdfkit check --model NAME [--json]; tables: brdfkit albedo; see README.\n");
}

}  // namespace

void RegisterRun(CLI::App& app) {
  auto* cmd = app.add_subcommand("run", "run a job; with no scene, a demonstration of the models and checks");
  cmd->callback([] { Demo(); });
}

}  // namespace brdfkit::cli
