#include "cli/scene.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>

#include "brdf/merl.h"
#include "brdf/params.h"
#include "fit/fit.h"
#include "formats/convert.h"
#include "validate/albedo.h"
#include "validate/presets.h"
#include "validate/integrators.h"

namespace brdfkit::cli {

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

[[noreturn]] void Fail(const std::string& origin, const std::string& path, const std::string& what) {
  throw std::runtime_error(origin + ": " + (path.empty() ? "" : path + ": ") + what);
}

std::string Join(const std::vector<std::string>& v) {
  std::string out;
  for (const std::string& x : v) out += (out.empty() ? "" : ", ") + x;
  return out;
}

}  // namespace

// Reads one JSON object, remembering the keys used so that unknown keys
// (typos) are reported instead of ignored.
class SceneReader {
 public:
  SceneReader(const json& j, std::string path, const std::string& origin) : j_(j), path_(std::move(path)), origin_(origin) {
    if (!j_.is_object()) Fail(origin_, path_, std::string("expected an object, got ") + j_.type_name());
  }
  std::string Path(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }
  [[noreturn]] void FailKey(const std::string& key, const std::string& what) const { Fail(origin_, Path(key), what); }
  bool Has(const std::string& key) const { return j_.contains(key); }
  const json& Get(const std::string& key) {
    if (!j_.contains(key)) FailKey(key, "missing (required)");
    used_.insert(key);
    return j_.at(key);
  }
  std::string String(const std::string& key) {
    const json& v = Get(key);
    if (!v.is_string()) FailKey(key, std::string("expected a string, got ") + v.type_name());
    return v.get<std::string>();
  }
  std::string String(const std::string& key, const std::string& fallback) { return Has(key) ? String(key) : fallback; }
  bool Bool(const std::string& key, bool fallback) {
    if (!Has(key)) return fallback;
    const json& v = Get(key);
    if (!v.is_boolean()) FailKey(key, std::string("expected true or false, got ") + v.type_name());
    return v.get<bool>();
  }
  double Number(const std::string& key, double fallback, double lower, double upper) {
    if (!Has(key)) return fallback;
    const json& v = Get(key);
    if (!v.is_number()) FailKey(key, std::string("expected a number, got ") + v.type_name());
    const double x = v.get<double>();
    if (!std::isfinite(x) || x < lower || x > upper)
      FailKey(key, "value " + v.dump() + " is outside [" + FormatDouble(lower) + ", " + FormatDouble(upper) + "]");
    return x;
  }
  std::int64_t Integer(const std::string& key, std::int64_t fallback, std::int64_t lower, std::int64_t upper) {
    if (!Has(key)) return fallback;
    const json& v = Get(key);
    if (!v.is_number_integer()) FailKey(key, std::string("expected an integer, got ") + v.dump());
    const std::int64_t x = v.get<std::int64_t>();
    if (x < lower || x > upper)
      FailKey(key, "value " + v.dump() + " is outside [" + std::to_string(lower) + ", " + std::to_string(upper) + "]");
    return x;
  }
  std::vector<std::string> Strings(const std::string& key, bool required) {
    std::vector<std::string> out;
    if (!required && !Has(key)) return out;
    const json& v = Get(key);
    if (!v.is_array()) FailKey(key, std::string("expected an array of strings, got ") + v.type_name());
    for (std::size_t i = 0; i < v.size(); ++i) {
      if (!v[i].is_string()) FailKey(key + "[" + std::to_string(i) + "]", "expected a string");
      out.push_back(v[i].get<std::string>());
    }
    return out;
  }
  // Keys outside `known` are errors, reported before anything else is read
  // (a misspelt section would otherwise surface as a missing one).
  void Only(const std::vector<std::string>& known) const {
    std::vector<KnownName> names;
    for (const std::string& k : known) names.push_back({k, ""});
    for (auto it = j_.begin(); it != j_.end(); ++it)
      if (std::find(known.begin(), known.end(), it.key()) == known.end() && it.key() != "$comment" &&
          it.key() != "description")
        FailKey(it.key(), "unknown key (known keys: " + Join(known) + ")" + DidYouMean(it.key(), names));
  }
  // Unknown keys are errors; "$comment" and "description" are free text.
  void Finish() const {
    for (auto it = j_.begin(); it != j_.end(); ++it)
      if (!used_.count(it.key()) && it.key() != "$comment" && it.key() != "description")
        FailKey(it.key(), "unknown key");
  }
  const std::string& origin() const { return origin_; }

