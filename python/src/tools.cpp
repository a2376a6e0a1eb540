// The command line's tools on numpy arrays: check, albedo_table, synth, fit,
// stress, and the readers and writers of measured data.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>

#include "brdf/merl.h"
#include "brdf/params.h"
#include "cli/common.h"
#include "cli/tasks.h"
#include "data_synth/outputs.h"
#include "data_synth/synth.h"
#include "data_synth/table_io.h"
#include "fit/fit.h"
#include "fit/jet_models.h"
#include "formats/convert.h"
#include "python/src/callable.h"
#include "python/src/common.h"
#include "validate/albedo.h"
#include "validate/check.h"
#include "validate/presets.h"

namespace brdfkit::python {

namespace {

nlohmann::json FromPython(const py::handle& obj) {
  const std::string text = py::module_::import("json").attr("dumps")(obj).cast<std::string>();
  return nlohmann::json::parse(text);
}

py::dict Check(const py::object& model, const py::object& params, bool sampling, std::int64_t samples,
               int random_pairs, std::uint64_t seed, std::int64_t albedo_budget, int threads) {
  const ToolModel m = ToolModelArgument(model, params);
  using O = validate::CheckOptions;
  if (samples < O::kMinSamples || samples > O::kMaxSamples)
    throw ArgumentError("samples must lie in [" + std::to_string(O::kMinSamples) + ", " + std::to_string(O::kMaxSamples) +
                        "] (got " + std::to_string(samples) + ")");
  if (random_pairs < 1) throw ArgumentError("random_pairs must be at least 1");
  if (albedo_budget < O::kMinAlbedoBudget || albedo_budget > O::kMaxAlbedoBudget)
    throw ArgumentError("albedo_budget must lie in [" + std::to_string(O::kMinAlbedoBudget) + ", " +
                        std::to_string(O::kMaxAlbedoBudget) + "] (got " + std::to_string(albedo_budget) + ")");
  validate::CheckOptions o;
  o.sampling = sampling;
  o.sampling_samples = samples;
  o.random_pairs = random_pairs;
  o.seed = seed;
  o.albedo_budget = albedo_budget;
  validate::CheckResult r;
  RunTool(m, threads, [&](const CancelToken& token) {
    const CancellableBxdf b(*m.bxdf, token);
    r = validate::CheckPlausibility(b, m.params.data(), o);
  });
  nlohmann::json j = cli::CheckResultJson(r);
  j["model"] = m.spec;
  j["params"] = FormatParams(m.bxdf->Info(), m.params);
  return ToPython(j);
}

py::dict AlbedoTableFn(const py::object& model, const py::object& params, const std::string& axes,
                       const std::string& nodes, double tolerance, double accept_error, int channel,
                       const std::string& part, std::int64_t albedo_budget, int threads) {
  const ToolModel m = ToolModelArgument(model, params);
  if (!(albedo_budget >= 1000 && albedo_budget <= 1000000000))
    throw ArgumentError("albedo_budget must lie in [1000, 1e9] (got " + std::to_string(albedo_budget) + ")");
  if (nodes != "uniform" && nodes != "gauss")
    throw ArgumentError("nodes must be 'uniform' or 'gauss' (got '" + nodes + "')");
  if (!(tolerance >= 1e-12 && tolerance <= 1e-2))
    throw ArgumentError("tolerance must lie in [1e-12, 1e-2] (got " + FormatDouble(tolerance) + ")");
  if (channel < 0 || channel > 2) throw ArgumentError("channel must be 0, 1 or 2");
  validate::AlbedoTableRequest req;
  req.axes = validate::ParseAxes(axes);
  req.rule = nodes == "gauss" ? validate::NodeRule::kGauss : validate::NodeRule::kUniform;
  req.quadrature.abs_tolerance = tolerance;
  req.quadrature.max_evals = albedo_budget;
  req.quadrature.part = validate::ParsePart(part);
  // The tables' contract, as the command line: no table above its tolerance
  // unless a looser one is accepted explicitly.
  const double accepted = std::max(accept_error, tolerance);
  req.quadrature.accepted_error = accepted;
  req.channel = channel;
  validate::AlbedoTable t;
  RunTool(m, threads, [&](const CancelToken& token) {
    req.progress = [&token](std::size_t, std::size_t) { token.ThrowIfCancelled(); };
    t = validate::BuildAlbedoTable(*m.bxdf, m.spec, m.params, req);
  });
  const std::vector<validate::AlbedoMiss> misses = validate::EntriesAboveTolerance(t, accepted);
  if (!misses.empty())
    throw ArgumentError(validate::DescribeMisses(misses, accepted) + "\n" + validate::MissAdvice(t, "tolerance=1e-3") +
                        ", or accept a looser table with accept_error=.");
  return ToPython(cli::AlbedoTableJson(t));
}

py::dict AlbedoPreset(const std::string& name, int size, const std::vector<std::string>& tables, double tolerance,
                      double accept_error, int threads) {
  if (!(tolerance >= 1e-12 && tolerance <= 1e-2))
    throw ArgumentError("tolerance must lie in [1e-12, 1e-2] (got " + FormatDouble(tolerance) + ")");
  validate::PresetOptions o;
  o.size = size;
  o.tables = tables;
  o.abs_tolerance = tolerance;
  validate::Preset p;
  RunReleased(threads, [&](const CancelToken& token) {
    o.progress = [&token](std::size_t, std::size_t) { token.ThrowIfCancelled(); };
    p = validate::BuildPreset(name, o);
  });
  const double accepted = std::max(accept_error, tolerance);
  const std::string misses = validate::DescribePresetMisses(p, accepted);
  if (!misses.empty()) throw ArgumentError(misses + "\nAccept a looser table with accept_error=.");
  return ToPython(cli::PresetJson(p));
}

synth::Instrument InstrumentArgument(const py::object& instrument) {
  if (instrument.is_none()) return synth::DefaultInstrument();
  if (py::isinstance<py::str>(instrument) || py::isinstance(instrument, py::module_::import("os").attr("PathLike")))
    return synth::LoadInstrument(py::str(instrument).cast<std::string>());
  if (py::isinstance<py::dict>(instrument)) return synth::ParseInstrument(FromPython(instrument), "instrument");
  throw DtypeError("instrument must be None, a file name or a dict (the instrument JSON)");
}

py::dict Synth(const py::object& model, const py::object& params, const py::object& instrument,
               std::uint64_t seed, const std::vector<std::string>& out, int threads) {
  const ToolModel m = ToolModelArgument(model, params);
  const synth::Instrument inst = InstrumentArgument(instrument);
  synth::SynthResult r;
  synth::Provenance prov;
  prov.model = m.spec;
  prov.params = m.params;
  prov.params_text = FormatParams(m.bxdf->Info(), m.params);
  prov.seed = seed;
  RunTool(m, threads, [&](const CancelToken& token) {
    r = synth::Synthesize(inst, *m.bxdf, m.params, seed, synth::ExpandPlan(inst.plan),
                          [&token](std::size_t, std::size_t) { token.ThrowIfCancelled(); });
    for (const std::string& path : out) synth::WriteSynthOutput(path, inst, r, prov);
  });
  const std::size_t n = r.samples.size();
  py::array_t<double> wi({n, std::size_t(3)}), wo({n, std::size_t(3)}), f({n, std::size_t(3)}),
      sigma({n, std::size_t(3)});
  py::array_t<bool> valid(n), saturated(n);
  for (std::size_t k = 0; k < n; ++k) {
    const synth::PlannedPair& p = r.plan.pairs[k];
    const Eigen::Vector3d a = synth::DirectionFromAngles(p.theta_i, p.phi_i);
    const Eigen::Vector3d b = synth::DirectionFromAngles(p.theta_o, p.phi_o);
    for (int c = 0; c < 3; ++c) {
      wi.mutable_at(k, c) = a[c];
      wo.mutable_at(k, c) = b[c];
      f.mutable_at(k, c) = r.samples[k].f[c];
      sigma.mutable_at(k, c) = r.samples[k].sigma[c];
    }
    valid.mutable_at(k) = r.samples[k].valid;
    saturated.mutable_at(k) = r.samples[k].saturated;
  }
  py::dict d = ToPython(synth::Sidecar(inst, r, prov));
  d["wi"] = wi;
  d["wo"] = wo;
  d["f"] = f;
  d["sigma"] = sigma;
  d["valid"] = valid;
  d["saturated"] = saturated;
  return d;
}

// Fit data: a file name, or arrays wi, wo, f (N, 3) and optional sigma.
fit::Dataset DatasetArgument(const py::object& data, const py::object& wo_obj, const py::object& f_obj,
                             const py::object& sigma_obj) {
  if (py::isinstance<py::str>(data) || py::isinstance(data, py::module_::import("os").attr("PathLike"))) {
    if (!wo_obj.is_none() || !f_obj.is_none() || !sigma_obj.is_none())
      throw ArgumentError("give either a file name or arrays wi, wo, f (and sigma), not both");
    const std::string path = py::str(data).cast<std::string>();
    return fit::LoadDataset(path);
  }
  if (wo_obj.is_none() || f_obj.is_none()) throw ArgumentError("fit data: give a file name, or arrays wi, wo and f");
  const Rows<double> wi = AsRows<double>(data, "wi", 3, true);
  const Rows<double> wo = AsRows<double>(wo_obj, "wo", 3, true);
  const Rows<double> f = AsRows<double>(f_obj, "f", 3, false);
  if (wi.single || wo.single || f.single || wi.n != wo.n || wi.n != f.n)
    throw ArgumentError("fit data: wi, wo and f must all have shape (N, 3) with the same N (got " +
                        std::to_string(wi.n) + ", " + std::to_string(wo.n) + " and " + std::to_string(f.n) + " rows)");
  fit::Dataset d;
  d.source = "arrays";
  d.has_sigma = !sigma_obj.is_none();
  Rows<double> sigma;
  if (d.has_sigma) {
    sigma = AsRows<double>(sigma_obj, "sigma", 3, false);
    if (sigma.single || sigma.n != wi.n)
      throw ArgumentError("sigma must have shape (N, 3) like f (got " + std::to_string(sigma.n) + " rows)");
  }
  d.samples.resize(wi.n);
  for (std::size_t k = 0; k < wi.n; ++k) {
    fit::Sample& s = d.samples[k];
    for (int c = 0; c < 3; ++c) {
      s.wi[c] = wi.data()[3 * k + c];
      s.wo[c] = wo.data()[3 * k + c];
      s.f[c] = f.data()[3 * k + c];
      s.sigma[c] = d.has_sigma ? sigma.data()[3 * k + c] : 0.0;
      if (d.has_sigma && !(s.sigma[c] > 0))
        throw ArgumentError("sigma row " + std::to_string(k) + " must be positive (got " + FormatDouble(s.sigma[c]) + ")");
    }
  }
  return d;
}

py::dict Fit(const py::object& model, const py::object& data, const py::object& wo, const py::object& f,
             const py::object& sigma, const py::object& init, const std::string& metric, const std::string& loss,
             const std::string& solver, double max_theta_deg, int threads, int max_iterations, int starts,
             bool covariance, bool use_sigma, const py::object& instrument, int aperture_order,
             const std::string& fix, const std::string& tie, const std::string& bounds, int random_starts,
             std::uint64_t seed) {
  fit::Options o;
  o.fix = fix;
  o.tie = tie;
  o.bounds = bounds;
  try {
    o.metric = fit::ParseMetric(metric);
    o.solver = fit::ParseLinearSolver(solver);
  } catch (const std::invalid_argument& e) {
    throw ArgumentError(e.what());
  }
  cli::ParseFitLoss(loss, o);
  if (threads < 1) throw ArgumentError("threads must be at least 1");
  o.random_starts = random_starts;
  o.seed = seed;
  o.max_theta_deg = max_theta_deg;
  o.num_threads = threads;
  o.max_iterations = max_iterations;
  o.starts_per_param = starts;
  o.covariance = covariance;
  o.use_sigma = use_sigma;
  try {
    fit::CheckOptions(o, [](const std::string& field) { return field == "starts_per_param" ? "starts" : field; });
  } catch (const std::invalid_argument& e) {
    throw ArgumentError(e.what());
  }
  Model mm = Model::Parse("lambert");
  std::shared_ptr<PythonModel> python;
  if (py::isinstance<PythonModel>(model)) {
    python = model.cast<std::shared_ptr<PythonModel>>();
  } else if (py::isinstance<PyModel>(model)) {
    const PyModel pm = model.cast<PyModel>();
    mm = pm.model;
    if (init.is_none()) o.initial = pm.params;
  } else if (py::isinstance<py::str>(model)) {
    const std::string spec = model.cast<std::string>();
    if (spec.rfind("fit:", 0) == 0) {
      const cli::LoadedModel lm = cli::LoadFitModel(spec.substr(4));
      mm = lm.model;
      if (init.is_none()) o.initial = lm.params;
    } else {
      mm = Model::Parse(spec);
    }
  } else if (py::isinstance(model, py::module_::import("brdfkit._brdfkit").attr("Tabulated"))) {
    throw ArgumentError("a Tabulated has no parameters to fit");
  } else {
    throw DtypeError("model must be a brdfkit.Model, a model name such as 'lambert+ggx' or a PythonModel");
  }
  if (!init.is_none())
    o.initial = python ? ParseParams(python->info, ParamsText(init)) : MakeModel(mm.Spec(), init).params;
  fit::CheckConstraints(python ? python->info : mm.Info(), o);  // std::invalid_argument: ValueError naming the parameter
  synth::Instrument inst;
  if (!instrument.is_none()) {
    inst = InstrumentArgument(instrument);
    o.instrument = &inst;
    o.aperture_order = aperture_order;
  }
  const fit::Dataset ds = DatasetArgument(data, wo, f, sigma);
  fit::Result r;
  if (python) {
    ToolModel tm;
    tm.calls = std::make_shared<CallState>(false);
    const std::unique_ptr<fit::Evaluators> ev = FitEvaluators(python, ds, tm.calls);
    RunTool(tm, threads, [&](const CancelToken& token) {
      // After a failed call the evaluators only return NaN: stop at the next iteration.
      o.progress = [&token, &tm](int, double, double) {
        token.ThrowIfCancelled();
        if (tm.calls->Stopped()) throw Cancelled();
      };
      r = fit::Fit(*ev, ds, o);
    });
  } else {
    RunReleased(threads, [&](const CancelToken& token) {
      o.progress = [&token](int, double, double) { token.ThrowIfCancelled(); };
      r = fit::Fit(mm, ds, o);
    });
  }
  o.progress = nullptr;
  nlohmann::json j = cli::FitResultJson(r, o);
  if (python) {
    // A PythonModel's parameters are scalars: name -> value (null where not finite).
    j["model"] = python->info.name;
    for (const char* key : {"params", "stddev"}) {
      const std::vector<double>& v = key[0] == 'p' ? r.params : r.stddev;
      j[key] = nlohmann::json::object();
      for (std::size_t k = 0; k < v.size(); ++k)
        j[key][python->info.params[k].name] = std::isfinite(v[k]) ? nlohmann::json(v[k]) : nlohmann::json(nullptr);
    }
  }
  py::dict d = ToPython(j);
  const std::size_t n = r.params.size();
  d["packed_names"] = r.packed_names;
  d["packed_params"] = py::array_t<double>(n, r.params.data());
  d["packed_stddev"] = py::array_t<double>(n, r.stddev.data());
  py::array_t<double> cov({n, n});
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t k = 0; k < n; ++k)
      cov.mutable_at(i, k) = r.covariance_ok ? r.correlation(i, k) * r.stddev[i] * r.stddev[k]
                                             : std::numeric_limits<double>::quiet_NaN();
  d["covariance"] = cov;
  d["model_object"] = python ? py::object(model)
                             : py::cast(MakeModel(r.model.Spec(), py::str(FormatParams(r.model.Info(), r.params))));
  return d;
}

py::dict Stress(const std::vector<std::string>& models, const std::string& merl, bool sweep_only) {
  nlohmann::json j;
  {
    py::gil_scoped_release release;
    j = cli::StressJson(models, {{"merl", merl}}, sweep_only);
  }
  return ToPython(j);
}

// --- measured data files -----------------------------------------------------

py::dict DatasetDict(const fit::Dataset& d) {
  const std::size_t n = d.samples.size();
  py::array_t<double> wi({n, std::size_t(3)}), wo({n, std::size_t(3)}), f({n, std::size_t(3)}),
      sigma({n, std::size_t(3)});
  for (std::size_t k = 0; k < n; ++k)
    for (int c = 0; c < 3; ++c) {
      wi.mutable_at(k, c) = d.samples[k].wi[c];
      wo.mutable_at(k, c) = d.samples[k].wo[c];
      f.mutable_at(k, c) = d.samples[k].f[c];
      sigma.mutable_at(k, c) = d.samples[k].sigma[c];
    }
  py::dict out;
  out["wi"] = wi;
  out["wo"] = wo;
  out["f"] = f;
  out["sigma"] = d.has_sigma ? py::object(sigma) : py::object(py::none());
  out["missing"] = d.missing;
  return out;
}

py::dict ReadMerl(const std::string& path) {
  const MerlTable t = MerlTable::Read(path);
  py::dict d = DatasetDict(fit::FromMerl(t, path));
  py::array_t<double> values({std::size_t(3), std::size_t(MerlTable::kThetaH), std::size_t(MerlTable::kThetaD),
                              std::size_t(MerlTable::kPhiD)});
  std::copy(t.values.begin(), t.values.end(), values.mutable_data());
  d["values"] = values;
  d["format"] = "merl";
  return d;
}

void WriteMerl(const std::string& path, const py::object& data) {
  MerlTable t;
  const py::object v = py::isinstance<py::dict>(data) ? py::object(data.cast<py::dict>()["values"]) : data;
  auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(v);
  if (!a || a.size() != static_cast<py::ssize_t>(3 * MerlTable::kCells))
    throw ArgumentError("MERL data: give a Model, or values of shape (3, 90, 90, 180) (f_r in 1/sr, -1 missing)");
  for (py::ssize_t k = 0; k < a.size(); ++k) {
    if (!std::isfinite(a.data()[k]))
      throw ArgumentError("MERL values: entry " + std::to_string(k) + " is not finite");
    t.values[k] = a.data()[k];
  }
  t.Write(path);
}

// The samples of a measured file at its own nodes, as `fit --data` reads
// them (the cosine of RGL's stored product divided out), and its format.
py::dict ReadSamples(const std::string& path) {
  const formats::Format format = formats::DetectFormat(path);
  py::dict d = DatasetDict(fit::LoadDataset(path));
  d["format"] = formats::FormatName(format);
  return d;
}

// A model tabulated into a measured-data file of the format the path's
// extension names, as `brdfkit convert --model` does: what the sidecar of
// that command holds (source and target), as JSON text.
std::string WriteModel(const std::string& path, const py::object& model, const py::object& params,
                       const std::map<std::string, int>& rgl, double step_deg, int phi_i, bool anisotropic,
                       int threads) {
  (void)formats::FormatOfName(path);  // a bad target name fails before the work
  formats::ConvertOptions o;
  const std::map<std::string, int formats::RglOptions::*> fields = {
      {"theta_i", &formats::RglOptions::theta_i}, {"phi_i", &formats::RglOptions::phi_i},
      {"ndf", &formats::RglOptions::ndf},         {"sigma", &formats::RglOptions::sigma},
      {"vndf", &formats::RglOptions::vndf},       {"vndf_theta", &formats::RglOptions::vndf_theta},
      {"samples", &formats::RglOptions::samples}, {"symmetry", &formats::RglOptions::symmetry}};
  for (const auto& [name, value] : rgl) {
    const auto it = fields.find(name);
    if (it == fields.end()) {
      std::string known;
      for (const auto& field : fields) known += (known.empty() ? "" : ", ") + field.first;
      throw ArgumentError("rgl: unknown resolution '" + name + "' (known: " + known + ")");
    }
    o.rgl.*(it->second) = value;
  }
  if (!(step_deg >= 0.5 && step_deg <= 45))
    throw ArgumentError("step_deg must be 0.5 to 45 degrees, got " + FormatDouble(step_deg));
  o.step_deg = step_deg;
  o.phi_i = phi_i;
  o.anisotropic = anisotropic;
  const ToolModel m = ToolModelArgument(model, params);
  nlohmann::json side;
  RunTool(m, threads, [&](const CancelToken&) {
    const formats::BrdfFunction f = [&m](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
      return m.bxdf->Eval(m.params.data(), wi, wo);
    };
    side["source"] = formats::ModelSource(f, m.spec, FormatParams(m.bxdf->Info(), m.params), o);
    if (!m.settings.empty()) side["source"]["settings"] = m.settings;  // e.g. the measured file's path
    side["target"] = formats::WriteFormat(path, f, o);
  });
  return side.dump();
}

py::dict ReadCsv(const std::string& path) {
  py::dict d = DatasetDict(fit::FromTable(synth::ReadTableCsv(path), path));
  d["format"] = "csv";
  return d;
}

void WriteCsv(const std::string& path, const py::dict& data) {
  for (const char* key : {"wi", "wo", "f"})
    if (!data.contains(key)) throw ArgumentError(std::string("CSV data: missing '") + key + "' (arrays wi, wo, f, optional sigma)");
  const py::object sigma_obj = data.contains("sigma") ? py::object(data["sigma"]) : py::object(py::none());
  const fit::Dataset d = DatasetArgument(data["wi"], data["wo"], data["f"], sigma_obj);
  synth::BrdfTable t;
  t.has_sigma = d.has_sigma;
  for (const fit::Sample& s : d.samples) {
    synth::BrdfSample r;
    r.theta_i = std::acos(std::clamp(s.wi.z(), -1.0, 1.0));
    r.phi_i = std::atan2(s.wi.y(), s.wi.x());
    r.theta_o = std::acos(std::clamp(s.wo.z(), -1.0, 1.0));
    r.phi_o = std::atan2(s.wo.y(), s.wo.x());
    r.f = s.f;
    r.sigma = s.sigma;
    t.rows.push_back(r);
  }
  synth::WriteTableCsv(path, t);
}

}  // namespace

