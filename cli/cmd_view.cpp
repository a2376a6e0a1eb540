// brdfkit view: the interactive explorer page for one or more materials.
#include "brdf/atomic_file.h"
#include "cli/explorer.h"

namespace brdfkit::cli {

void RegisterView(CLI::App& app) {
  auto* cmd = app.add_subcommand("view", "write an interactive BRDF explorer page (one self-contained HTML file)");
  static std::vector<std::string> materials;
  static std::string out = "explorer.html", title;
  cmd->add_option("materials", materials,
                  "MODEL or MODEL:PARAMS, e.g. ggx:alpha=0.2, lambert+ggx:lambert.albedo=0.1:0.2:0.5,ggx.alpha=0.1, "
                  "a measured table (merl:FILE, rgl:FILE, utia:FILE, astm:FILE), fit:FILE.json; several are overlaid")
      ->required();
  cmd->add_option("--out,-o", out, "the HTML file to write")->capture_default_str();
  cmd->add_option("--title", title, "page title (default: the materials)");
  cmd->callback([] {
    std::vector<ExplorerMaterial> ms;
    for (const std::string& m : materials) ms.push_back(ParseMaterialArg(m));
    std::string t = title;
    for (const std::string& m : materials) t += title.empty() ? (t.empty() ? "" : ", ") + m : "";
    WriteFileAtomic(out, ExplorerPage(title.empty() ? "brdfkit explorer: " + t : t, ms));
  });
}

}  // namespace brdfkit::cli