 private:
  const json& j_;
  std::string path_;
  const std::string& origin_;
  std::set<std::string> used_;
};

namespace {

// Names become folder names and report anchors.
void CheckName(const std::string& name, const std::string& origin, const std::string& path) {
  if (name.empty() || name.size() > 64) Fail(origin, path, "a name must have 1 to 64 characters");
  for (char c : name)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-'))
      Fail(origin, path, "name '" + name + "' may contain only letters, digits, '_' and '-'");
}

std::string Resolve(const std::string& base_dir, const std::string& p) {
  if (p.empty() || fs::path(p).is_absolute() || base_dir.empty()) return p;
  return (fs::path(base_dir) / p).lexically_normal().string();
}

// A path as the user wrote it and, when relative, as it was resolved:
// "'data/x.binary' (resolved to '/home/me/scenes/data/x.binary')".
std::string ShownPath(const std::string& given, const std::string& resolved) {
  std::error_code ec;
  const fs::path abs = fs::absolute(resolved, ec).lexically_normal();
  if (fs::path(given).is_absolute() || ec) return "'" + resolved + "'";
  return "'" + given + "' (resolved to '" + abs.string() + "')";
}

// The file must exist and be a readable regular file.
std::string ExistingFile(const std::string& base_dir, const std::string& p, const std::string& origin,
                         const std::string& key_path) {
  const std::string r = Resolve(base_dir, p);
  std::error_code ec;
  if (!fs::exists(r, ec)) Fail(origin, key_path, "file " + ShownPath(p, r) + " not found");
  if (fs::is_directory(r, ec)) Fail(origin, key_path, ShownPath(p, r) + " is a directory, not a file");
  std::ifstream in(r, std::ios::binary);
  if (!in) Fail(origin, key_path, "cannot read " + ShownPath(p, r));
  return r;
}

// Parameters as "name=value,..." or as an object {"name": value or [r, g, b]}.
std::vector<double> ReadParams(SceneReader& r, const std::string& key, const ModelInfo& info) {
  std::string text;
  if (r.Has(key)) {
    const json& v = r.Get(key);
    if (v.is_string()) {
      text = v.get<std::string>();
    } else if (v.is_object()) {
      for (auto it = v.begin(); it != v.end(); ++it) {
        std::string value;
        if (it->is_number()) {
          value = FormatDouble(it->get<double>());
        } else if (it->is_array() && it->size() == 3 && (*it)[0].is_number() && (*it)[1].is_number() &&
                   (*it)[2].is_number()) {
          value = FormatDouble((*it)[0].get<double>()) + ":" + FormatDouble((*it)[1].get<double>()) + ":" +
                  FormatDouble((*it)[2].get<double>());
        } else {
          r.FailKey(key + "." + it.key(), "expected a number or [r, g, b]");
        }
        text += (text.empty() ? "" : ",") + it.key() + "=" + value;
      }
    } else {
      r.FailKey(key, "expected \"name=value,...\" or an object of name: value");
    }
  }
  try {
    return ParseParams(info, text);
  } catch (const std::exception& e) {
    r.FailKey(key, e.what());
  }
}

Model ParseModelAt(SceneReader& r, const std::string& key) {
  const std::string spec = r.String(key);
  try {
    return Model::Parse(spec);
  } catch (const std::exception& e) {
    r.FailKey(key, e.what());
  }
}

// Throws (ModelError) unless every parameter axis after mu names a parameter of info.
void CheckAxisParameters(const ModelInfo& info, const std::vector<validate::AxisSpec>& axes) {
  for (std::size_t i = 1; i < axes.size(); ++i) validate::AxisParameter(info, axes[i].name);
}

const std::set<std::string> kSynthFormats = {"csv", "binary", "exr"};
const std::set<std::string> kAlbedoFormats = {"csv", "exr", "header"};

}  // namespace

