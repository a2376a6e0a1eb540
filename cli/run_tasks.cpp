// The tasks of a scene: check, albedo, synth, fit, convergence. Each writes
// into <out>/<task name>/ (every file atomically) and returns what the
// report shows.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>

#include "brdf/atomic_file.h"
#include "brdf/merl.h"
#include "brdf/params.h"
#include "cli/common.h"
#include "cli/progress.h"
#include "cli/run.h"
#include "cli/tasks.h"
#include "data_synth/camera.h"
#include "data_synth/outputs.h"
#include "fit/fit.h"
#include "validate/albedo.h"
#include "validate/presets.h"
#include "validate/check.h"
#include "validate/plot.h"

namespace brdfkit::cli {

// A material as a model and parameters (fitted ones from their fit's file).
LoadedModel MaterialModel(const MaterialSpec& m, const RunContext& ctx) {
  namespace fs = std::filesystem;
  switch (m.kind) {
    case MaterialSpec::Kind::kAnalytic: {
      LoadedModel out{Model::Parse(m.model), m.params, {}};
      return out;
    }
    case MaterialSpec::Kind::kMeasured: {
      LoadedModel out{Model::Parse(m.model, Settings{{"path", m.path}}), {}, {{"path", m.path}}};
      out.params = out.model.Info().Defaults();
      return out;
    }
    case MaterialSpec::Kind::kFit:
      return LoadFitModel((fs::path(ctx.out_dir) / m.fit_task / "fit.json").string());
    case MaterialSpec::Kind::kTable:
      break;
  }
  throw std::runtime_error("material '" + m.name + "' is a data table, not a BRDF");
}

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

constexpr double kDegree = kPi / 180;

std::string Describe(const MaterialSpec& m, const LoadedModel& lm) {
  switch (m.kind) {
    case MaterialSpec::Kind::kMeasured: return m.model + " file " + m.path;
    case MaterialSpec::Kind::kFit: return "fit '" + m.fit_task + "': " + lm.model.Spec() + " (" + FormatParams(lm.model.Info(), lm.params) + ")";
    default: return lm.model.Spec() + " (" + FormatParams(lm.model.Info(), lm.params) + ")";
  }
}

struct TaskDir {
  fs::path abs;
  std::string rel;
  TaskDir(const RunContext& ctx, const std::string& name) : abs(fs::path(ctx.out_dir) / name), rel(name) {
    std::error_code ec;
    fs::create_directories(abs, ec);
    if (!fs::is_directory(abs)) throw std::runtime_error("cannot create the output folder '" + abs.string() + "'");
  }
  std::string Abs(const std::string& file) const { return (abs / file).string(); }
  std::string Rel(const std::string& file) const { return rel + "/" + file; }
};

// log10 of f (one channel) at phi_d = 90 degrees over the MERL theta_h x
// theta_d bin centres: the usual image of an isotropic BRDF.
std::vector<double> HalfDiffLog10(const std::function<double(const Eigen::Vector3d&, const Eigen::Vector3d&)>& f) {
  constexpr int kN = 90;
  std::vector<double> v(kN * kN);
  for (int j = 0; j < kN; ++j)
    for (int i = 0; i < kN; ++i) {
      Eigen::Vector3d wi, wo;
      MerlTable::BinDirections(i, j, 90, wi, wo);
      const double x = (wi.z() > 0 && wo.z() > 0) ? f(wi, wo) : NAN;
      v[j * kN + i] = x > 0 ? std::log10(x) : NAN;
    }
  return v;
}

std::vector<double> HalfDiffNodes(bool theta_d) {
  std::vector<double> nodes(90);
  for (int i = 0; i < 90; ++i) {
    double th, td, pd;
    MerlTable::BinCentre(i, i, 90, th, td, pd);
    nodes[i] = (theta_d ? td : th) / kDegree;
  }
  return nodes;
}

void HalfDiffImage(const std::string& path, const std::string& title, const std::vector<double>& log10_f,
                   validate::ColourScale scale = {}) {
  scale.log10_values = true;
  if (scale.label.empty()) scale.label = "f_r [1/sr]";
  validate::HeatMap(path, title, "theta_h [deg]", "theta_d [deg]", HalfDiffNodes(false), HalfDiffNodes(true), log10_f,
                    scale);
}

void HalfDiffImage(const std::string& path, const std::string& title,
                   const std::function<double(const Eigen::Vector3d&, const Eigen::Vector3d&)>& f) {
  HalfDiffImage(path, title, HalfDiffLog10(f));
}

}  // namespace

// ------------------------------------------------------------------ check

