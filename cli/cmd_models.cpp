#include <iostream>

#include "cli/common.h"

namespace brdfkit::cli {

namespace {
std::string KindText(unsigned kind) {
  std::string s;
  const std::pair<unsigned, const char*> names[] = {{LobeKind::kDiffuse, "diffuse"},
                                                    {LobeKind::kGlossy, "glossy"},
                                                    {LobeKind::kSpecular, "specular"},
                                                    {LobeKind::kTransmission, "transmission"}};
  for (const auto& [flag, name] : names)
    if (kind & flag) s += (s.empty() ? "" : ", ") + std::string(name);
  return s;
}
}  // namespace

std::string ModelTableMarkdown() {
  std::string out =
      "| model | parameters (range, default) | kind | reciprocal | energy conserving | summary |\n"
      "|---|---|---|---|---|---|\n";
  for (const ModelInfo& i : RegisteredModelInfos()) {
    std::string params;
    for (const ParamInfo& p : i.params)
      params += (params.empty() ? "" : "; ") + ("`" + p.name + "`") + (p.colour ? " (rgb)" : "") + " [" +
                FormatShort(p.lower) + ", " + FormatShort(p.upper) + "] " + FormatShort(p.default_value);
    for (const std::string& s : i.settings) params += (params.empty() ? "" : "; ") + ("`" + s + "`") + " (setting)";
    out += "| `" + i.name + "` | " + params + " | " + KindText(TraitsOf(i.name).kind) + " | " +
           (i.reciprocal ? "yes" : "**no**") + " | " + (i.energy_conserving ? "yes" : "no") + " | " + i.summary +
           " |\n";
  }
  return out;
}

void RegisterModels(CLI::App& app) {
  auto* cmd = app.add_subcommand("models", "list every model with its parameter table");
  static bool json = false;
  cmd->add_flag("--json", json, "print JSON: a list of {name, params, reciprocal, energy_conserving}");
  static bool markdown = false;
  cmd->add_flag("--markdown", markdown, "print the Markdown table of the README's 'Registered models'");
  cmd->callback([] {
    const auto infos = RegisteredModelInfos();
    if (markdown) {
      std::cout << ModelTableMarkdown();
      return;
    }
    if (json) {
      nlohmann::json out = nlohmann::json::array();
      for (const ModelInfo& i : infos) out.push_back(ModelInfoJson(i));
      std::cout << out.dump(2) << "\n";
      return;
    }
    for (const ModelInfo& i : infos) {
      std::printf("%s  (%s%s)\n  %s\n", i.name.c_str(), i.reciprocal ? "reciprocal" : "NOT reciprocal",
                  i.energy_conserving ? ", energy-conserving" : "", i.summary.c_str());
      for (const ParamInfo& p : i.params)
        std::printf("    %-10s [%g, %g] default %g%s  %s\n", p.name.c_str(), p.lower, p.upper, p.default_value,
                    p.colour ? " (rgb)" : "", p.meaning.c_str());
      for (const std::string& s : i.settings) std::printf("    %-10s (setting)\n", s.c_str());
    }
  });
}

}  // namespace brdfkit::cli