const TaskSpec* Scene::FindTask(const std::string& name) const {
  for (const TaskSpec& t : tasks)
    if (t.name == name) return &t;
  return nullptr;
}

std::vector<std::string> Scene::Dependencies(const TaskSpec& task) const {
  std::vector<std::string> out;
  const auto add = [&](const std::string& n) {
    if (!n.empty() && std::find(out.begin(), out.end(), n) == out.end()) out.push_back(n);
  };
  const auto material_dep = [&](const std::string& m) {
    auto it = materials.find(m);
    if (it != materials.end() && it->second.kind == MaterialSpec::Kind::kFit) add(it->second.fit_task);
  };
  for (const std::string& t : task.Tasks()) add(t);
  for (const std::string& m : task.Materials()) material_dep(m);
  return out;
}

namespace {

// One entry of "materials".
MaterialSpec ParseMaterial(SceneReader& r, const Scene& s, const std::string& name, const std::string& path) {
  MaterialSpec m;
  m.name = name;
  const int kinds = int(r.Has("model")) + int(r.Has("measured")) + int(r.Has("merl")) + int(r.Has("table")) +
                    int(r.Has("fit"));
  if (kinds != 1)
    Fail(s.origin, path, "give exactly one of \"model\", \"measured\", \"merl\", \"table\" or \"fit\"");
  if (r.Has("model")) {
    m.kind = MaterialSpec::Kind::kAnalytic;
    const Model model = ParseModelAt(r, "model");
    if (!model.Info().settings.empty())
      r.FailKey("model", "'" + model.Spec() + "' reads a file: use \"measured\": FILE for measured materials");
    m.model = model.Spec();
    m.params = ReadParams(r, "params", model.Info());
  } else if (r.Has("measured") || r.Has("merl")) {
    // "merl" is "measured" restricted to MERL binaries.
    const std::string key = r.Has("measured") ? "measured" : "merl";
    m.kind = MaterialSpec::Kind::kMeasured;
    m.path = ExistingFile(s.base_dir, r.String(key), s.origin, r.Path(key));
    // The format and the whole file are checked now, not after other work.
    try {
      const formats::Format f = key == "merl" ? formats::Format::kMerl : formats::DetectFormat(m.path);
      if (f == formats::Format::kCsv) {
        m.kind = MaterialSpec::Kind::kTable;
      } else {
        m.model = formats::FormatName(f);  // the measured model of each format has its name
        (void)Model::Parse(m.model, Settings{{"path", m.path}});
      }
    } catch (const std::exception& e) {
      r.FailKey(key, e.what());
    }
  } else if (r.Has("table")) {
    m.kind = MaterialSpec::Kind::kTable;
    m.path = ExistingFile(s.base_dir, r.String("table"), s.origin, r.Path("table"));
  } else {
    m.kind = MaterialSpec::Kind::kFit;
    m.fit_task = r.String("fit");
  }
  return m;
}

// One entry of "instruments".
InstrumentSpec ParseInstrumentEntry(SceneReader& r, const Scene& s, const std::string& name, const std::string& path) {
  InstrumentSpec in;
  in.name = name;
  const std::string type = r.String("type");
  if (type != "gonioreflectometer" && type != "camera")
    r.FailKey("type", "unknown instrument type '" + type + "' (expected gonioreflectometer or camera)");
  in.camera = type == "camera";
  if (r.Has("file") && r.Has("spec")) Fail(s.origin, path, "give \"file\" or \"spec\", not both");
  try {
    if (r.Has("file")) {
      in.file = ExistingFile(s.base_dir, r.String("file"), s.origin, r.Path("file"));
      if (in.camera) in.rig = synth::LoadCameraRig(in.file);
      else in.instrument = synth::LoadInstrument(in.file);
    } else if (r.Has("spec")) {
      const json& spec = r.Get("spec");
      const std::string where = s.origin + ": " + r.Path("spec");
      if (in.camera) in.rig = synth::ParseCameraRig(spec, where);
      else in.instrument = synth::ParseInstrument(spec, where, s.base_dir);
    } else {
      if (in.camera) in.rig = synth::DefaultCameraRig();
      else in.instrument = synth::DefaultInstrument();
    }
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    // Messages from the instrument parser already name the file and key.
    if (what.rfind(s.origin, 0) == 0 || (!in.file.empty() && what.find(in.file) != std::string::npos)) throw;
    Fail(s.origin, path, what);
  }
  return in;
}

// A material of the scene named at `key`.
const MaterialSpec& NeedMaterial(SceneReader& r, const Scene& s, const std::string& key, const std::string& name) {
  auto it = s.materials.find(name);
  if (it == s.materials.end()) r.FailKey(key, "no material named '" + name + "' in \"materials\"");
  return it->second;
}

}  // namespace