TaskOutcome CheckTask::Run(const TaskSpec& spec, const RunContext& ctx) const {
  const CheckTask& t = *this;
  TaskOutcome o;
  TaskDir dir(ctx, spec.name);
  json materials = json::array();
  Progress progress("check " + spec.name, double(t.materials.size()), ctx.quiet);
  std::size_t implausible = 0, inconclusive = 0;
  for (std::size_t k = 0; k < t.materials.size(); ++k) {
    ThrowIfInterrupted();
    progress.Update(double(k), t.materials[k]);
    const MaterialSpec& m = ctx.scene.materials.at(t.materials[k]);
    const LoadedModel lm = MaterialModel(m, ctx);
    validate::CheckOptions opt;
    opt.sampling = t.sampling;
    opt.sampling_samples = t.sampling_samples;
    opt.albedo_budget = t.albedo_budget;
    const auto b = lm.model.Make<double>();
    const validate::CheckResult r = validate::CheckPlausibility(*b, lm.params.data(), opt);
    json j = CheckResultJson(r);
    j["material"] = m.name;
    j["model"] = lm.model.Spec();
    j["params"] = FormatParams(lm.model.Info(), lm.params);
    j["description"] = Describe(m, lm);
    implausible += r.reasons.empty() ? 0 : 1;
    inconclusive += r.reasons.empty() && !r.inconclusive.empty() ? 1 : 0;
    materials.push_back(j);
  }
  o.result = {{"materials", materials}, {"implausible", implausible}, {"inconclusive", inconclusive}};
  WriteFileAtomic(dir.Abs("check.json"), materials.dump(2) + "\n");
  o.files.push_back(dir.Rel("check.json"));
  return o;
}

// ------------------------------------------------------------------ albedo

// A renderer's table set: its files, and a figure per table (a heat map of
// its first two axes at the middle node of a third; a line over one axis;
// one per channel of a colour table).
TaskOutcome AlbedoTask::RunPreset(const TaskSpec& spec, const RunContext& ctx) const {
  TaskOutcome o;
  TaskDir dir(ctx, spec.name);
  validate::PresetOptions po;
  po.abs_tolerance = tolerance;
  po.size = size;
  po.tables = tables;
  ThreadedProgress progress("albedo " + spec.name, ctx.quiet);
  po.progress = progress.Callback();
  const validate::Preset p = validate::BuildPreset(preset, po);
  progress.Finish();
  const double accepted = std::max(accept_error, tolerance);
  const std::string misses = validate::DescribePresetMisses(p, accepted);
  if (!misses.empty()) throw ResultError("task '" + spec.name + "': " + misses + "\nSet \"accept_error\" to accept them.");
  const bool filament = preset == "filament";
  for (const std::string& f : formats) {
    if (f == "csv") {
      validate::WritePresetCsv(p, dir.Abs("tables.csv"));
      o.files.push_back(dir.Rel("tables.csv"));
    } else if (f == "exr") {
      validate::WritePresetExr(p, dir.Abs("tables.exr"));
      o.files.push_back(dir.Rel("tables.exr"));
    } else if (f == "header") {
      const std::vector<std::string> names =
          filament ? std::vector<std::string>{"dfg.h", "dfg.inc"}
                   : std::vector<std::string>{preset == "cycles" ? "shader_tables.h" : preset + ".h"};
      for (const std::string& name : names) {
        validate::WritePresetHeader(p, dir.Abs(name));
        o.files.push_back(dir.Rel(name));
      }
    }
  }
  json tables_j = json::array();
  for (const validate::PresetTable& t : p.tables) {
    double worst = 0;
    for (double e : t.error) worst = std::max(worst, e);
    tables_j.push_back({{"name", t.name}, {"definition", t.definition}, {"entries", t.value.size()}, {"max_error", worst}});
    const std::size_t nc = t.channels.size(), n0 = t.axes[0].coordinate.size();
    if (t.axes.size() == 1) {
      validate::Series s{t.channels[0], t.axes[0].coordinate, {}};
      for (std::size_t i = 0; i < n0; ++i) s.y.push_back(t.value[i * nc]);
      validate::LinePlot(dir.Abs(t.name + ".svg"), t.name, t.axes[0].name, t.channels[0], {s}, false, false);
      o.figures.push_back({t.name, dir.Rel(t.name + ".svg"), t.definition + "."});
      continue;
    }
    const std::size_t n1 = t.axes[1].coordinate.size();
    const std::size_t k2 = t.axes.size() > 2 ? t.axes[2].coordinate.size() / 2 : 0;
    std::string slice;
    if (t.axes.size() > 2) slice = " at " + t.axes[2].name + " = " + FormatDouble(t.axes[2].coordinate[k2]);
    for (std::size_t c = 0; c < nc; ++c) {
      std::vector<double> v(n0 * n1);
      for (std::size_t i1 = 0; i1 < n1; ++i1)
        for (std::size_t i0 = 0; i0 < n0; ++i0) v[i1 * n0 + i0] = t.value[((k2 * n1 + i1) * n0 + i0) * nc + c];
      const std::string name = t.name + (nc > 1 ? "_" + t.channels[c] : "");
      validate::HeatMap(dir.Abs(name + ".svg"), name + slice, t.axes[0].name, t.axes[1].name, t.axes[0].coordinate,
                        t.axes[1].coordinate, v, {t.channels[c], NAN, NAN, false});
      o.figures.push_back({name, dir.Rel(name + ".svg"),
                           t.definition + (nc > 1 ? " (channel " + t.channels[c] + ")" : "") + slice +
                               "; largest error estimate " + FormatDouble(worst) + "."});
    }
  }
  std::size_t entries = 0;
  for (const validate::PresetTable& t : p.tables) entries += t.value.size();
  o.result = {{"preset", preset},      {"model", "preset " + preset}, {"entries", entries},
              {"tables", tables_j},    {"max_error", p.max_error},    {"table_seconds", p.seconds}};
  return o;
}

