// `brdfkit run`: the plan of a scene (what its requested outputs need, what
// is already up to date), the tasks, and the report.
#pragma once

#include <nlohmann/json.hpp>

#include <map>
#include <string>
#include <vector>

#include "cli/common.h"
#include "cli/scene.h"

namespace brdfkit::cli {

struct Figure {
  std::string title;
  std::string file;  // relative to the output folder
  std::string caption;
};

// What a task produced: the values the report shows, its files and figures.
// Stored in the cache so an up-to-date task is shown without recomputing.
struct TaskOutcome {
  std::string name, type;
  std::string status;  // "computed" or "cached"
  double seconds = 0;  // wall time when it was computed
  nlohmann::json result = nlohmann::json::object();
  std::vector<std::string> files;  // relative to the output folder
  std::vector<Figure> figures;

  nlohmann::json ToJson() const;
  static TaskOutcome FromJson(const nlohmann::json& j);
};

struct PlanItem {
  const TaskSpec* task = nullptr;
  enum class Action { kRun, kCached, kSkip } action = Action::kSkip;
  std::string why;
  std::string key;  // content hash of the task's inputs (and brdfkit's version)
};

// Tasks in run order (dependencies first), then the skipped ones.
std::vector<PlanItem> MakePlan(const Scene& scene, const std::string& out_dir, bool force);

struct RunContext {
  const Scene& scene;
  std::string out_dir;
  bool quiet = false;
};

// Runs one task into <out_dir>/<task name>/; the tasks it depends on have run
// (or are cached) already.
TaskOutcome RunTask(const TaskSpec& task, const RunContext& ctx);

// A material as a model and parameters (fitted ones read from their fit's
// result); throws for a data table.
LoadedModel MaterialModel(const MaterialSpec& m, const RunContext& ctx);

// report.html: one self-contained file (figures embedded as data URIs).
void WriteReport(const std::string& path, const Scene& scene, const std::vector<TaskOutcome>& outcomes,
                 const std::vector<PlanItem>& plan, const std::string& out_dir, double seconds);

// FNV-1a 64 of bytes, as 16 hex digits.
std::string HashHex(const std::string& bytes);

}  // namespace brdfkit::cli