// Each task type owns its keys: one parser per type, each reading its
// fields of the task object (the common name and type are read before).
void CheckTask::Parse(SceneReader& r, const Scene& s) {
  CheckTask& t = *this;
  t.materials = r.Strings("materials", true);
  if (t.materials.empty()) r.FailKey("materials", "name at least one material");
  for (std::size_t i = 0; i < t.materials.size(); ++i) {
    const MaterialSpec& m = NeedMaterial(r, s, "materials[" + std::to_string(i) + "]", t.materials[i]);
    if (m.kind == MaterialSpec::Kind::kTable)
      r.FailKey("materials[" + std::to_string(i) + "]",
                "'" + m.name + "' is a data table, which has no BRDF to check (fit a model to it first)");
  }
  t.sampling = r.Bool("sampling", true);
  t.sampling_samples = r.Integer("samples", 100000, validate::CheckOptions::kMinSamples, validate::CheckOptions::kMaxSamples);
  t.albedo_budget = r.Integer("albedo_budget", validate::CheckOptions().albedo_budget, validate::CheckOptions::kMinAlbedoBudget,
                              validate::CheckOptions::kMaxAlbedoBudget);
}

void AlbedoTask::Parse(SceneReader& r, const Scene& s) {
  AlbedoTask& t = *this;
  t.formats = r.Strings("formats", false);
  if (!r.Has("formats")) t.formats = {"csv", "exr", "header"};
  for (const std::string& f : t.formats)
    if (!kAlbedoFormats.count(f)) r.FailKey("formats", "unknown format '" + f + "' (expected csv, exr, header)");
  if (r.Has("preset")) {
    t.preset = r.String("preset");
    try {
      validate::PresetSize(t.preset, 0);  // the name: known presets are listed otherwise
    } catch (const ModelError& e) {
      r.FailKey("preset", e.what());
    }
    for (const char* key : {"model", "material", "params", "axes", "nodes", "part"})
      if (r.Has(key))
        r.FailKey(key, "a preset has its own models and axes: give \"preset\", \"model\" or \"material\", only one");
    const std::vector<std::string> names = validate::PresetTableNames(t.preset);
    t.tables = r.Strings("tables", false);
    for (std::size_t i = 0; i < t.tables.size(); ++i)
      if (std::find(names.begin(), names.end(), t.tables[i]) == names.end()) {
        std::string list;
        for (const std::string& n : names) list += (list.empty() ? "" : ", ") + n;
        r.FailKey("tables[" + std::to_string(i) + "]",
                  "preset '" + t.preset + "' has no table '" + t.tables[i] + "' (its tables: " + list + ")");
      }
    t.size = int(r.Integer("size", 0, 2, 4096));
    try {
      validate::PresetSize(t.preset, t.size);
    } catch (const ModelError& e) {
      r.FailKey("size", e.what());
    }
    t.tolerance = r.Number("tolerance", validate::PresetOptions{}.abs_tolerance, 1e-12, 1e-2);
    t.accept_error = r.Number("accept_error", t.accept_error, 1e-12, 1e3);
    return;
  }
  for (const char* key : {"tables", "size"})
    if (r.Has(key)) r.FailKey(key, "only with \"preset\"");
  if (r.Has("model") && r.Has("material")) r.FailKey("material", "give \"model\" or \"material\", not both");
  if (!r.Has("model") && !r.Has("material"))
    r.FailKey("model", "missing: give \"model\" (and \"params\"), \"material\" or \"preset\"");
  // The model whose parameters the axes may name; a fitted material's is
  // its fit task's, checked once every task is read (ParseScene).
  std::optional<Model> model;
  bool measured = false;
  if (r.Has("model")) {
    model = ParseModelAt(r, "model");
    if (!model->Info().settings.empty())
      r.FailKey("model", "'" + model->Spec() + "' reads a file: make it a material (\"measured\": FILE) and name it in \"material\"");
    t.model = model->Spec();
    t.params = ReadParams(r, "params", model->Info());
  } else {
    t.material = r.String("material");
    const MaterialSpec& m = NeedMaterial(r, s, "material", t.material);
    if (m.kind == MaterialSpec::Kind::kTable)
      r.FailKey("material", "'" + m.name + "' is a data table, which has no BRDF to tabulate (fit a model to it first)");
    if (r.Has("params")) r.FailKey("params", "a material has its own parameters (give \"model\" to set them)");
    if (m.kind == MaterialSpec::Kind::kAnalytic) model = Model::Parse(m.model);
    measured = m.kind == MaterialSpec::Kind::kMeasured;
  }
  t.axes = r.String("axes", t.axes);
  if (!r.Has("axes") && !t.material.empty()) t.axes = "mu:32";  // a material as it is
  try {
    const auto axes = validate::ParseAxes(t.axes);
    if (axes.empty() || axes[0].name != "mu") throw std::runtime_error("the first axis must be mu:N");
    if (axes.size() > 3)
      throw std::runtime_error("give mu alone or mu and one or two parameters, e.g. mu:32,alpha:32");
    if (measured && axes.size() > 1)
      throw std::runtime_error("'" + t.material + "' is measured data, which has no parameters: give mu alone, e.g. mu:32");
    if (model) CheckAxisParameters(model->Info(), axes);
  } catch (const std::exception& e) {
    r.FailKey("axes", e.what());
  }
  const std::string nodes = r.String("nodes", "uniform");
  if (nodes != "uniform" && nodes != "gauss") r.FailKey("nodes", "expected \"uniform\" or \"gauss\"");
  t.gauss_nodes = nodes == "gauss";
  t.tolerance = r.Number("tolerance", t.tolerance, 1e-12, 1e-2);
  t.accept_error = r.Number("accept_error", t.accept_error, 1e-12, 1e3);
  t.part = r.String("part", t.part);
  try {
    validate::ParsePart(t.part);
  } catch (const std::exception& e) {
    r.FailKey("part", e.what());
  }
}