TaskOutcome AlbedoTask::Run(const TaskSpec& spec, const RunContext& ctx) const {
  if (!preset.empty()) return RunPreset(spec, ctx);
  const AlbedoTask& t = *this;
  TaskOutcome o;
  TaskDir dir(ctx, spec.name);
  // The model and its parameters, given or those of a material.
  const LoadedModel lm = t.material.empty() ? LoadedModel{Model::Parse(t.model), t.params, {}}
                                            : MaterialModel(ctx.scene.materials.at(t.material), ctx);
  const Model& model = lm.model;
  validate::AlbedoTableRequest req;
  req.axes = validate::ParseAxes(t.axes);
  req.rule = t.gauss_nodes ? validate::NodeRule::kGauss : validate::NodeRule::kUniform;
  req.quadrature.abs_tolerance = t.tolerance;
  req.quadrature.part = validate::ParsePart(t.part);
  const double accepted = std::max(t.accept_error, t.tolerance);
  req.quadrature.accepted_error = accepted;
  ThreadedProgress progress("albedo " + spec.name, ctx.quiet);
  req.progress = progress.Callback();
  const validate::AlbedoTable table = validate::BuildAlbedoTable(model, lm.params, req);
  progress.Finish();
  const std::vector<validate::AlbedoMiss> misses = validate::EntriesAboveTolerance(table, accepted);
  if (!misses.empty())
    throw ResultError("task '" + spec.name + "': " + validate::DescribeMisses(misses, accepted) + "\n" +
                      validate::MissAdvice(table, "\"tolerance\": 1e-3") + ", or set \"accept_error\".");
  for (const std::string& f : t.formats) {
    if (f == "csv") {
      validate::WriteAlbedoCsv(table, dir.Abs("albedo.csv"));
      for (const char* name : {"albedo.csv", "albedo_avg.csv", "albedo_ms.csv", "albedo_f1.csv"})
        if (fs::exists(dir.Abs(name))) o.files.push_back(dir.Rel(name));
    } else if (f == "exr") {
      validate::WriteAlbedoExr(table, dir.Abs("albedo.exr"));
      o.files.push_back(dir.Rel("albedo.exr"));
    } else if (f == "header") {
      validate::WriteAlbedoHeader(table, dir.Abs("albedo.h"),
                                  AlbedoHeaderPrefix(t.material.empty() ? model.Spec() : t.material));
      o.files.push_back(dir.Rel("albedo.h"));
    }
  }
  json axes = json::array();
  for (const validate::Axis& a : table.params) axes.push_back({{"name", a.name}, {"nodes", a.nodes}});
  o.result = {{"model", table.model},      {"params", table.params_text}, {"part", table.part.empty() ? "E" : table.part},
              {"mu", table.mu.nodes},
              {"axes", axes},              {"E_avg", table.E_avg},         {"entries", table.E.size()},
              {"max_error", table.max_error}, {"limit_error", table.limit_error}, {"table_seconds", table.seconds}};
  if (!t.material.empty()) o.result["material"] = t.material;
  const std::string of = t.material.empty() ? table.model : "material '" + t.material + "' (" + table.model + ")";
  if (table.params.empty()) {
    // Over mu alone: E(mu) as a line, E_avg in the caption.
    validate::LinePlot(dir.Abs("E.svg"), "E(mu) of " + of, "mu = cos theta_o", "directional albedo E",
                       {{"E", table.mu.nodes, table.E}}, false, false);
    o.figures.push_back({"Directional albedo of " + of, dir.Rel("E.svg"),
                         "E(mu); E_avg = 2 int E(mu) mu dmu = " + FormatDouble(table.E_avg[0]) +
                             "; largest error estimate " + FormatDouble(table.max_error) + "."});
    return o;
  }
  // Figures: E over (mu, first parameter) at the first node of a second
  // parameter, and E_avg over the first parameter.
  const validate::Axis& a1 = table.params[0];
  std::vector<double> e(table.n_mu() * table.n1());
  for (std::size_t i1 = 0; i1 < table.n1(); ++i1)
    for (std::size_t m = 0; m < table.n_mu(); ++m) e[i1 * table.n_mu() + m] = table.at(m, i1, 0);
  std::string slice;
  if (table.params.size() > 1) slice = " at " + table.params[1].name + " = " + FormatDouble(table.params[1].nodes[0]);
  validate::HeatMap(dir.Abs("E.svg"), "E(mu, " + a1.name + ") of " + of + slice, "mu = cos theta_o", a1.name,
                    table.mu.nodes, a1.nodes, e, {"directional albedo E", 0.0, NAN, false});
  std::vector<validate::Series> avg;
  for (std::size_t i2 = 0; i2 < std::min<std::size_t>(table.n2(), 8); ++i2) {
    validate::Series s{table.params.size() > 1 ? table.params[1].name + " = " + FormatDouble(table.params[1].nodes[i2])
                                               : "E_avg",
                       a1.nodes, {}};
    for (std::size_t i1 = 0; i1 < table.n1(); ++i1) s.y.push_back(table.E_avg[i1 * table.n2() + i2]);
    avg.push_back(s);
  }
  validate::LinePlot(dir.Abs("E_avg.svg"), "average albedo E_avg of " + of, a1.name, "E_avg", avg, false, false);
  o.figures.push_back({"Directional albedo of " + of, dir.Rel("E.svg"),
                       "E(mu, " + a1.name + ")" + slice + "; colour scale from 0; largest error estimate " + FormatDouble(table.max_error) + "."});
  o.figures.push_back({"Average albedo of " + of, dir.Rel("E_avg.svg"),
                       "E_avg = 2 int E(mu) mu dmu; the Kulla-Conty lobe's normalisation is 1 / (pi (1 - E_avg))."});
  return o;
}

