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
#include <vector>

#include "brdf/model.h"
#include "data_synth/camera.h"
#include "data_synth/instrument.h"

namespace brdfkit::cli {

struct MaterialSpec {
  enum class Kind { kAnalytic, kMerl, kTable, kFit };
  std::string name;
  Kind kind = Kind::kAnalytic;
  std::string model;          // analytic: model specification ("lambert+ggx")
  std::vector<double> params; // analytic: packed parameter values
  std::string path;           // merl / table: the file (resolved against the scene's folder)
  std::string fit_task;       // fit: the task whose result this material is
};

struct InstrumentSpec {
  std::string name;
  bool camera = false;
  synth::Instrument instrument;  // !camera
  synth::CameraRig rig;          // camera
  std::string file;              // where it was read from, if a file
};

struct TaskSpec {
  enum class Type { kCheck, kAlbedo, kSynth, kFit, kConvergence };
  std::string name;
  Type type = Type::kCheck;
  nlohmann::json json;  // the task object as written (part of the cache key)

  // check
  std::vector<std::string> materials;
  bool sampling = true;
  std::int64_t sampling_samples = 100000;
  // albedo
  std::string model;             // also fit
  std::vector<double> params;    // albedo: fixed parameter values (packed)
  std::string axes = "mu:32,alpha:32:0.001:1";  // within the tables' 1e-6 contract
  bool gauss_nodes = false;
  double tolerance = 1e-6;  // as validate::AlbedoQuadratureOptions
  double accept_error = 0;  // largest accepted error estimate (0: the tolerance)
  std::vector<std::string> formats;  // albedo: csv, exr, header; synth: csv, binary, exr
  // synth
  std::string material;
  std::string instrument;  // synth: the instrument; fit: fit through its apertures (optional)
  std::uint64_t seed = 0;
  // fit
  std::string data_task;      // a synth task of the scene
  std::string data_material;  // or a measured material (merl / table)
  std::string metric = "l2";
  std::string loss = "none";
  std::string solver = "dense_qr";
  std::string init;           // name=value,... (empty: multi-start)
  int max_iterations = 200;
  int starts = 5;
  // convergence
  bool quick = true;
  std::vector<std::string> methods;
};

const char* TaskTypeName(TaskSpec::Type t);

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