void SynthTask::Parse(SceneReader& r, const Scene& s) {
  SynthTask& t = *this;
  t.material = r.String("material");
  const MaterialSpec& m = NeedMaterial(r, s, "material", t.material);
  if (m.kind == MaterialSpec::Kind::kTable)
    r.FailKey("material", "'" + m.name + "' is a data table: an instrument measures a BRDF, not a table");
  t.instrument = r.String("instrument");
  auto in = s.instruments.find(t.instrument);
  if (in == s.instruments.end())
    r.FailKey("instrument", "no instrument named '" + t.instrument + "' in \"instruments\"");
  t.seed = static_cast<std::uint64_t>(r.Integer("seed", 0, 0, INT64_MAX));
  t.formats = r.Strings("formats", false);
  if (!r.Has("formats")) t.formats = {"csv"};
  for (const std::string& f : t.formats) {
    if (!kSynthFormats.count(f)) r.FailKey("formats", "unknown format '" + f + "' (expected csv, binary, exr)");
    if (in->second.camera && f != "csv")
      r.FailKey("formats", "a camera writes raw EXR images and a reduced csv table; '" + f + "' does not apply");
    if (!in->second.camera && f == "binary" && in->second.instrument.plan.kind != synth::SamplingPlan::Kind::kMerl)
      r.FailKey("formats", "'binary' (MERL) needs an instrument whose plan is the MERL grid");
    if (!in->second.camera && f == "exr" && in->second.instrument.plan.kind != synth::SamplingPlan::Kind::kFull &&
        in->second.instrument.plan.kind != synth::SamplingPlan::Kind::kInPlane &&
        in->second.instrument.plan.kind != synth::SamplingPlan::Kind::kMerl)
      r.FailKey("formats", "'exr' needs a grid plan (full, in_plane or merl)");
  }
}

