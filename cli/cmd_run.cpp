// `brdfkit run [SCENE]`: does what a scene asks for and nothing else, reuses
// results that are up to date, and writes results.json and report.html.
// With no scene, runs the built-in default scene (examples/default.json).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>

#include "brdf/atomic_file.h"
#include "cli/common.h"
#include "cli/progress.h"
#include "cli/run.h"

namespace brdfkit::cli {

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

const char* ActionName(PlanItem::Action a) {
  switch (a) {
    case PlanItem::Action::kRun: return "run";
    case PlanItem::Action::kCached: return "cached";
    case PlanItem::Action::kSkip: return "skip";
  }
  return "?";
}

json PlanJson(const std::vector<PlanItem>& plan) {
  json j = json::array();
  for (const PlanItem& p : plan)
    j.push_back({{"task", p.task->name},
                 {"type", p.task->TypeName()},
                 {"action", ActionName(p.action)},
                 {"why", p.why},
                 {"key", p.key}});
  return j;
}

void PrintPlan(const Scene& scene, const std::vector<PlanItem>& plan, const std::string& out_dir) {
  std::printf("plan for %s (outputs in %s):\n", scene.origin.c_str(), out_dir.c_str());
  for (const PlanItem& p : plan)
    std::printf("  %-6s %-20s %-12s %s\n", ActionName(p.action), p.task->name.c_str(), p.task->TypeName(),
                p.why.c_str());
}

}  // namespace

void RegisterRun(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "run",
      "run a scene (JSON: materials, instruments, tasks, outputs): only what the requested outputs need, reusing "
      "up-to-date results; writes results.json and report.html. No scene: the built-in default scene.");
  static std::string scene_path, out;
  static bool dry_run = false, json_out = false, force = false, quiet = false;
  cmd->add_option("scene", scene_path, "scene file (default: the built-in scene, also in examples/default.json)");
  cmd->add_option("--out,-o", out, "output folder (default: the scene's \"output\", relative to the current folder)");
  cmd->add_flag("--dry-run,-n", dry_run, "print the plan (what would run, what is up to date, what is skipped) and stop");
  cmd->add_flag("--json", json_out, "with --dry-run: the plan as JSON; otherwise print results.json");
  cmd->add_flag("--force", force, "recompute every needed task, even when its cached result is up to date");
  cmd->add_flag("--quiet,-q", quiet, "no progress bars or per-task lines");
  static bool names = false;
  cmd->add_flag("--names", names, "print, as JSON, every name a scene may use for a type, format, metric, loss, "
                                  "solver or integration method, and stop");
  cmd->callback([] {
    if (names) {
      std::cout << SceneNames().dump(2) << "\n";
      return;
    }
    InstallInterruptHandler();
    Scene scene;
    try {
      scene = scene_path.empty() ? ParseScene(DefaultSceneText(), "<built-in default scene>", "")
                                 : LoadScene(scene_path);
    } catch (const std::runtime_error& e) {
      throw UsageError(e.what());
    }
    const std::string out_dir = out.empty() ? scene.output : out;
    const std::vector<PlanItem> plan = MakePlan(scene, out_dir, force);
    if (dry_run) {
      if (json_out) std::cout << json{{"scene", scene.origin}, {"output", out_dir}, {"plan", PlanJson(plan)}}.dump(2) << "\n";
      else PrintPlan(scene, plan, out_dir);
      return;
    }
    std::error_code ec;
    fs::create_directories(fs::path(out_dir) / ".cache", ec);
    if (!fs::is_directory(fs::path(out_dir) / ".cache"))
      throw UsageError("cannot create the output folder '" + out_dir + "'");

    const auto start = std::chrono::steady_clock::now();
    RunContext ctx{scene, out_dir, quiet};
    std::vector<TaskOutcome> outcomes;
    std::size_t to_do = 0, done = 0;
    for (const PlanItem& p : plan) to_do += p.action == PlanItem::Action::kSkip ? 0 : 1;
    try {
      for (const PlanItem& p : plan) {
        if (p.action == PlanItem::Action::kSkip) continue;
        ++done;
        const fs::path cache = fs::path(out_dir) / ".cache" / (p.task->name + ".json");
        TaskOutcome o;
        if (p.action == PlanItem::Action::kCached) {
          std::ifstream in(cache);
          o = TaskOutcome::FromJson(json::parse(in).at("outcome"));
          o.status = "cached";
        } else {
          ThrowIfInterrupted();
          o = RunTask(*p.task, ctx);
          WriteFileAtomic(cache, json{{"key", p.key}, {"outcome", o.ToJson()}}.dump(1) + "\n");
        }
        if (!quiet && !json_out)
          std::fprintf(stderr, "[%zu/%zu] %-20s %-12s %s\n", done, to_do, p.task->name.c_str(), o.type.c_str(),
                       o.status == "cached" ? "up to date" : (FormatDouble(std::round(o.seconds * 100) / 100) + " s").c_str());
        outcomes.push_back(std::move(o));
      }
    } catch (const Interrupted&) {
      std::fprintf(stderr,
                   "\nbrdfkit: stopped by Ctrl-C after %zu of %zu task(s). Finished tasks are kept (and cached); no "
                   "partial file was written. results.json and report.html were not updated.\n",
                   outcomes.size(), to_do);
      std::fflush(stderr);
      std::exit(130);
    }
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    json results = {{"scene", scene.origin},
                    {"title", scene.title},
                    {"brdfkit", BRDFKIT_VERSION},
                    {"output", out_dir},
                    {"seconds", seconds},
                    {"plan", PlanJson(plan)}};
    json tasks = json::array();
    for (const TaskOutcome& o : outcomes) tasks.push_back(o.ToJson());
    results["tasks"] = tasks;
    WriteFileAtomic(fs::path(out_dir) / "results.json", results.dump(2) + "\n");
    WriteReport((fs::path(out_dir) / "report.html").string(), scene, outcomes, plan, out_dir, seconds);
    if (json_out) {
      std::cout << results.dump(2) << "\n";
      return;
    }
    // The verdicts and the fit in a few lines; the rest is in the report.
    for (const TaskOutcome& o : outcomes) {
      if (o.type == "check") {
        for (const json& m : o.result.at("materials")) {
          std::printf("%-22s %s", m.at("material").get<std::string>().c_str(),
                      m.at("plausible").get<bool>() ? "plausible" : "IMPLAUSIBLE");
          for (const json& r : m.at("reasons")) {
            const std::string s = r.get<std::string>();
            std::printf("  [%s]", s.substr(0, s.find(':')).c_str());
          }
          std::printf("\n");
        }
      } else if (o.type == "fit") {
        std::printf("fit %-18s %s, rmse %.4g, %d iterations, %s\n", o.name.c_str(),
                    o.result.at("model").get<std::string>().c_str(), o.result.at("rmse").get<double>(),
                    o.result.at("iterations").get<int>(), o.result.at("converged").get<bool>() ? "converged" : "NOT converged");
      } else if (o.type == "albedo") {
        std::printf("albedo %-15s %s: %lld entries, largest error estimate %.2g\n", o.name.c_str(),
                    o.result.at("model").get<std::string>().c_str(), o.result.at("entries").get<long long>(),
                    o.result.at("max_error").get<double>());
      }
    }
    std::printf("wrote %s and %s (%.1f s)\n", (fs::path(out_dir) / "report.html").string().c_str(),
                (fs::path(out_dir) / "results.json").string().c_str(), seconds);
  });
}

}  // namespace brdfkit::cli