void BindTools(py::module_& m) {
  m.def("_check", &Check, py::arg("model"), py::arg("params"), py::arg("sampling"), py::arg("samples"),
        py::arg("random_pairs"), py::arg("seed"), py::arg("albedo_budget"), py::arg("threads"));
  m.def("_albedo_table", &AlbedoTableFn, py::arg("model"), py::arg("params"), py::arg("axes"), py::arg("nodes"),
        py::arg("tolerance"), py::arg("accept_error"), py::arg("channel"), py::arg("part"), py::arg("albedo_budget"),
        py::arg("threads"));
  m.def("_albedo_preset", &AlbedoPreset, py::arg("name"), py::arg("size"), py::arg("tables"), py::arg("tolerance"),
        py::arg("accept_error"), py::arg("threads"));
  m.def("_synth", &Synth, py::arg("model"), py::arg("params"), py::arg("instrument"), py::arg("seed"),
        py::arg("out"), py::arg("threads"));
  m.def("_fit", &Fit, py::arg("model"), py::arg("data"), py::arg("wo"), py::arg("f"), py::arg("sigma"),
        py::arg("init"), py::arg("metric"), py::arg("loss"), py::arg("solver"), py::arg("max_theta_deg"),
        py::arg("threads"), py::arg("max_iterations"), py::arg("starts"), py::arg("covariance"),
        py::arg("use_sigma"), py::arg("instrument"), py::arg("aperture_order"), py::arg("fix"), py::arg("tie"),
        py::arg("bounds"), py::arg("random_starts"), py::arg("seed"));
  m.def("_stress", &Stress, py::arg("models"), py::arg("merl"), py::arg("sweep_only"));
  m.def("_read_merl", &ReadMerl, py::arg("path"));
  m.def("_write_merl", &WriteMerl, py::arg("path"), py::arg("data"));
  m.def("_read_csv", &ReadCsv, py::arg("path"));
  m.def("_read_samples", &ReadSamples, py::arg("path"));
  m.def("_write_model", &WriteModel, py::arg("path"), py::arg("model"), py::arg("params"), py::arg("rgl"),
        py::arg("step_deg"), py::arg("phi_i"), py::arg("anisotropic"), py::arg("threads"));
  m.def("_write_csv", &WriteCsv, py::arg("path"), py::arg("data"));
}

}  // namespace brdfkit::python