void FitTask::Parse(SceneReader& r, const Scene& s) {
  FitTask& t = *this;
  const std::string data = r.String("data");
  if (const TaskSpec* d = s.FindTask(data)) {
    if (!d->As<SynthTask>())
      r.FailKey("data", "task '" + data + "' is a " + d->TypeName() + " task; data comes from a synth task");
    t.data_task = data;
  } else if (s.materials.count(data)) {
    const MaterialSpec& m = s.materials.at(data);
    if (m.kind != MaterialSpec::Kind::kMeasured && m.kind != MaterialSpec::Kind::kTable)
      r.FailKey("data", "material '" + data + "' is not measured data (use a measured or table material, or a synth task)");
    t.data_material = data;
  } else {
    r.FailKey("data", "'" + data + "' is neither a synth task defined before this one nor a measured material");
  }
  const Model model = ParseModelAt(r, "model");
  if (!model.Info().settings.empty()) r.FailKey("model", "fit an analytic model or a sum of lobes");
  t.model = model.Spec();
  if (r.Has("init")) {
    t.init = r.String("init");
    try {
      ParseParams(model.Info(), t.init);
    } catch (const std::exception& e) {
      r.FailKey("init", e.what());
    }
  }
  {
    fit::Options constraints;
    for (const auto& [key, text] : {std::pair<const char*, std::string*>{"fix", &t.fix}, {"tie", &t.tie},
                                    {"bounds", &t.bounds}})
      if (r.Has(key)) *text = r.String(key);
    constraints.fix = t.fix;
    constraints.tie = t.tie;
    constraints.bounds = t.bounds;
    try {
      fit::CheckConstraints(model.Info(), constraints);
    } catch (const std::invalid_argument& e) {
      // The message starts with the option it is about ("tie: ...").
      const std::string what = e.what();
      const std::string key = what.substr(0, what.find(':'));
      r.FailKey(key == "tie" || key == "bounds" ? key.c_str() : "fix", what);
    }
  }
  // The fitter's own name parsers: a name it accepts is a name here.
  const auto parsed = [&r](const char* key, const std::string& text, auto parse) {
    try {
      parse(text);
    } catch (const std::invalid_argument& e) {
      r.FailKey(key, e.what());
    }
  };
  t.metric = r.String("metric", t.metric);
  parsed("metric", t.metric, fit::ParseMetric);
  t.loss = r.String("loss", t.loss);
  parsed("loss", t.loss, fit::ParseLoss);
  t.solver = r.String("solver", t.solver);
  parsed("solver", t.solver, fit::ParseLinearSolver);
  if (r.Has("instrument")) {
    t.instrument = r.String("instrument");
    auto in = s.instruments.find(t.instrument);
    if (in == s.instruments.end())
      r.FailKey("instrument", "no instrument named '" + t.instrument + "' in \"instruments\"");
    if (in->second.camera) r.FailKey("instrument", "fits go through a gonioreflectometer's apertures, not a camera");
  }
  t.max_iterations = static_cast<int>(r.Integer("max_iterations", t.max_iterations, 1, 100000));
  t.starts = static_cast<int>(r.Integer("starts", t.starts, 1, 100));
  t.random_starts = static_cast<int>(r.Integer("random_starts", t.random_starts, 0, fit::kMaxRandomStarts));
  t.seed = static_cast<std::uint64_t>(r.Integer("seed", 1, 0, INT64_MAX));
}

void ConvergenceTask::Parse(SceneReader& r, const Scene& /*scene*/) {
  ConvergenceTask& t = *this;
  t.quick = r.Bool("quick", true);
  t.methods = r.Strings("methods", false);
  for (const std::string& m : t.methods) {
    try {
      validate::ParseMethod(m);
    } catch (const std::invalid_argument& e) {
      r.FailKey("methods", e.what());
    }
  }
}