// ------------------------------------------------------------------ synth

namespace {

// Measured (markers) and optionally modelled (lines) in-plane slices:
// samples with both directions in the plane of incidence, grouped by
// theta_i; signed angle of wo from the normal, negative on the specular side.
struct Slice {
  double theta_i;
  std::vector<double> angle, f;
};

std::vector<Slice> InPlaneSlices(const std::vector<fit::Sample>& samples, int channel, std::size_t max_slices) {
  std::map<long, Slice> by_theta;
  for (const fit::Sample& s : samples) {
    if (std::abs(s.wi.y()) > 1e-9 || std::abs(s.wo.y()) > 1e-9 || s.wi.x() < -1e-12) continue;
    const double ti = std::acos(std::clamp(s.wi.z(), -1.0, 1.0));
    const long key = std::lround(ti / kDegree * 1000);
    Slice& sl = by_theta[key];
    sl.theta_i = ti;
    sl.angle.push_back(std::atan2(s.wo.x(), s.wo.z()));
    sl.f.push_back(s.f[channel]);
  }
  std::vector<Slice> all;
  for (auto& [k, s] : by_theta)
    if (s.f.size() >= 3) all.push_back(std::move(s));
  std::vector<Slice> out;
  if (all.empty()) return out;
  // Spread over theta_i: first, last and the middle ones.
  const std::size_t n = std::min(max_slices, all.size());
  for (std::size_t k = 0; k < n; ++k) {
    Slice s = all[n == 1 ? 0 : k * (all.size() - 1) / (n - 1)];
    std::vector<std::size_t> idx(s.angle.size());
    for (std::size_t i = 0; i < idx.size(); ++i) idx[i] = i;
    std::sort(idx.begin(), idx.end(), [&](std::size_t a, std::size_t b) { return s.angle[a] < s.angle[b]; });
    Slice sorted{s.theta_i, {}, {}};
    for (std::size_t i : idx) {
      sorted.angle.push_back(s.angle[i]);
      sorted.f.push_back(s.f[i]);
    }
    out.push_back(sorted);
  }
  return out;
}

}  // namespace

