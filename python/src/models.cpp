// brdfkit.models() and the Model class: f_r, sampling, pdf and albedo on
// numpy arrays.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "brdf/params.h"
#include "cli/common.h"
#include "python/src/callable.h"
#include "python/src/common.h"
#include "validate/albedo.h"

namespace brdfkit::python {

namespace {

// "name=value" text of one dict entry: a number, or r:g:b for a sequence.
std::string AssignmentText(const py::handle& key, const py::handle& value) {
  const std::string name = py::str(key).cast<std::string>();
  if (py::isinstance<py::str>(value)) return name + "=" + value.cast<std::string>();
  if (py::isinstance<py::float_>(value) || py::isinstance<py::int_>(value) ||
      (py::isinstance<py::array>(value) && py::reinterpret_borrow<py::array>(value).ndim() == 0))
    return name + "=" + FormatDouble(value.cast<double>());
  if (py::isinstance<py::sequence>(value) || py::isinstance<py::array>(value)) {
    std::string s = name + "=";
    int k = 0;
    for (const py::handle& v : value) s += (k++ ? ":" : "") + FormatDouble(v.cast<double>());
    return s;
  }
  throw ArgumentError("parameter '" + name + "': expected a number, (r, g, b) or a string");
}

}  // namespace

std::string ParamsText(const py::object& params) {
  std::string text;
  if (params.is_none()) {
  } else if (py::isinstance<py::str>(params)) {
    text = params.cast<std::string>();
  } else if (py::isinstance<py::dict>(params)) {
    for (const auto& [k, v] : params.cast<py::dict>()) text += (text.empty() ? "" : ",") + AssignmentText(k, v);
  } else {
    throw DtypeError("params must be None, a dict or a string name=value,...");
  }
  return text;
}

PyModel MakeModel(const std::string& spec, const py::object& params) {
  cli::ModelArgs args{spec, ParamsText(params)};
  cli::LoadedModel lm = cli::LoadModel(args);
  PyModel m{lm.model, lm.params, {}, nullptr, nullptr, lm.settings};
  m.params_f.assign(m.params.begin(), m.params.end());
  m.bxdf = m.model.Make<double>();
  m.bxdf_f = m.model.Make<float>();
  return m;
}

PyModel ModelArgument(const py::object& model, const py::object& params) {
  if (py::isinstance<PyModel>(model)) {
    if (!params.is_none()) throw ArgumentError("params are given with the Model; pass a model name to give them here");
    return model.cast<PyModel>();
  }
  if (py::isinstance<py::str>(model)) return MakeModel(model.cast<std::string>(), params);
  throw DtypeError("model must be a brdfkit.Model or a model name such as 'lambert+ggx'");
}

namespace {

// f_r of the rows of wi and wo. The values are checked chunk by chunk
// right before the chunk is evaluated, with the GIL released, so the input
// is read from memory once; on a bad row the arguments are checked again in
// AsRows's order (wi, then wo) to raise AsRows's message.
template <typename T>
py::array_t<T> EvalT(const Bxdf<T>& b, const T* p, const py::handle& wi_obj, const py::handle& wo_obj) {
  const Rows<T> wi = AsRowsUnchecked<T>(wi_obj, "wi", 3);
  const auto raise = [&](const Rows<T>* wo) {
    CheckRows(wi, "wi", 3, true);
    if (wo) CheckRows(*wo, "wo", 3, true);
  };
  Rows<T> wo;
  std::size_t n = 0;
  try {
    wo = AsRowsUnchecked<T>(wo_obj, "wo", 3);
  } catch (const std::exception&) {
    raise(nullptr);  // wi's values come before wo's shape
    throw;
  }
  try {
    n = BroadcastRows("wi", wi.n, wi.single, "wo", wo.n, wo.single);
  } catch (const std::exception&) {
    raise(&wo);  // the values before the row counts
    throw;
  }
  py::array_t<T> out = NewRows<T>(n, 3, wi.single && wo.single);
  T* o = out.mutable_data();
  bool bad = (wi.single && !UnitRows(wi.data(), 1)) || (wo.single && !UnitRows(wo.data(), 1));
  if (!bad) {
    py::gil_scoped_release release;
    // 2048 pairs: 96 kB of input and 48 kB of output in double, in cache.
    constexpr std::size_t kChunk = 2048;
    for (std::size_t start = 0; start < n; start += kChunk) {
      const std::size_t m = std::min(kChunk, n - start);
      const T* a = wi.data() + start * wi.stride;
      const T* c = wo.data() + start * wo.stride;
      if ((!wi.single && !UnitRows(a, m)) || (!wo.single && !UnitRows(c, m))) {
        bad = true;
        break;
      }
      b.EvalBatch(p, a, wi.stride, c, wo.stride, m, o + 3 * start);
    }
  }
  if (bad) {
    raise(&wo);
    throw std::logic_error("eval: a row failed the unit-vector test but passed AsRows's");
  }
  return out;
}

template <typename T>
py::tuple SampleT(const Bxdf<T>& b, const T* p, const py::handle& wo_obj, const py::handle& u_obj) {
  const Rows<T> wo = AsRows<T>(wo_obj, "wo", 3, true);
  const Rows<double> u = AsRows<double>(u_obj, "u", 2, false);
  const std::size_t n = BroadcastRows("wo", wo.n, wo.single, "u", u.n, u.single);
  const bool single = wo.single && u.single;
  for (std::size_t k = 0; k < (u.single ? 1 : u.n); ++k)
    for (int c = 0; c < 2; ++c)
      if (!(u.data()[2 * k + c] >= 0 && u.data()[2 * k + c] < 1))
        throw ArgumentError("u" + (u.single ? std::string() : " row " + std::to_string(k)) +
                            " must lie in [0, 1) (got " + FormatDouble(u.data()[2 * k + c]) + ")");
  py::array_t<T> wi = NewRows<T>(n, 3, single);
  py::array_t<T> pdf = single ? py::array_t<T>(std::vector<py::ssize_t>{}) : py::array_t<T>(n);
  py::array_t<bool> valid = single ? py::array_t<bool>(std::vector<py::ssize_t>{}) : py::array_t<bool>(n);
  T* w = wi.mutable_data();
  T* pd = pdf.mutable_data();
  bool* v = valid.mutable_data();
  {
    py::gil_scoped_release release;
    for (std::size_t k = 0; k < n; ++k) {
      const T* a = wo.data() + k * wo.stride;
      const double* uu = u.data() + k * u.stride;
      const BsdfSample<T> s = b.Sample(p, Vec3<T>(a[0], a[1], a[2]), uu[0], uu[1]);
      for (int c = 0; c < 3; ++c) w[3 * k + c] = s.wi[c];
      pd[k] = s.valid ? s.pdf : T(0);
      v[k] = s.valid;
    }
  }
  return py::make_tuple(wi, pdf, valid);
}

template <typename T>
py::array_t<T> PdfT(const Bxdf<T>& b, const T* p, const py::handle& wo_obj, const py::handle& wi_obj) {
  const Rows<T> wo = AsRows<T>(wo_obj, "wo", 3, true);
  const Rows<T> wi = AsRows<T>(wi_obj, "wi", 3, true);
  const std::size_t n = BroadcastRows("wo", wo.n, wo.single, "wi", wi.n, wi.single);
  const bool single = wo.single && wi.single;
  py::array_t<T> out = single ? py::array_t<T>(std::vector<py::ssize_t>{}) : py::array_t<T>(n);
  T* o = out.mutable_data();
  {
    py::gil_scoped_release release;
    for (std::size_t k = 0; k < n; ++k) {
      const T* a = wo.data() + k * wo.stride;
      const T* c = wi.data() + k * wi.stride;
      o[k] = b.Pdf(p, Vec3<T>(a[0], a[1], a[2]), Vec3<T>(c[0], c[1], c[2]));
    }
  }
  return out;
}

// Either precision: float32 when every direction argument is float32.
bool Single(const py::handle& a, const py::handle& b) { return IsFloat32(a) && IsFloat32(b); }

py::array_t<double> Albedo(const PyModel& m, const py::handle& wo_obj, double tolerance, int threads) {
  if (!(tolerance >= 1e-12 && tolerance <= 1e-2))
    throw ArgumentError("tolerance must lie in [1e-12, 1e-2] (got " + FormatDouble(tolerance) + ")");
  const Rows<double> wo = AsRows<double>(wo_obj, "wo", 3, true);
  py::array_t<double> out = NewRows<double>(wo.n, 3, wo.single);
  double* o = out.mutable_data();
  validate::AlbedoQuadratureOptions q;
  q.abs_tolerance = tolerance;
  RunReleased(threads, [&](const CancelToken& token) {
    const CancellableBxdf b(*m.bxdf, token);
    const validate::LobeShape shape = validate::EstimateLobeShape(b, m.params.data());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, wo.n), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t k = r.begin(); k < r.end(); ++k) {
        const double* w = wo.data() + 3 * k;
        validate::AlbedoValue a;
        if (w[2] > 0)
          a = validate::DirectionalAlbedo(b, m.params.data(), Eigen::Vector3d(w[0], w[1], w[2]),
                                          validate::Method::kAdaptive, q.Integrate(shape));
        for (int c = 0; c < 3; ++c) o[3 * k + c] = a.value[c];
      }
    });
  });
  return out;
}

