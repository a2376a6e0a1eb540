// The plan of a scene: the requested tasks and what they need, in
// dependency order, each keyed by the content of its inputs.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <set>
#include <sstream>

#include "brdf/params.h"
#include "cli/run.h"

namespace brdfkit::cli {

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

std::string FileHash(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return "unreadable";
  std::ostringstream ss;
  ss << in.rdbuf();
  return HashHex(ss.str());
}

json MaterialKey(const Scene& scene, const std::string& name, const std::map<std::string, std::string>& keys) {
  const MaterialSpec& m = scene.materials.at(name);
  json j;
  switch (m.kind) {
    case MaterialSpec::Kind::kAnalytic:
      j = {{"model", m.model}, {"params", m.params}};
      break;
    case MaterialSpec::Kind::kMeasured:
    case MaterialSpec::Kind::kTable:
      j = {{"file", FileHash(m.path)}, {"kind", m.kind == MaterialSpec::Kind::kMeasured ? m.model : "table"}};
      break;
    case MaterialSpec::Kind::kFit:
      j = {{"fit", keys.at(m.fit_task)}};
      break;
  }
  return j;
}

json InstrumentKey(const Scene& scene, const std::string& name) {
  const InstrumentSpec& in = scene.instruments.at(name);
  if (in.camera) return synth::CameraRigToJson(in.rig);
  json j = synth::InstrumentToJson(in.instrument);
  if (in.instrument.plan.kind == synth::SamplingPlan::Kind::kList) j["list_file_content"] = FileHash(in.instrument.plan.list_file);
  return j;
}

}  // namespace

std::string HashHex(const std::string& bytes) {
  std::uint64_t h = 1469598103934665603ull;
  for (unsigned char c : bytes) {
    h ^= c;
    h *= 1099511628211ull;
  }
  char buf[17];
  std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(h));
  return buf;
}

json TaskOutcome::ToJson() const {
  json figs = json::array();
  for (const Figure& f : figures) figs.push_back({{"title", f.title}, {"file", f.file}, {"caption", f.caption}});
  return {{"name", name}, {"type", type},   {"status", status}, {"seconds", seconds},
          {"result", result}, {"files", files}, {"figures", figs}};
}

TaskOutcome TaskOutcome::FromJson(const json& j) {
  TaskOutcome o;
  o.name = j.at("name").get<std::string>();
  o.type = j.at("type").get<std::string>();
  o.status = j.at("status").get<std::string>();
  o.seconds = j.at("seconds").get<double>();
  o.result = j.at("result");
  o.files = j.at("files").get<std::vector<std::string>>();
  for (const json& f : j.at("figures"))
    o.figures.push_back({f.at("title").get<std::string>(), f.at("file").get<std::string>(),
                         f.at("caption").get<std::string>()});
  return o;
}

std::vector<PlanItem> MakePlan(const Scene& scene, const std::string& out_dir, bool force) {
  // What the requested outputs need, and who needs it.
  std::map<std::string, std::string> needed_by;  // task -> why
  std::vector<std::string> order;                 // dependencies first
  std::set<std::string> visited;
  std::function<void(const std::string&, const std::string&)> visit = [&](const std::string& name,
                                                                          const std::string& why) {
    if (!needed_by.count(name)) needed_by[name] = why;
    if (visited.count(name)) return;
    visited.insert(name);
    const TaskSpec* t = scene.FindTask(name);
    for (const std::string& d : scene.Dependencies(*t)) visit(d, "needed by " + name);
    order.push_back(name);
  };
  for (const std::string& r : scene.requested) visit(r, "requested");
  for (const std::string& r : scene.requested) needed_by[r] = "requested";

  // Keys, in dependency order so a task's key includes its inputs' keys.
  std::map<std::string, std::string> keys;
  std::vector<PlanItem> plan;
  for (const std::string& name : order) {
    const TaskSpec& t = *scene.FindTask(name);
    json k;
    k["brdfkit"] = BRDFKIT_VERSION;
    k["task"] = t.json;
    json mats = json::object(), insts = json::object(), deps = json::object();
    for (const std::string& m : t.Materials()) mats[m] = MaterialKey(scene, m, keys);
    for (const std::string& i : t.Instruments()) insts[i] = InstrumentKey(scene, i);
    for (const std::string& d : scene.Dependencies(t)) deps[d] = keys.at(d);
    k["materials"] = mats;
    k["instruments"] = insts;
    k["depends"] = deps;
    PlanItem item;
    item.task = &t;
    item.key = HashHex(k.dump());
    keys[name] = item.key;
    item.action = PlanItem::Action::kRun;
    item.why = needed_by[name];
    // Up to date: the same key in the cache and every file still there.
    const fs::path cache = fs::path(out_dir) / ".cache" / (name + ".json");
    if (!force && fs::exists(cache)) {
      try {
        std::ifstream in(cache);
        const json c = json::parse(in);
        if (c.at("key").get<std::string>() == item.key) {
          const TaskOutcome o = TaskOutcome::FromJson(c.at("outcome"));
          bool complete = true;
          for (const std::string& f : o.files) complete = complete && fs::exists(fs::path(out_dir) / f);
          if (complete) {
            item.action = PlanItem::Action::kCached;
            item.why += "; up to date";
          }
        }
      } catch (const std::exception&) {
        // An unreadable cache entry only means the task runs again.
      }
    }
    plan.push_back(item);
  }
  for (const TaskSpec& t : scene.tasks) {
    if (needed_by.count(t.name)) continue;
    PlanItem item;
    item.task = &t;
    item.action = PlanItem::Action::kSkip;
    item.why = "not requested, and no requested output needs it";
    plan.push_back(item);
  }
  return plan;
}

}  // namespace brdfkit::cli
