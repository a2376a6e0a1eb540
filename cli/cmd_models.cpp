#include <cstdio>
#include <iostream>

#include "cli/common.h"

namespace brdfkit::cli {

void RegisterModels(CLI::App& app) {
  auto* cmd = app.add_subcommand("models", "list every model with its parameter table");
  static bool json = false;
  cmd->add_flag("--json", json, "print JSON: a list of {name, params, reciprocal, energy_conserving}");
  cmd->callback([] {
    const auto infos = RegisteredModelInfos();
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
