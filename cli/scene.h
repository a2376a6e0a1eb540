// Scene files: one JSON document naming materials, instruments, tasks and
// the outputs wanted (see examples/scene.schema.json and the README section
// "Scenes"). Parsing checks everything that can be checked without
// computing: models and parameters, instruments, files, task references,
// dependency cycles. Every error names the file and the key path.
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <map>
#include <string>
#include <type_traits>
#include <variant>
#include <vector>

#include "brdf/model.h"
#include "data_synth/camera.h"
#include "data_synth/instrument.h"
#include "validate/check.h"

namespace brdfkit::cli {

struct MaterialSpec {
  enum class Kind { kAnalytic, kMeasured, kTable, kFit };
  std::string name;
  Kind kind = Kind::kAnalytic;
  std::string model;          // analytic: model specification ("lambert+ggx"); measured: merl, rgl, utia or astm
  std::vector<double> params; // analytic: packed parameter values
  std::string path;           // measured / table: the file (resolved against the scene's folder)
  std::string fit_task;       // fit: the task whose result this material is
};

struct InstrumentSpec {
  std::string name;
  bool camera = false;
  synth::Instrument instrument;  // !camera
  synth::CameraRig rig;          // camera
  std::string file;              // where it was read from, if a file
};

struct Scene;
struct TaskSpec;
struct TaskOutcome;  // cli/run.h
struct RunContext;   // cli/run.h
class SceneReader;   // cli/scene.cpp: reads one JSON object, naming the key path in errors

// A task type is one options struct: its name, the keys of its task object
// (`Parse`, in cli/scene.cpp), what it reads from the scene (materials,
// instruments, other tasks' outputs), and `Run` (cli/run_tasks.cpp). Adding a
// type is one such struct and its entry in `TaskOptions`; scene parsing,
// dependencies, cache keys, `run --names` and dispatch follow from them.
struct TaskTypeBase {
  // Scene materials, instruments and tasks whose outputs this task reads.
  std::vector<std::string> Materials() const { return {}; }
  std::vector<std::string> Instruments() const { return {}; }
  std::vector<std::string> Tasks() const { return {}; }
};

struct CheckTask : TaskTypeBase {
  static constexpr const char* kName = "check";
  std::vector<std::string> materials;
  bool sampling = true;
  std::int64_t sampling_samples = 100000;
  std::int64_t albedo_budget = validate::CheckOptions().albedo_budget;

  void Parse(SceneReader& r, const Scene& s);
  std::vector<std::string> Materials() const { return materials; }
  TaskOutcome Run(const TaskSpec& t, const RunContext& ctx) const;
};

struct AlbedoTask : TaskTypeBase {
  static constexpr const char* kName = "albedo";
  std::string model;
  std::vector<double> params;  // fixed parameter values (packed)
  // Or a material of the scene (analytic, measured or fitted) in place of
  // model and params; a measured one is tabulated over mu alone.
  std::string material;
  std::string axes = "mu:32,alpha:32:0.001:1";  // within the tables' 1e-6 contract
  bool gauss_nodes = false;
  double tolerance = 1e-6;  // as validate::AlbedoQuadratureOptions
  double accept_error = 0;  // largest accepted error estimate (0: the tolerance)
  std::string part = "total";  // a transmitting model's entries: total, reflected or transmitted
  std::vector<std::string> formats;  // csv, exr, header
  // A renderer's table set instead of a model and axes (validate/presets.h).
  std::string preset;
  std::vector<std::string> tables;  // only these of the preset's tables (empty: all)
  int size = 0;  // nodes per axis of a preset (0: its default; validate::PresetSize)

  void Parse(SceneReader& r, const Scene& s);
  std::vector<std::string> Materials() const {
    return material.empty() ? std::vector<std::string>{} : std::vector<std::string>{material};
  }
  TaskOutcome Run(const TaskSpec& t, const RunContext& ctx) const;
  TaskOutcome RunPreset(const TaskSpec& t, const RunContext& ctx) const;
};

struct SynthTask : TaskTypeBase {
  static constexpr const char* kName = "synth";
  std::string material;
  std::string instrument;
  std::uint64_t seed = 0;
  std::vector<std::string> formats;  // csv, binary, exr