TaskOutcome SynthTask::Run(const TaskSpec& spec, const RunContext& ctx) const {
  const SynthTask& t = *this;
  TaskOutcome o;
  TaskDir dir(ctx, spec.name);
  const MaterialSpec& m = ctx.scene.materials.at(t.material);
  const LoadedModel lm = MaterialModel(m, ctx);
  const InstrumentSpec& in = ctx.scene.instruments.at(t.instrument);
  ThreadedProgress progress("synth " + spec.name, ctx.quiet);
  if (in.camera) {
    const synth::CameraCapture cap = synth::RenderCamera(in.rig, lm.model, lm.params, t.seed);
    ThrowIfInterrupted();
    const std::vector<std::string> raw =
        synth::WriteCameraCapture(dir.Abs("raw"), in.rig, cap, lm.model.Spec(), lm.params, t.seed);
    for (const std::string& f : raw) o.files.push_back(dir.Rel(fs::path(f).filename().string()));
    o.files.push_back(dir.Rel("raw.json"));
    const synth::BrdfTable table = synth::ReduceCamera(in.rig, raw);
    synth::WriteTableCsv(dir.Abs("data.csv"), table);
    o.files.push_back(dir.Rel("data.csv"));
    // The first exposure's green channel, top row at the top.
    const int w = in.rig.width, h = in.rig.height;
    std::vector<double> xs(w), ys(h), v(std::size_t(w) * h);
    for (int x = 0; x < w; ++x) xs[x] = x;
    for (int y = 0; y < h; ++y) ys[y] = y;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) v[std::size_t(h - 1 - y) * w + x] = cap.raw[0][std::size_t(w) * h + std::size_t(y) * w + x];
    validate::HeatMap(dir.Abs("raw.svg"), "raw image, green channel, exposure 1", "x [pixel]", "y [pixel]", xs, ys, v,
                      {"sensor value [DN]", NAN, NAN, false});
    o.figures.push_back({"Camera image of " + m.name, dir.Rel("raw.svg"),
                         "Raw sensor values before reduction (cos^4 falloff and noise included)."});
    o.result = {{"material", m.name}, {"description", Describe(m, lm)}, {"instrument", t.instrument}, {"camera", true},
                {"samples", table.rows.size()}, {"images", raw.size()}};
    return o;
  }
  const synth::Instrument& inst = in.instrument;
  const synth::SynthResult r = synth::Synthesize(inst, lm.model, lm.params, t.seed, progress.Callback());
  progress.Finish();
  synth::Provenance prov;
  prov.model = lm.model.Spec();
  prov.params = lm.params;
  prov.params_text = FormatParams(lm.model.Info(), lm.params);
  prov.seed = t.seed;
  prov.command = "brdfkit run " + ctx.scene.origin + " (task " + spec.name + ")";
  // data.csv is always written: it is what fits read.
  synth::WriteSynthOutput(dir.Abs("data.csv"), inst, r, prov);
  o.files.push_back(dir.Rel("data.csv"));
  o.files.push_back(dir.Rel("data.csv.json"));
  for (const std::string& f : t.formats) {
    if (f == "csv") continue;
    const std::string name = f == "binary" ? "data.binary" : "data.exr";
    synth::WriteSynthOutput(dir.Abs(name), inst, r, prov);
    o.files.push_back(dir.Rel(name));
    o.files.push_back(dir.Rel(name + ".json"));
  }
  // Figures: in-plane slices, or a theta_h x theta_d image for MERL plans.
  std::vector<fit::Sample> samples;
  for (std::size_t k = 0; k < r.samples.size(); ++k) {
    if (!r.samples[k].valid) continue;
    const synth::PlannedPair& p = r.plan.pairs[k];
    samples.push_back({synth::DirectionFromAngles(p.theta_i, p.phi_i), synth::DirectionFromAngles(p.theta_o, p.phi_o),
                       r.samples[k].f, r.samples[k].sigma});
  }
  const std::vector<Slice> slices = InPlaneSlices(samples, 1, 4);
  if (!slices.empty()) {
    std::vector<validate::Series> series;
    for (const Slice& s : slices)
      series.push_back({"theta_i = " + FormatDouble(std::round(s.theta_i / kDegree * 10) / 10) + " deg", s.angle, s.f});
    validate::PolarPlot(dir.Abs("slices.svg"), "measured f_r (green), plane of incidence", "f_r [1/sr]", series,
                        std::vector<bool>(series.size(), true), {}, true, 3);
    o.figures.push_back({"Synthetic measurement of " + m.name, dir.Rel("slices.svg"),
                         "In-plane samples; light from positive angles, the specular direction at negative angles. Log radius over "
                         "three decades below the peak; smaller values sit at the centre."});
  }
  if (inst.plan.kind == synth::SamplingPlan::Kind::kMerl) {
    const auto b = lm.model.Make<double>();
    HalfDiffImage(dir.Abs("halfdiff.svg"), "log10 f_r (green) of " + m.name + ", phi_d = 90 deg",
                  [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return b->Eval(lm.params.data(), wi, wo)[1]; });
    o.figures.push_back({"BRDF slice of " + m.name, dir.Rel("halfdiff.svg"), "theta_h x theta_d image of the measured material."});
  }
  const synth::SynthReport& rep = r.report;
  o.result = {{"material", m.name},
              {"description", Describe(m, lm)},
              {"instrument", t.instrument},
              {"camera", false},
              {"measured", rep.measured},
              {"not_measured", rep.not_measured},
              {"saturated", rep.saturated},
              {"aperture_order", rep.order},
              {"quadrature_error", rep.quadrature_error},
              {"pairs_above_tolerance", rep.pairs_at_max_order},
              {"noisy", r.noisy},
              {"seed", t.seed},
              {"synth_seconds", rep.seconds}};
  return o;
}