std::vector<std::string> TaskTypeNames() {
  std::vector<std::string> out;
  [&out]<std::size_t... I>(std::index_sequence<I...>) {
    (out.push_back(std::variant_alternative_t<I, TaskOptions>::kName), ...);
  }(std::make_index_sequence<std::variant_size_v<TaskOptions>>());
  return out;
}

namespace {

// The options of the task type named `type`, default-constructed.
bool MakeTaskOptions(const std::string& type, TaskOptions& out) {
  bool found = false;
  [&]<std::size_t... I>(std::index_sequence<I...>) {
    ((!found && type == std::variant_alternative_t<I, TaskOptions>::kName
          ? (out.emplace<I>(), found = true)
          : false),
     ...);
  }(std::make_index_sequence<std::variant_size_v<TaskOptions>>());
  return found;
}

}  // namespace

nlohmann::json SceneNames() {
  using nlohmann::json;
  json methods = json::array(), metrics = json::array(), losses = json::array(), solvers = json::array();
  for (validate::Method m : validate::AllMethods()) methods.push_back(validate::MethodName(m));
  for (fit::Metric m : fit::AllMetrics()) metrics.push_back(fit::MetricName(m));
  for (fit::Loss l : fit::AllLosses()) losses.push_back(fit::LossName(l));
  for (fit::LinearSolver l : fit::AllLinearSolvers()) solvers.push_back(fit::LinearSolverName(l));
  return json{{"task_types", TaskTypeNames()},
              {"instrument_types", {"gonioreflectometer", "camera"}},
              {"albedo_nodes", {"uniform", "gauss"}},
              {"albedo_parts", validate::PartNames()},
              {"albedo_presets", validate::PresetNames()},
              {"albedo_formats", kAlbedoFormats},
              {"synth_formats", kSynthFormats},
              {"metrics", metrics},
              {"losses", losses},
              {"solvers", solvers},
              {"methods", methods}};
}