  void Parse(SceneReader& r, const Scene& s);
  std::vector<std::string> Materials() const { return {material}; }
  std::vector<std::string> Instruments() const { return {instrument}; }
  TaskOutcome Run(const TaskSpec& t, const RunContext& ctx) const;
};

struct FitTask : TaskTypeBase {
  static constexpr const char* kName = "fit";
  std::string data_task;      // a synth task of the scene
  std::string data_material;  // or a measured material (merl / table)
  std::string model;
  std::string metric = "l2";
  std::string loss = "none";
  std::string solver = "dense_qr";
  std::string init;        // name=value,... (empty: multi-start)
  std::string fix, tie, bounds;  // fit::Options::fix, tie, bounds
  std::string instrument;  // fit through its apertures (optional)
  int max_iterations = 200;
  int starts = 5;
  int random_starts = 0;    // fit::Options::random_starts
  std::uint64_t seed = 1;   // of the random starts

  void Parse(SceneReader& r, const Scene& s);
  std::vector<std::string> Materials() const { return Listed(data_material); }
  std::vector<std::string> Instruments() const { return Listed(instrument); }
  std::vector<std::string> Tasks() const { return Listed(data_task); }
  TaskOutcome Run(const TaskSpec& t, const RunContext& ctx) const;

 private:
  static std::vector<std::string> Listed(const std::string& n) {
    return n.empty() ? std::vector<std::string>{} : std::vector<std::string>{n};
  }
};

struct ConvergenceTask : TaskTypeBase {
  static constexpr const char* kName = "convergence";
  bool quick = true;
  std::vector<std::string> methods;

  void Parse(SceneReader& r, const Scene& s);
  TaskOutcome Run(const TaskSpec& t, const RunContext& ctx) const;
};

using TaskOptions = std::variant<CheckTask, AlbedoTask, SynthTask, FitTask, ConvergenceTask>;

// The names of the task types, in `TaskOptions` order.
std::vector<std::string> TaskTypeNames();

struct TaskSpec {
  std::string name;
  nlohmann::json json;  // the task object as written (part of the cache key)
  TaskOptions options;

  const char* TypeName() const {
    return std::visit([](const auto& o) { return std::decay_t<decltype(o)>::kName; }, options);
  }
  template <class Type>
  const Type* As() const { return std::get_if<Type>(&options); }
  // What the task reads from the scene (see TaskTypeBase).
  std::vector<std::string> Materials() const {
    return std::visit([](const auto& o) { return o.Materials(); }, options);
  }
  std::vector<std::string> Instruments() const {
    return std::visit([](const auto& o) { return o.Instruments(); }, options);
  }
  std::vector<std::string> Tasks() const {
    return std::visit([](const auto& o) { return o.Tasks(); }, options);
  }
};

// Every name a scene may use where the schema (examples/scene.schema.json)
// lists an enumeration, from the libraries' own lists: task and instrument
// types, albedo nodes and formats, synth formats, fit metrics, losses and
// solvers, integration methods (`brdfkit run --names`).
nlohmann::json SceneNames();

struct Scene {
  std::string origin;    // file name for messages ("<embedded default scene>")
  std::string base_dir;  // relative paths resolve here
  std::string output = "brdfkit-out";
  std::string title;
  std::map<std::string, MaterialSpec> materials;
  std::map<std::string, InstrumentSpec> instruments;
  std::vector<TaskSpec> tasks;          // in file order
  std::vector<std::string> requested;   // task names whose outputs are wanted (default: all)

  const TaskSpec* FindTask(const std::string& name) const;
  // Tasks a task needs first (synth before the fit of its data, a fit
  // before a task using its fitted material).
  std::vector<std::string> Dependencies(const TaskSpec& task) const;
};

// Throws std::runtime_error "<origin>: <key path>: <what>" (or the JSON
// parser's line and column) for anything malformed.
Scene ParseScene(const std::string& text, const std::string& origin, const std::string& base_dir);
Scene LoadScene(const std::string& path);

// The scene `brdfkit run` runs with no argument (examples/default.json,
// compiled in).
const std::string& DefaultSceneText();

}  // namespace brdfkit::cli