py::dict ParamsDict(const ModelInfo& info, const std::vector<double>& packed) {
  py::dict d;
  std::size_t k = 0;
  for (const ParamInfo& p : info.params) {
    if (p.colour) {
      d[py::str(p.name)] = py::make_tuple(packed[k], packed[k + 1], packed[k + 2]);
      k += 3;
    } else {
      d[py::str(p.name)] = packed[k++];
    }
  }
  return d;
}

}  // namespace

void BindModels(py::module_& m) {
  m.def(
      "models",
      [] {
        py::list out;
        for (const ModelInfo& i : RegisteredModelInfos()) out.append(ToPython(cli::ModelInfoJson(i)));
        return out;
      },
      R"doc(The registered models with their parameter tables.

Returns
-------
list of dict
    One entry per model, as ``brdfkit models --json``: name, summary,
    params (name, lower, upper, default, colour, meaning, scale),
    reciprocal, energy_conserving, settings.
)doc");

  py::class_<PyModel>(m, "Model", R"doc(A BRDF model (one lobe or a sum of lobes) with its parameter values.

Parameters
----------
spec : str
    Model name or sum of lobes: ``"ggx"``, ``"lambert+ggx"``,
    ``"merl:FILE.binary"`` (see :func:`models`).
params : dict or str, optional
    Parameter values; unnamed parameters keep their defaults. A dict maps
    names to numbers, colour parameters to a number or ``(r, g, b)``; a
    string is the command line's ``"name=value,name=r:g:b"``. Lobes of a
    sum are prefixed: ``{"lambert.albedo": 0.5, "ggx.alpha": 0.2}``.
    Settings such as ``path`` go here too.

Raises
------
ValueError
    Unknown model or parameter, value outside its range, bad file.

Notes
-----
Directions are unit vectors in the local frame (z the normal); ``wi``
points towards the light, ``wo`` towards the detector. Values are f_r in
1/sr per RGB channel, without the cosine. A Model is immutable and may be
shared between threads.
)doc")
      .def(py::init(&MakeModel), py::arg("spec"), py::arg("params") = py::none())
      .def_property_readonly("spec", [](const PyModel& p) { return p.model.Spec(); }, "The model specification.")
      .def_property_readonly("params", [](const PyModel& p) { return ParamsDict(p.model.Info(), p.params); },
                             "Parameter values by name (colour parameters as (r, g, b)).")
      .def_property_readonly(
          "packed",
          [](const PyModel& p) { return py::array_t<double>(p.params.size(), p.params.data()); },
          "Parameter values in packed order (colour parameters as three slots).")
      .def_property_readonly("packed_names", [](const PyModel& p) {
            std::vector<std::string> names;
            static const char* kChannel[3] = {"r", "g", "b"};
            for (const ParamInfo& q : p.model.Info().params)
              for (int c = 0; c < (q.colour ? 3 : 1); ++c) names.push_back(q.colour ? q.name + "." + kChannel[c] : q.name);
            return names;
          }, "Names of the packed slots.")
      .def_property_readonly("info", [](const PyModel& p) { return ToPython(cli::ModelInfoJson(p.model.Info())); },
                             "Parameter table of the model, as in models().")
      .def("__repr__", [](const PyModel& p) {
        return "brdfkit.Model('" + p.model.Spec() + "', '" + FormatParams(p.model.Info(), p.params) + "')";
      })
      .def(
          "eval",
          [](const PyModel& p, const py::object& wi, const py::object& wo) -> py::object {
            if (Single(wi, wo)) return EvalT<float>(*p.bxdf_f, p.params_f.data(), wi, wo);
            return EvalT<double>(*p.bxdf, p.params.data(), wi, wo);
          },
          py::arg("wi"), py::arg("wo"),
          R"doc(f_r(wi, wo) in 1/sr per RGB channel (no cosine factor).

Parameters
----------
wi : array_like, shape (N, 3) or (3,)
    Unit directions towards the light.
wo : array_like, shape (N, 3) or (3,)
    Unit directions towards the detector. One direction (shape (3,))
    is used for every row of the other argument.

Returns
-------
numpy.ndarray, shape (N, 3) or (3,)
    float32 when both inputs are float32 (the model runs in single
    precision), float64 otherwise.

Raises
------
ValueError
    Wrong shape, different row counts, non-finite or non-unit rows.
TypeError
    Non-numeric arrays.
)doc")
      .def(
          "sample",
          [](const PyModel& p, const py::object& wo, const py::object& u) -> py::tuple {
            if (IsFloat32(wo)) return SampleT<float>(*p.bxdf_f, p.params_f.data(), wo, u);
            return SampleT<double>(*p.bxdf, p.params.data(), wo, u);
          },
          py::arg("wo"), py::arg("u"),
          R"doc(Importance-samples wi given wo.

Parameters
----------
wo : array_like, shape (N, 3) or (3,)
    Unit directions towards the detector.
u : array_like, shape (N, 2) or (2,)
    Uniform random numbers in [0, 1).

Returns
-------
wi : numpy.ndarray, shape (N, 3)
    Sampled directions towards the light.
pdf : numpy.ndarray, shape (N,)
    Their density with respect to solid angle (0 where not valid).
valid : numpy.ndarray of bool, shape (N,)
    False where the sample fell below the horizon (it carries no weight).
)doc")
      .def(
          "pdf",
          [](const PyModel& p, const py::object& wo, const py::object& wi) -> py::object {
            if (Single(wo, wi)) return PdfT<float>(*p.bxdf_f, p.params_f.data(), wo, wi);
            return PdfT<double>(*p.bxdf, p.params.data(), wo, wi);
          },
          py::arg("wo"), py::arg("wi"),
          R"doc(Density of :meth:`sample` (solid angle) of wi given wo.

Parameters
----------
wo, wi : array_like, shape (N, 3) or (3,)
    Unit directions; one direction broadcasts.

Returns
-------
numpy.ndarray, shape (N,)
)doc")
      .def("albedo", &Albedo, py::arg("wo"), py::arg("tolerance") = 1e-6, py::arg("threads") = 0,
           R"doc(Directional albedo E(wo) = int f_r(wi, wo) cos(theta_i) dwi per channel.

By the adaptive half-vector cubature of the albedo tables.

Parameters
----------
wo : array_like, shape (N, 3) or (3,)
    Unit directions; E = 0 at or below the horizon.
tolerance : float
    Absolute error target per channel (default 1e-6).
threads : int
    Threads (0: every core). Interruptible with Ctrl-C.

Returns
-------
numpy.ndarray, shape (N, 3) or (3,)
)doc");
}

}  // namespace brdfkit::python
