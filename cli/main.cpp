// brdfkit: check, tabulate, synthesise and fit BRDFs.
#include <cstdio>
#include <exception>

#include "cli/common.h"

int main(int argc, char** argv) {
  CLI::App app{"brdfkit: measure, check and fit BRDFs"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "brdfkit " BRDFKIT_VERSION);
  brdfkit::cli::RegisterModels(app);
  brdfkit::cli::RegisterEval(app);
  brdfkit::cli::RegisterRun(app);
  brdfkit::cli::RegisterFit(app);
  brdfkit::cli::RegisterSynth(app);
  brdfkit::cli::RegisterConvergence(app);
  brdfkit::cli::RegisterCheck(app);
  brdfkit::cli::RegisterAlbedo(app);
  brdfkit::cli::RegisterStress(app);
  brdfkit::cli::RegisterConvert(app);
  brdfkit::cli::RegisterView(app);
  if (argc > 1 && argv[1][0] != '-') {
    bool known = false;
    std::string names;
    for (const CLI::App* sub : app.get_subcommands({})) {
      known = known || sub->get_name() == argv[1];
      names += (names.empty() ? "" : ", ") + sub->get_name();
    }
    if (!known) {
      std::fprintf(stderr, "brdfkit: error: unknown command '%s' (commands: %s)\n", argv[1], names.c_str());
      return 2;
    }
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version print and succeed; any other parse error (text
    // where a number must be, a missing option) is a usage error as all others.
    if (e.get_exit_code() == 0) return app.exit(e);
    std::fprintf(stderr, "brdfkit: error: %s\n", e.what());
    return 2;
  } catch (const brdfkit::cli::ResultError& e) {
    std::fprintf(stderr, "brdfkit: error: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "brdfkit: error: %s\n", e.what());
    return 2;
  }
  return 0;
}