// ------------------------------------------------------------------ fit

TaskOutcome FitTask::Run(const TaskSpec& spec, const RunContext& ctx) const {
  const FitTask& t = *this;
  TaskOutcome o;
  TaskDir dir(ctx, spec.name);
  const std::string data_path = !t.data_task.empty()
                                    ? (fs::path(ctx.out_dir) / t.data_task / "data.csv").string()
                                    : ctx.scene.materials.at(t.data_material).path;
  const fit::Dataset ds = fit::LoadDataset(data_path);
  const Model model = Model::Parse(t.model);
  fit::Options opt;
  opt.metric = fit::ParseMetric(t.metric);
  opt.solver = fit::ParseLinearSolver(t.solver);
  opt.loss = fit::ParseLoss(t.loss);
  opt.max_iterations = t.max_iterations;
  opt.starts_per_param = t.starts;
  opt.random_starts = t.random_starts;
  opt.seed = t.seed;
  if (!t.init.empty()) opt.initial = ParseParams(model.Info(), t.init);
  opt.fix = t.fix;
  opt.tie = t.tie;
  opt.bounds = t.bounds;
  synth::Instrument inst;
  if (!t.instrument.empty()) {
    inst = ctx.scene.instruments.at(t.instrument).instrument;
    opt.instrument = &inst;
  }
  Progress progress("fit " + spec.name, 0, ctx.quiet);  // the number of iterations is not known in advance
  opt.progress = [&](int iteration, double, double cost) {
    // Between iterations: the solver's state is consistent, so stopping here is clean.
    ThrowIfInterrupted();
    progress.Update(iteration, "iteration " + std::to_string(iteration) + ", cost " + FormatDouble(cost));
  };
  const fit::Result r = fit::Fit(model, ds, opt);
  progress.Finish();
  json j = FitResultJson(r, opt);
  j["data"] = !t.data_task.empty() ? "task " + t.data_task : data_path;
  WriteFileAtomic(dir.Abs("fit.json"), j.dump(2) + "\n");
  WriteFileAtomic(dir.Abs("trace.csv"), FitTraceCsv(r));
  o.files = {dir.Rel("fit.json"), dir.Rel("trace.csv")};
  try {
    WriteFitTracePlot(dir.Abs("trace.svg"), r);
    o.files.push_back(dir.Rel("trace.svg"));
    o.figures.push_back({"Fit " + spec.name + ": error against run time", dir.Rel("trace.svg"),
                         "Metric RMSE after each accepted iteration against seconds since the start: the "
                         "multi-start solves (grey, each on a subset of the samples; for a sum also its nested "
                         "sub-sums, refined on all samples), then the final solve from the best start on all "
                         "samples."});
  } catch (const std::invalid_argument&) {
    // A fit that converged at its starting point has no positive trace to draw.
  }
  const auto fitted = model.Make<double>();
  // Measured against fitted, in the plane of incidence.
  const std::vector<Slice> slices = InPlaneSlices(ds.samples, 1, 3);
  if (!slices.empty()) {
    std::vector<validate::Series> series;
    std::vector<bool> markers;
    std::vector<int> colours;
    for (const Slice& s : slices) {
      colours.push_back(int(colours.size() / 2));
      colours.push_back(int(colours.size() / 2));
      const std::string label = "theta_i = " + FormatDouble(std::round(s.theta_i / kDegree * 10) / 10);
      series.push_back({label + " measured", s.angle, s.f});
      markers.push_back(true);
      validate::Series line{label + " fitted", {}, {}};
      const Eigen::Vector3d wi = synth::DirectionFromAngles(s.theta_i, 0);
      for (int k = -89 * 4; k <= 89 * 4; ++k) {
        const double a = k * 0.25 * kDegree;
        const Eigen::Vector3d wo(std::sin(a), 0, std::cos(a));
        line.x.push_back(a);
        line.y.push_back(fitted->Eval(r.params.data(), wi, wo)[1]);
      }
      series.push_back(line);
      markers.push_back(false);
    }
    validate::PolarPlot(dir.Abs("slices.svg"), "measured and fitted f_r (green), plane of incidence", "f_r [1/sr]",
                        series, markers, colours, true, 3);
    o.files.push_back(dir.Rel("slices.svg"));
    o.figures.push_back({"Fit " + spec.name + ": measured against fitted", dir.Rel("slices.svg"),
                         "Points: data; lines: the fitted " + r.model.Spec() + ", one colour per theta_i. Light from positive angles; "
                         "log radius over three decades below the peak."});
  }
  // Residuals against the half-vector angle: RMS relative residual per bin.
  {
    constexpr int kBins = 18;
    std::vector<double> centre(kBins), sum2[3], count(kBins, 0.0);
    for (auto& v : sum2) v.assign(kBins, 0.0);
    for (const fit::Sample& s : ds.samples) {
      const Eigen::Vector3d h = (s.wi + s.wo).normalized();
      const int bin = std::min(kBins - 1, static_cast<int>(std::acos(std::clamp(h.z(), -1.0, 1.0)) / (90 * kDegree) * kBins));
      const Rgb<double> f = fitted->Eval(r.params.data(), s.wi, s.wo);
      bool any = false;
      for (int c = 0; c < 3; ++c)
        if (s.f[c] > 0) {
          const double rel = (f[c] - s.f[c]) / s.f[c];
          sum2[c][bin] += rel * rel;
          any = true;
        }
      count[bin] += any ? 1 : 0;
    }
    std::vector<validate::Series> series;
    static const char* kNames[3] = {"red", "green", "blue"};
    for (int c = 0; c < 3; ++c) {
      validate::Series s{kNames[c], {}, {}};
      for (int b = 0; b < kBins; ++b)
        if (count[b] > 0 && sum2[c][b] > 0) {
          s.x.push_back((b + 0.5) * 90.0 / kBins);
          s.y.push_back(std::sqrt(sum2[c][b] / count[b]));
        }
      if (!s.x.empty()) series.push_back(s);
    }
    if (!series.empty()) {
      validate::LinePlot(dir.Abs("residuals.svg"), "fit residuals: RMS of (fitted - measured) / measured", "theta_h [deg]",
                         "RMS relative residual", series, false, true);
      o.files.push_back(dir.Rel("residuals.svg"));
      o.figures.push_back({"Fit " + spec.name + ": residuals", dir.Rel("residuals.svg"),
                           "Per 5-degree bin of the half-vector angle theta_h, per channel; the model is evaluated at the nominal "
                           "directions (without the instrument's apertures)."});
    }
  }
  // theta_h x theta_d images at phi_d = 90 deg (the plane of incidence) on
  // 3-degree cells: the samples within 15 degrees of that phi_d, the fitted
  // model at the cell centres, and fitted / measured at the samples.
  {
    constexpr int kCells = 30;
    constexpr double kWidth = 90.0 / kCells;
    std::vector<double> nodes(kCells), meas(kCells * kCells, 0.0), fit_at(kCells * kCells, 0.0),
        count(kCells * kCells, 0.0), fitted_log(kCells * kCells, NAN);
    for (int i = 0; i < kCells; ++i) nodes[i] = (i + 0.5) * kWidth;
    for (const fit::Sample& s : ds.samples) {
      double th, td, pd;
      MerlTable::DirectionsToHalfDiff(s.wi, s.wo, th, td, pd);
      if (std::abs(pd - 90 * kDegree) > 15 * kDegree || !(s.f[1] > 0)) continue;
      const int ih = std::min(kCells - 1, int(th / kDegree / kWidth)), id = std::min(kCells - 1, int(td / kDegree / kWidth));
      meas[id * kCells + ih] += s.f[1];
      fit_at[id * kCells + ih] += fitted->Eval(r.params.data(), s.wi, s.wo)[1];
      count[id * kCells + ih] += 1;
    }
    std::vector<double> log_meas(meas.size(), NAN), log_ratio(meas.size(), NAN);
    double lo = INFINITY, hi = -INFINITY;
    for (std::size_t k = 0; k < meas.size(); ++k) {
      if (count[k] > 0) {
        log_meas[k] = std::log10(meas[k] / count[k]);
        if (fit_at[k] > 0) log_ratio[k] = std::log10(fit_at[k] / meas[k]);
        lo = std::min(lo, log_meas[k]);
        hi = std::max(hi, log_meas[k]);
      }
      Eigen::Vector3d wi, wo;
      MerlTable::HalfDiffToDirections(nodes[k % kCells] * kDegree, nodes[k / kCells] * kDegree, 90 * kDegree, wi, wo);
      const double f = (wi.z() > 0 && wo.z() > 0) ? fitted->Eval(r.params.data(), wi, wo)[1] : NAN;
      fitted_log[k] = f > 0 ? std::log10(f) : NAN;
    }
    const std::string fitted_spec = r.model.Spec();
    // The fitted image shares the measured colour range, so equal colours are equal values.
    const validate::ColourScale measured_scale{"f_r [1/sr]", lo, hi, true};
    if (hi >= lo) {
      validate::HeatMap(dir.Abs("halfdiff_measured.svg"), "measured f_r (green), phi_d = 90 deg", "theta_h [deg]",
                        "theta_d [deg]", nodes, nodes, log_meas, measured_scale);
      o.figures.push_back({"Fit " + spec.name + ": measured theta_h x theta_d image", dir.Rel("halfdiff_measured.svg"),
                           "Mean measured f_r per 3-degree cell (samples within 15 degrees of phi_d = 90 deg); grey "
                           "cells hold no sample."});
    }
    validate::HeatMap(dir.Abs("halfdiff.svg"), "fitted " + fitted_spec + " f_r (green), phi_d = 90 deg", "theta_h [deg]",
                      "theta_d [deg]", nodes, nodes, fitted_log, hi >= lo ? measured_scale : validate::ColourScale{"f_r [1/sr]", NAN, NAN, true});
    o.figures.push_back({"Fit " + spec.name + ": fitted theta_h x theta_d image", dir.Rel("halfdiff.svg"),
                         "The fitted model at the cell centres, on the measured image's colour scale (values beyond it "
                         "saturate at the end colours); grey: below the horizon."});
    if (hi >= lo) {
      validate::HeatMap(dir.Abs("halfdiff_ratio.svg"), "fitted / measured (green), phi_d = 90 deg", "theta_h [deg]",
                        "theta_d [deg]", nodes, nodes, log_ratio, {"fitted / measured", -std::log10(2.0), std::log10(2.0), true});
      o.figures.push_back({"Fit " + spec.name + ": fitted / measured", dir.Rel("halfdiff_ratio.svg"),
                           "Ratio of the fitted model to the data per cell, on a log scale from 1/2 to 2 (beyond it "
                           "saturated); grey cells hold no sample."});
    }
  }
  o.result = j;
  o.result.erase("trace");
  o.result["data_missing"] = ds.missing;
  return o;
}

