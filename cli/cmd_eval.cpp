#include <cstdio>
#include <iostream>

#include "cli/common.h"

namespace brdfkit::cli {

void RegisterEval(CLI::App& app) {
  auto* cmd = app.add_subcommand("eval", "evaluate f_r(wi, wo) in 1/sr per RGB channel (no cosine)");
  static ModelArgs margs;
  static std::string wi, wo, wi_deg, wo_deg;
  static bool json = false;
  AddModelOptions(cmd, margs);
  auto* o_wi = cmd->add_option("--wi", wi, "direction towards the light, x,y,z (normalised by the tool)");
  auto* o_wo = cmd->add_option("--wo", wo, "direction towards the detector, x,y,z");
  auto* o_wid = cmd->add_option("--wi-deg", wi_deg, "wi as theta,phi in degrees");
  auto* o_wod = cmd->add_option("--wo-deg", wo_deg, "wo as theta,phi in degrees");
  o_wi->excludes(o_wid);
  o_wo->excludes(o_wod);
  cmd->add_flag("--json", json, "print {\"f\": [r, g, b]}");
  cmd->callback([] {
    if (wi.empty() && wi_deg.empty()) throw UsageError("eval: give --wi x,y,z or --wi-deg theta,phi");
    if (wo.empty() && wo_deg.empty()) throw UsageError("eval: give --wo x,y,z or --wo-deg theta,phi");
    const LoadedModel m = LoadModel(margs);
    const Eigen::Vector3d vi = wi.empty() ? ParseDirection(wi_deg, true, "--wi-deg") : ParseDirection(wi, false, "--wi");
    const Eigen::Vector3d vo = wo.empty() ? ParseDirection(wo_deg, true, "--wo-deg") : ParseDirection(wo, false, "--wo");
    const Rgb<double> f = m.model.Make<double>()->Eval(m.params.data(), vi, vo);
    if (json) {
      std::cout << nlohmann::json{{"f", {f[0], f[1], f[2]}}}.dump() << "\n";
    } else {
      std::printf("f_r = %.10g %.10g %.10g  1/sr (r g b)\n", f[0], f[1], f[2]);
    }
  });
}

}  // namespace brdfkit::cli