Scene ParseScene(const std::string& text, const std::string& origin, const std::string& base_dir) {
  json root;
  try {
    root = json::parse(text);
  } catch (const json::exception& e) {
    // nlohmann's message gives the line and column (a number too large for a
    // double is an out_of_range error, not a parse_error).
    std::string what = e.what();
    const auto p = what.find("] ");
    throw std::runtime_error(origin + ": not valid JSON: " + (p == std::string::npos ? what : what.substr(p + 2)));
  }
  Scene s;
  s.origin = origin;
  s.base_dir = base_dir;
  SceneReader top(root, "", s.origin);
  top.Only({"$schema", "title", "output", "materials", "instruments", "tasks", "outputs"});
  if (top.Has("$schema")) top.Get("$schema");
  s.title = top.String("title", "");
  s.output = top.String("output", s.output);
  if (s.output.empty()) top.FailKey("output", "must not be empty");

  // Materials.
  if (top.Has("materials")) {
    const json& mats = top.Get("materials");
    if (!mats.is_object()) top.FailKey("materials", "expected an object of name: material");
    for (auto it = mats.begin(); it != mats.end(); ++it) {
      const std::string path = "materials." + it.key();
      CheckName(it.key(), s.origin, path);
      SceneReader r(it.value(), path, s.origin);
      MaterialSpec m = ParseMaterial(r, s, it.key(), path);
      r.Finish();
      s.materials[m.name] = m;
    }
  }

  // Instruments.
  if (top.Has("instruments")) {
    const json& insts = top.Get("instruments");
    if (!insts.is_object()) top.FailKey("instruments", "expected an object of name: instrument");
    for (auto it = insts.begin(); it != insts.end(); ++it) {
      const std::string path = "instruments." + it.key();
      CheckName(it.key(), s.origin, path);
      SceneReader r(it.value(), path, s.origin);
      InstrumentSpec in = ParseInstrumentEntry(r, s, it.key(), path);
      r.Finish();
      s.instruments[in.name] = in;
    }
  }

  // Tasks.
  const json& tasks = top.Get("tasks");
  if (!tasks.is_array() || tasks.empty()) top.FailKey("tasks", "expected a non-empty array of tasks");
  for (std::size_t k = 0; k < tasks.size(); ++k) {
    const std::string path = "tasks[" + std::to_string(k) + "]";
    SceneReader r(tasks[k], path, s.origin);
    TaskSpec t;
    t.json = tasks[k];
    t.name = r.String("name");
    CheckName(t.name, s.origin, r.Path("name"));
    if (s.FindTask(t.name)) r.FailKey("name", "a task named '" + t.name + "' is already defined");
    const std::string type = r.String("type");
    if (!MakeTaskOptions(type, t.options))
      r.FailKey("type", "unknown task type '" + type + "' (expected one of: " + Join(TaskTypeNames()) + ")");
    std::visit([&](auto& o) { o.Parse(r, s); }, t.options);
    r.Finish();
    s.tasks.push_back(std::move(t));
  }

  // Fitted materials name fit tasks.
  for (const auto& [name, m] : s.materials) {
    if (m.kind != MaterialSpec::Kind::kFit) continue;
    const TaskSpec* t = s.FindTask(m.fit_task);
    if (!t || !t->As<FitTask>())
      Fail(s.origin, "materials." + name + ".fit", "no fit task named '" + m.fit_task + "'");
  }
  // The axes of albedo tasks over a fitted material name its fit's parameters.
  for (std::size_t k = 0; k < s.tasks.size(); ++k) {
    const AlbedoTask* a = s.tasks[k].As<AlbedoTask>();
    if (!a || a->material.empty() || s.materials.at(a->material).kind != MaterialSpec::Kind::kFit) continue;
    const Model fitted = Model::Parse(s.FindTask(s.materials.at(a->material).fit_task)->As<FitTask>()->model);
    try {
      CheckAxisParameters(fitted.Info(), validate::ParseAxes(a->axes));
    } catch (const std::exception& e) {
      Fail(s.origin, "tasks[" + std::to_string(k) + "].axes", e.what());
    }
  }

  // Requested outputs.
  if (top.Has("outputs")) {
    s.requested = top.Strings("outputs", true);
    if (s.requested.empty()) top.FailKey("outputs", "name at least one task (or leave \"outputs\" out for all)");
    for (std::size_t i = 0; i < s.requested.size(); ++i)
      if (!s.FindTask(s.requested[i]))
        top.FailKey("outputs[" + std::to_string(i) + "]", "no task named '" + s.requested[i] + "'");
  } else {
    for (const TaskSpec& t : s.tasks) s.requested.push_back(t.name);
  }
  top.Finish();

  // Dependency cycles (a fit of data measured on its own result).
  std::map<std::string, int> state;  // 1 visiting, 2 done
  std::function<void(const std::string&, std::vector<std::string>&)> visit = [&](const std::string& n,
                                                                                std::vector<std::string>& stack) {
    if (state[n] == 2) return;
    stack.push_back(n);
    if (state[n] == 1) {
      std::string cycle;
      for (const std::string& x : stack) cycle += (cycle.empty() ? "" : " -> ") + x;
      Fail(s.origin, "tasks", "circular dependency: " + cycle);
    }
    state[n] = 1;
    for (const std::string& d : s.Dependencies(*s.FindTask(n))) visit(d, stack);
    state[n] = 2;
    stack.pop_back();
  };
  for (const TaskSpec& t : s.tasks) {
    std::vector<std::string> stack;
    visit(t.name, stack);
  }
  return s;
}

Scene LoadScene(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec))
    throw std::runtime_error(path + ": scene file not found" +
                             (fs::path(path).is_absolute() ? "" : " (resolved to '" + fs::absolute(path, ec).string() + "')"));
  if (fs::is_directory(path, ec)) throw std::runtime_error(path + ": is a directory, not a scene file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot read the scene file");
  std::stringstream ss;
  ss << in.rdbuf();
  const fs::path parent = fs::path(path).parent_path();
  return ParseScene(ss.str(), path, parent.empty() ? "." : parent.string());
}

}  // namespace brdfkit::cli
