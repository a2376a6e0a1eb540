#include "cli/common.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <sstream>

#include <tbb/info.h>

namespace brdfkit::cli {

int ThreadCount(int requested) {
  if (requested < 0) throw UsageError("--threads " + std::to_string(requested) + ": expected 0 (every core) or more");
  const int cores = std::max(1, tbb::info::default_concurrency());
  if (requested == 0) return cores;
  if (requested > cores) {
    std::fprintf(stderr, "brdfkit: note: --threads %d: this machine offers %d cores; using %d\n", requested, cores,
                 cores);
    return cores;
  }
  return requested;
}

void AddModelOptions(CLI::App* cmd, ModelArgs& args, bool required) {
  auto* opt = cmd->add_option("--model,-m", args.model,
                              "model name or sum of lobes, e.g. ggx, lambert+ggx, or a measured table (merl:FILE, "
                              "rgl:FILE, utia:FILE, astm:FILE; see 'brdfkit models')");
  if (required) opt->required();
  cmd->add_option("--params,-p", args.params,
                  "parameters name=value,...; a colour parameter takes one value or r:g:b; "
                  "lobes of a sum are named <lobe>.<param>");
}

LoadedModel LoadModel(const ModelArgs& args) {
  if (args.model.rfind("fit:", 0) == 0) return LoadFitModel(args.model.substr(4));  // a saved fit result
  // Settings (e.g. path=) of a single-lobe model are given with the parameters.
  Settings settings;
  std::string numeric;
  const bool single = args.model.find('+') == std::string::npos;
  const std::string lobe_name = args.model.substr(0, args.model.find(':'));
  std::vector<std::string> setting_names;
  if (single)
    for (const ModelInfo& i : RegisteredModelInfos())
      if (i.name == lobe_name) setting_names = i.settings;
  for (const auto& [k, v] : SplitAssignments(args.params)) {
    bool is_setting = false;
    for (const auto& s : setting_names) is_setting = is_setting || s == k;
    if (is_setting) settings[k] = v;
    else numeric += (numeric.empty() ? "" : ",") + k + "=" + v;
  }
  LoadedModel out{Model::Parse(args.model, settings), {}, settings};
  out.params = ParseParams(out.model.Info(), numeric);
  return out;
}

Eigen::Vector3d ParseDirection(const std::string& text, bool degrees, const std::string& option) {
  std::vector<double> v;
  std::stringstream ss(text);
  std::string part;
  while (std::getline(ss, part, ',')) {
    double x;
    if (!ParseDouble(part, x) || !std::isfinite(x))
      throw UsageError(option + ": '" + part + "' is not a finite number (in '" + text + "')");
    v.push_back(x);
  }
  if (degrees) {
    if (v.size() != 2) throw UsageError(option + ": expected theta,phi in degrees, got '" + text + "'");
    const double t = v[0] * kPi / 180.0, p = v[1] * kPi / 180.0;
    return Eigen::Vector3d(std::sin(t) * std::cos(p), std::sin(t) * std::sin(p), std::cos(t));
  }
  if (v.size() != 3) throw UsageError(option + ": expected x,y,z, got '" + text + "'");
  Eigen::Vector3d d(v[0], v[1], v[2]);
  if (!(d.norm() > 0)) throw UsageError(option + ": the direction '" + text + "' has zero length");
  return d.normalized();
}

nlohmann::json ModelInfoJson(const ModelInfo& info) {
  nlohmann::json params = nlohmann::json::array();
  for (const ParamInfo& p : info.params)
    params.push_back({{"name", p.name},
                      {"lower", p.lower},
                      {"upper", p.upper},
                      {"default", p.default_value},
                      {"colour", p.colour},
                      {"meaning", p.meaning}});
  nlohmann::json j = {{"name", info.name},
                      {"summary", info.summary},
                      {"params", params},
                      {"reciprocal", info.reciprocal},
                      {"energy_conserving", info.energy_conserving}};
  if (!info.settings.empty()) j["settings"] = info.settings;
  return j;
}

std::string AlbedoHeaderPrefix(const std::string& name) {
  std::string p = !name.empty() && std::isdigit(static_cast<unsigned char>(name[0])) ? "m_" : "";
  for (char c : name) p += std::isalnum(static_cast<unsigned char>(c)) ? c : '_';
  return p + "_albedo";
}

}  // namespace brdfkit::cli