// ------------------------------------------------------------------ convergence

TaskOutcome ConvergenceTask::Run(const TaskSpec& spec, const RunContext& ctx) const {
  const ConvergenceTask& t = *this;
  TaskOutcome o;
  TaskDir dir(ctx, spec.name);
  const ConvergenceOutcome c = RunConvergence(dir.abs.string(), t.methods, t.quick, false, ctx.quiet);
  o.files = {dir.Rel("convergence.csv"), dir.Rel("convergence.svg"), dir.Rel("convergence_summary.md")};
  o.figures.push_back({"Hemisphere integrators: error against run time", dir.Rel("convergence.svg"),
                       "Worst absolute error over the reference integrals against the mean time per integral."});
  o.result = {{"summary_markdown", c.summary_markdown}, {"rows", c.rows}, {"cases", c.cases}, {"quick", t.quick}};
  return o;
}

TaskOutcome RunTask(const TaskSpec& task, const RunContext& ctx) {
  const auto start = std::chrono::steady_clock::now();
  TaskOutcome o = std::visit([&](const auto& options) { return options.Run(task, ctx); }, task.options);
  for (const Figure& f : o.figures)
    if (std::find(o.files.begin(), o.files.end(), f.file) == o.files.end()) o.files.push_back(f.file);
  o.name = task.name;
  o.type = task.TypeName();
  o.status = "computed";
  o.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return o;
}

}  // namespace brdfkit::cli
