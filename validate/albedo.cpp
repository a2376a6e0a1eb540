#include "validate/albedo.h"

#include <tbb/parallel_for.h>

#include <atomic>

#include <ImfAttribute.h>
#include <ImfChannelList.h>
#include <ImfFloatVectorAttribute.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfMultiPartOutputFile.h>
#include <ImfOutputPart.h>
#include <ImfPartType.h>
#include <ImfStdIO.h>
#include <ImfStringAttribute.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <limits>
#include <memory>
#include <sstream>

#include "brdf/atomic_file.h"
#include "brdf/params.h"
#include "brdf/quadrature.h"

namespace brdfkit::validate {

Eigen::Array3d AdaptiveGaussKronrod(const std::function<Eigen::Array3d(double)>& f, double a, double b,
                                    std::vector<double> breakpoints, double abs_tolerance, int max_subdivisions,
                                    double* error, std::int64_t* evals, const std::function<bool()>& stop) {
  std::int64_t n = 0;
  const auto g = [&](double x) {
    ++n;
    return QuadValue{f(x), Eigen::Array3d::Zero()};
  };
  const QuadValue r = AdaptiveKronrod(g, a, b, std::move(breakpoints), abs_tolerance, 0.0, max_subdivisions,
                                      [&] { return stop && stop(); });
  if (error) *error = r.error.maxCoeff();
  if (evals) *evals += n;
  return r.value;
}

namespace {
// Below 1e-15 the direction wo itself (sin_o = 1 exactly) carries no more information.
double GrazingMu(const LobeShape& shape) { return std::max(1e-15, std::min(kGrazingMu, 1e-9 * shape.width)); }
}  // namespace

AlbedoValue AlbedoAtMu(const Bxdf<double>& bxdf, const double* p, double mu, const LobeShape& shape,
                       const AlbedoQuadratureOptions& o) {
  mu = std::max(mu, GrazingMu(shape));
  mu = std::min(mu, 1.0);
  const Eigen::Vector3d wo(std::sqrt(std::max(0.0, (1 - mu) * (1 + mu))), 0, mu);
  // The power scattered from light arriving along wo: over the sphere for a
  // transmitting model, over the other argument for a non-reciprocal one.
  const bool transmits = bxdf.Kind() & LobeKind::kTransmission;
  if (transmits || !bxdf.Info().reciprocal) {
    IntegrateOptions io = o.Integrate(shape);
    // The total adds two estimates: each part gets half the tolerance.
    if (transmits && o.part == AlbedoQuadratureOptions::Part::kTotal) io.abs_tolerance /= 2;
    using Part = AlbedoQuadratureOptions::Part;
    const ScatteredParts parts = o.part == Part::kReflected     ? ScatteredParts::kReflected
                                 : o.part == Part::kTransmitted ? ScatteredParts::kTransmitted
                                                                : ScatteredParts::kBoth;
    const ScatteredEstimate e = ScatteredPower(bxdf, p, wo, io, parts);
    switch (o.part) {
      case AlbedoQuadratureOptions::Part::kReflected: return e.reflected;
      case AlbedoQuadratureOptions::Part::kTransmitted: return e.transmitted;
      case AlbedoQuadratureOptions::Part::kTotal: break;
    }
    return e.Total();
  }
  return DirectionalAlbedo(bxdf, p, wo, Method::kAdaptive, o.Integrate(shape));
}

namespace {
// Tolerance for E at mu inside E_avg: c tol max(1, (m0 / mu)^b) with
// int_0^1 2 mu tol_E dmu = c tol (1 + m0^2 b / (2 - b)) = tol / 2 for
// m0 = 0.3, b = 1.9, c = 0.5 / 2.71: grazing nodes, where the horizon cuts
// the lobe and E is costly, carry little weight and get a loose target.
double NodeTolerance(double tol, double mu) {
  constexpr double kM0 = 0.3, kB = 1.9, kC = 0.5 / (1 + kM0 * kM0 * kB / (2 - kB));
  return std::min(1e-3, kC * tol * (mu < kM0 ? std::pow(kM0 / mu, kB) : 1.0));
}

// mu = cos(theta) of the critical angle for light arriving from outside a
// transmitting model whose inside is the less dense side (relative index
// n_out / n_in = k > 1: sin(theta_c) = 1 / k); 0 when there is none.
double CriticalMu(const Bxdf<double>& bxdf, const double* p) {
  if (!(bxdf.Kind() & LobeKind::kTransmission)) return 0;
  const double k = bxdf.RelativeIndex(p, Eigen::Vector3d::UnitZ(), -Eigen::Vector3d::UnitZ());
  return k > 1 ? std::sqrt(1 - 1 / (k * k)) : 0.0;
}
}  // namespace

AlbedoValue AverageAlbedo(const Bxdf<double>& bxdf, const double* p, const LobeShape& shape,
                          const AlbedoQuadratureOptions& o) {
  AlbedoValue out;
  AlbedoQuadratureOptions io = o;
  io.max_evals = std::min<std::int64_t>(o.max_evals, 200000);
  // In s = ln(mu) the integrand 2 mu^2 E(e^s) is smooth at grazing: the
  // mu ln(mu) terms of E there and the dip of width ~w at mu ~ w both become
  // features of unit scale. Below mu_min = 1e-4 w, E is at its grazing limit
  // and int_0^mu_min 2 mu E dmu = mu_min^2 E(mu_min). Towards normal
  // incidence E has terms in (1 - mu)^(3/2) ~ theta^3 (rough glass), an end
  // point singularity in s; the rule runs in v = sqrt(-s) (v ~ theta / sqrt(2)
  // there), where they are smooth: int_s0^0 h(s) ds = int_0^v0 h(-v^2) 2 v dv.
  const double mu_min = std::max(1e-4 * std::min(shape.width, 1.0), 1e-12);
  // E at mu is needed to NodeTolerance(tol, mu): its error enters with
  // weight 2 mu dmu, so the sum is at most tol / 2; worst = max of
  // error / tol_E over the nodes scales that bound (a node may miss or beat
  // its target).
  double worst = 0;
  const auto g = [&](double v) -> Eigen::Array3d {
    const double mu = std::exp(-v * v);
    AlbedoQuadratureOptions is = io;
    is.abs_tolerance = NodeTolerance(o.abs_tolerance, mu);
    const AlbedoValue e = AlbedoAtMu(bxdf, p, mu, shape, is);
    out.evals += e.evals;
    worst = std::max(worst, e.error.maxCoeff() / is.abs_tolerance);
    return 2 * mu * mu * e.value * (2 * v);
  };
  // The estimate below is at least 0.5 tol worst, and worst only grows:
  // past the accepted error no refinement of the outer rule can bring it back.
  const auto give_up = [&] { return 0.5 * o.abs_tolerance * worst > o.accepted_error; };
  const auto v_of = [](double s) { return std::sqrt(-s); };
  const double v0 = v_of(std::log(mu_min)), sw = std::log(std::min(shape.width, 1.0));
  // Panels: below, across and above the lobe-width dip.
  std::vector<double> breaks;
  for (double b : {sw - 2, sw + 2})
    if (b < 0) breaks.push_back(v_of(b));
  double err = 0;
  std::int64_t n = 0;
  const double mu_c = CriticalMu(bxdf, p);
  if (mu_c > mu_min && mu_c < 1) {
    // Light from the denser side: E falls (reflected) or rises (transmitted)
    // across the critical angle theta_c over an angle ~w, a transition the
    // adaptive rule resolves with fewer nodes in u, v = v_c + c sinh(u):
    // uniform in v over the transition, geometric away from it. c is w in
    // v, dv / dtheta = tan(theta) / (2 v) (1 / sqrt(2) as theta -> 0).
    const double v_c = v_of(std::log(mu_c)), tan_c = std::sqrt((1 - mu_c) * (1 + mu_c)) / mu_c;
    const double c = std::min(shape.width, 1.0) * tan_c / (2 * v_c);
    const auto u_of = [&](double v) { return std::asinh((v - v_c) / c); };
    const auto gu = [&](double u) -> Eigen::Array3d { return g(v_c + c * std::sinh(u)) * (c * std::cosh(u)); };
    std::vector<double> u_breaks{0.0};
    for (double b : breaks) u_breaks.push_back(u_of(b));
    out.value = AdaptiveGaussKronrod(gu, u_of(0.0), u_of(v0), u_breaks, 0.5 * o.abs_tolerance, o.max_subdivisions,
                                     &err, &n, give_up);
  } else {
    out.value = AdaptiveGaussKronrod(g, 0.0, v0, breaks, 0.5 * o.abs_tolerance, o.max_subdivisions, &err, &n, give_up);
  }
  AlbedoQuadratureOptions mo = io;
  mo.abs_tolerance = NodeTolerance(o.abs_tolerance, mu_min);
  const AlbedoValue e_min = AlbedoAtMu(bxdf, p, mu_min, shape, mo);
  out.value += mu_min * mu_min * e_min.value;
  out.evals += e_min.evals;
  out.error = Eigen::Array3d::Constant(err + 0.5 * o.abs_tolerance * worst +
                                       mu_min * mu_min * e_min.error.maxCoeff());
  return out;
}

// --- tables ----------------------------------------------------------------

std::size_t AxisParameter(const ModelInfo& info, const std::string& axis_name) {
  const std::string target = axis_name == "roughness" ? "alpha" : axis_name;
  for (std::size_t i = 0; i < info.params.size(); ++i)
    if (info.params[i].name == target) return i;
  std::string known;
  for (const auto& p : info.params) known += (known.empty() ? "" : ", ") + p.name;
  if (axis_name == "roughness")
    throw ModelError("axis 'roughness' sets alpha = roughness^2, and model '" + info.name +
                     "' has no parameter alpha (parameters: " + (known.empty() ? "none" : known) + ")");
  throw ModelError("axis '" + axis_name + "' is not a parameter of model '" + info.name + "' (parameters: " +
                   (known.empty() ? "none" : known) + ")");
}

std::vector<std::string> PartNames() { return {"total", "reflected", "transmitted"}; }

AlbedoQuadratureOptions::Part ParsePart(const std::string& text) {
  using Part = AlbedoQuadratureOptions::Part;
  const std::vector<std::string> names = PartNames();
  for (std::size_t k = 0; k < names.size(); ++k)
    if (text == names[k]) return static_cast<Part>(k);
  throw ModelError("part '" + text + "': expected total (E_R + E_T), reflected (E_R) or transmitted (E_T)");
}

std::vector<AxisSpec> ParseAxes(const std::string& text) {
  std::vector<AxisSpec> out;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    std::vector<std::string> parts;
    std::stringstream is(item);
    std::string part;
    while (std::getline(is, part, ':')) parts.push_back(part);
    if (parts.size() != 2 && parts.size() != 4)
      throw ModelError("axis '" + item + "': expected name:count or name:count:lower:upper");
    AxisSpec a;
    a.name = parts[0];
    double count;
    if (a.name.empty()) throw ModelError("axis '" + item + "': empty name");
    if (!ParseDouble(parts[1], count) || count != std::floor(count) || count < 1 || count > 4096)
      throw ModelError("axis '" + item + "': count '" + parts[1] + "' is not an integer in [1, 4096]");
    a.count = static_cast<int>(count);
    if (parts.size() == 4) {
      if (!ParseDouble(parts[2], a.lower) || !ParseDouble(parts[3], a.upper) || !std::isfinite(a.lower) ||
          !std::isfinite(a.upper))
        throw ModelError("axis '" + item + "': range '" + parts[2] + ":" + parts[3] + "' is not two numbers");
      if (a.lower > a.upper) throw ModelError("axis '" + item + "': lower bound above upper bound");
    }
    out.push_back(a);
  }
  if (out.empty()) throw ModelError("no axes given (expected e.g. mu:32,alpha:32)");
  return out;
}

namespace {

// Nodes of `count` points on [lo, hi] in coordinate c = sqrt(x) or x.
void MakeNodes(Axis& axis, int count, double lo, double hi, NodeRule rule) {
  const auto to_c = [&](double x) { return axis.sqrt_spacing ? std::sqrt(x) : x; };
  const auto from_c = [&](double c) { return axis.sqrt_spacing ? c * c : c; };
  const double c0 = to_c(lo), c1 = to_c(hi);
  axis.nodes.clear();
  axis.weights.clear();
  if (count == 1 || lo == hi) {
    // A single node sits at the middle of the range (a point range: there).
    axis.nodes = {lo == hi ? lo : from_c(0.5 * (c0 + c1))};
    if (rule == NodeRule::kGauss) axis.weights = {hi - lo};
    return;
  }
  if (rule == NodeRule::kUniform) {
    for (int i = 0; i < count; ++i) {
      const double c = c0 + (c1 - c0) * i / (count - 1);
      axis.nodes.push_back(i == 0 ? lo : i == count - 1 ? hi : from_c(c));
    }
    return;
  }
  const GaussLegendre gl(count);
  for (int i = 0; i < count; ++i) {
    const double c = c0 + (c1 - c0) * gl.node01(i);
    axis.nodes.push_back(from_c(c));
    // Weight for int dx: dx = (dx/dc) dc, dx/dc = 2c under sqrt spacing.
    axis.weights.push_back((c1 - c0) * gl.weight01(i) * (axis.sqrt_spacing ? 2 * c : 1.0));
  }
}

void SetParam(const ModelInfo& info, const Axis& axis, double value, std::vector<double>& packed) {
  // Roughness 0 (renderers' first node) is the smoothest alpha the model takes.
  if (axis.squared) value = std::max(value * value, info.params[axis.param_index].lower);
  const std::size_t off = info.Offset(axis.param_index);
  const int n = info.params[axis.param_index].colour ? 3 : 1;
  for (int c = 0; c < n; ++c) packed[off + c] = value;
}

}  // namespace

AlbedoTable BuildAlbedoTable(const Model& model, const std::vector<double>& base_params,
                             const AlbedoTableRequest& req) {
  return BuildAlbedoTable(*model.Make<double>(), model.Spec(), base_params, req);
}

AlbedoTable BuildAlbedoTable(const Bxdf<double>& model, const std::string& spec,
                             const std::vector<double>& base_params, const AlbedoTableRequest& req) {
  const auto t_start = std::chrono::steady_clock::now();
  const ModelInfo& info = model.Info();
  ValidateParams(info, base_params);
  if (req.axes.empty() || req.axes.size() > 3 || req.axes[0].name != "mu")
    throw ModelError("axes: expected mu:N followed by up to two model parameters (e.g. mu:32,alpha:32)");
  if (req.channel < 0 || req.channel > 2) throw ModelError("channel must be 0, 1 or 2");
  if (req.axes.size() == 1 && (req.slice_begin != 0 || req.slice_end != static_cast<std::size_t>(-1)))
    throw ModelError("slice: a slice is taken along the first parameter axis, and the axes name none (mu only)");
  AlbedoTable t;
  t.model = spec;
  t.base_params = base_params;
  t.mu.name = "mu";
  {
    const AxisSpec& a = req.axes[0];
    double lo = 0, hi = 1;
    if (a.lower != 0 || a.upper != 0) {
      lo = a.lower;
      hi = a.upper;
    }
    if (lo < 0 || hi > 1) throw ModelError("axis mu: range must lie in [0, 1]");
    MakeNodes(t.mu, a.count, lo, hi, req.rule);
  }
  for (std::size_t k = 1; k < req.axes.size(); ++k) {
    const AxisSpec& a = req.axes[k];
    Axis axis;
    axis.name = a.name;
    const std::size_t index = AxisParameter(info, a.name);
    for (const Axis& prev : t.params)
      if (prev.param_index == index)
        throw ModelError("axis '" + a.name + "' sets " + info.params[index].name + ", which another axis sets");
    const ParamInfo& pi = info.params[index];
    axis.param_index = index;
    axis.squared = a.name == "roughness";
    axis.sqrt_spacing = !axis.squared && pi.scale == ParamInfo::Scale::kLog;
    // A roughness axis runs over sqrt of alpha's range, and may start at 0.
    const double lower = axis.squared ? 0.0 : pi.lower;
    double lo = axis.squared ? std::sqrt(pi.lower) : pi.lower, hi = axis.squared ? std::sqrt(pi.upper) : pi.upper;
    if (a.lower != 0 || a.upper != 0) {
      lo = a.lower;
      hi = a.upper;
    }
    if (lo < lower || (axis.squared ? hi * hi : hi) > pi.upper)
      throw ModelError("axis '" + a.name + "': range [" + FormatDouble(lo) + ", " + FormatDouble(hi) +
                       "] is outside the " + (axis.squared ? "roughness" : "parameter's") + " range [" +
                       FormatDouble(lower) + ", " + FormatDouble(axis.squared ? std::sqrt(pi.upper) : pi.upper) +
                       "]");
    MakeNodes(axis, a.count, lo, hi, req.rule);
    if (k == 1 && (req.slice_begin != 0 || req.slice_end != static_cast<std::size_t>(-1))) {
      const std::size_t n = axis.nodes.size(), end = std::min(req.slice_end, n);
      if (req.slice_begin >= end || (req.slice_end != static_cast<std::size_t>(-1) && req.slice_end > n))
        throw ModelError("slice " + std::to_string(req.slice_begin) + ":" + std::to_string(req.slice_end) +
                         " of axis '" + a.name + "': expected BEGIN < END <= " + std::to_string(n) +
                         " (the axis has " + std::to_string(n) + " nodes)");
      axis.nodes = std::vector<double>(axis.nodes.begin() + req.slice_begin, axis.nodes.begin() + end);
      if (!axis.weights.empty())
        axis.weights = std::vector<double>(axis.weights.begin() + req.slice_begin, axis.weights.begin() + end);
    }
    if (a.name == "f0") t.f0_axis = static_cast<int>(t.params.size());
    t.params.push_back(std::move(axis));
  }

  // The parameters held fixed (those of the axes vary over the table).
  {
    std::stringstream all(FormatParams(info, base_params));
    std::string item;
    while (std::getline(all, item, ',')) {
      const std::string name = item.substr(0, item.find('='));
      const bool on_axis = std::any_of(t.params.begin(), t.params.end(),
                                       [&](const Axis& a) { return info.params[a.param_index].name == name; });
      if (!on_axis) t.params_text += (t.params_text.empty() ? "" : ",") + item;
    }
  }
  if (model.Kind() & LobeKind::kTransmission) {
    using Part = AlbedoQuadratureOptions::Part;
    const Part part = req.quadrature.part;
    t.part = part == Part::kReflected ? "E_R" : part == Part::kTransmitted ? "E_T" : "E_R+E_T";
  }

  const std::size_t n_mu = t.n_mu(), n1 = t.n1(), n2 = t.n2();
  const std::size_t n_points = n1 * n2;
  t.E.assign(n_mu * n_points, 0.0);
  t.E_error.assign(t.E.size(), 0.0);
  t.E_avg.assign(n_points, 0.0);
  t.E_avg_error.assign(n_points, 0.0);
  const Bxdf<double>* const bxdf = &model;
  const int ch = req.channel;

  // Parameter vectors and lobe shapes per point.
  std::vector<std::vector<double>> point_params(n_points, base_params);
  for (std::size_t i1 = 0; i1 < n1; ++i1)
    for (std::size_t i2 = 0; i2 < n2; ++i2) {
      auto& pp = point_params[i1 * n2 + i2];
      if (!t.params.empty()) SetParam(info, t.params[0], t.params[0].nodes[i1], pp);
      if (t.params.size() > 1) SetParam(info, t.params[1], t.params[1].nodes[i2], pp);
    }
  // F = 1 points for the Fresnel compensation terms (f0 axis set to 1).
  std::size_t n_other = 1;
  std::vector<std::vector<double>> f1_params;
  if (t.f0_axis >= 0) {
    const int other = t.params.size() > 1 ? 1 - t.f0_axis : -1;
    n_other = other >= 0 ? t.params[other].nodes.size() : 1;
    f1_params.assign(n_other, base_params);
    for (std::size_t j = 0; j < n_other; ++j) {
      SetParam(info, t.params[t.f0_axis], 1.0, f1_params[j]);
      if (other >= 0) SetParam(info, t.params[other], t.params[other].nodes[j], f1_params[j]);
    }
    t.E1.assign(n_mu * n_other, 0.0);
    t.E1_error.assign(t.E1.size(), 0.0);
    t.E1_avg.assign(n_other, 0.0);
    t.E1_avg_error.assign(n_other, 0.0);
  }
  std::vector<LobeShape> shapes(n_points), f1_shapes(f1_params.size());
  for (std::size_t i = 0; i < n_points; ++i) shapes[i] = EstimateLobeShape(*bxdf, point_params[i].data());
  for (std::size_t i = 0; i < f1_params.size(); ++i) f1_shapes[i] = EstimateLobeShape(*bxdf, f1_params[i].data());

  // Tasks: averages first (each costs dozens of cells), then the cells.
  std::vector<double> limit_err(n_points + f1_params.size(), 0.0);
  const std::size_t n_tasks = n_points + f1_params.size() + t.E.size() + t.E1.size();
  std::atomic<std::size_t> tasks_done{0};
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n_tasks, 1), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t task = r.begin(); task != r.end(); ++task) {
      if (req.progress) req.progress(tasks_done.fetch_add(1), n_tasks);
      std::size_t k = task;
      if (k < n_points) {
        const AlbedoValue a = AverageAlbedo(*bxdf, point_params[k].data(), shapes[k], req.quadrature);
        t.E_avg[k] = a.value[ch];
        t.E_avg_error[k] = a.error[ch];
        continue;
      }
      k -= n_points;
      if (k < f1_params.size()) {
        const AlbedoValue a = AverageAlbedo(*bxdf, f1_params[k].data(), f1_shapes[k], req.quadrature);
        t.E1_avg[k] = a.value[ch];
        t.E1_avg_error[k] = a.error[ch];
        continue;
      }
      k -= f1_params.size();
      const bool f1 = k >= t.E.size();
      if (f1) k -= t.E.size();
      const std::size_t i_mu = k % n_mu, point = k / n_mu;
      const double* pp = f1 ? f1_params[point].data() : point_params[point].data();
      const LobeShape& shape = f1 ? f1_shapes[point] : shapes[point];
      const AlbedoValue a = AlbedoAtMu(*bxdf, pp, t.mu.nodes[i_mu], shape, req.quadrature);
      if (f1) {
        t.E1[k] = a.value[ch];
        t.E1_error[k] = a.error[ch];
      } else {
        t.E[k] = a.value[ch];
        t.E_error[k] = a.error[ch];
      }
      if (t.mu.nodes[i_mu] == 0) {
        // Distance from the limit: E at ten times the grazing cosine.
        const double mu10 = 10 * GrazingMu(shape);
        const AlbedoValue b = AlbedoAtMu(*bxdf, pp, mu10, shape, req.quadrature);
        limit_err[(f1 ? n_points : 0) + point] = std::abs(b.value[ch] - a.value[ch]);
      }
    }
  });

  t.ms_norm.resize(n_points);
  for (std::size_t i = 0; i < n_points; ++i) {
    // E_avg >= 1: nothing is lost and the compensation lobe is zero (its
    // normalisation has no finite value there).
    t.ms_norm[i] = t.E_avg[i] < 1 ? 1.0 / (kPi * (1.0 - t.E_avg[i])) : 0.0;
  }
  if (t.f0_axis >= 0) {
    const Axis& fa = t.params[t.f0_axis];
    // Schlick: 2 int_0^1 (f0 + (1 - f0)(1 - mu)^5) mu dmu = f0 + (1 - f0) / 21.
    for (double f0 : fa.nodes) t.F_avg.push_back(f0 + (1 - f0) / 21.0);
    t.F_ms.resize(n_points);
    for (std::size_t i1 = 0; i1 < n1; ++i1)
      for (std::size_t i2 = 0; i2 < n2; ++i2) {
        const std::size_t i_f0 = t.f0_axis == 0 ? i1 : i2, i_other = t.f0_axis == 0 ? i2 : i1;
        const double fav = t.F_avg[i_f0], e1 = t.E1_avg[t.params.size() > 1 ? i_other : 0];
        t.F_ms[i1 * n2 + i2] = fav * fav * e1 / (1 - fav * (1 - e1));
      }
  }
  for (double e : t.E_error) t.max_error = std::max(t.max_error, e);
  for (double e : t.E_avg_error) t.max_error = std::max(t.max_error, e);
  for (double e : t.E1_error) t.max_error = std::max(t.max_error, e);
  for (double e : t.E1_avg_error) t.max_error = std::max(t.max_error, e);
  for (double e : limit_err) t.limit_error = std::max(t.limit_error, e);
  t.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return t;
}

std::vector<AlbedoMiss> EntriesAboveTolerance(const AlbedoTable& t, double tolerance) {
  std::vector<AlbedoMiss> out;
  const std::size_t n2 = t.n2();
  // Axis values of parameter point i1 * n2 + i2.
  const auto point = [&](std::size_t k) {
    std::vector<std::pair<std::string, double>> v;
    if (!t.params.empty()) v.emplace_back(t.params[0].name, t.params[0].nodes[k / n2]);
    if (t.params.size() > 1) v.emplace_back(t.params[1].name, t.params[1].nodes[k % n2]);
    return v;
  };
  // The F = 1 tables run over the axis other than f0 (one entry without one).
  const auto other_point = [&](std::size_t j) {
    std::vector<std::pair<std::string, double>> v{{"f0", 1.0}};
    if (t.params.size() > 1) {
      const Axis& other = t.params[1 - t.f0_axis];
      v.emplace_back(other.name, other.nodes[j]);
    }
    return v;
  };
  const auto add = [&](const char* table, double error, double mu, std::vector<std::pair<std::string, double>> at) {
    // A NaN estimate is a miss too.
    if (!(error <= tolerance)) out.push_back({table, mu, std::move(at), error});
  };
  for (std::size_t k = 0; k < t.E_error.size(); ++k)
    add("E", t.E_error[k], t.mu.nodes[k % t.n_mu()], point(k / t.n_mu()));
  for (std::size_t k = 0; k < t.E_avg_error.size(); ++k) add("E_avg", t.E_avg_error[k], -1, point(k));
  for (std::size_t k = 0; k < t.E1_error.size(); ++k)
    add("E1", t.E1_error[k], t.mu.nodes[k % t.n_mu()], other_point(k / t.n_mu()));
  for (std::size_t k = 0; k < t.E1_avg_error.size(); ++k) add("E1_avg", t.E1_avg_error[k], -1, other_point(k));
  return out;
}

std::string DescribeMisses(const std::vector<AlbedoMiss>& misses, double tolerance, std::size_t shown) {
  std::ostringstream s;
  s << misses.size() << " table entr" << (misses.size() == 1 ? "y misses" : "ies miss")
    << " the error tolerance " << FormatDouble(tolerance) << ":";
  std::vector<const AlbedoMiss*> worst;
  for (const AlbedoMiss& m : misses) worst.push_back(&m);
  std::sort(worst.begin(), worst.end(), [](const AlbedoMiss* a, const AlbedoMiss* b) { return a->error > b->error; });
  for (std::size_t i = 0; i < std::min(shown, worst.size()); ++i) {
    const AlbedoMiss& m = *worst[i];
    char err[32];
    std::snprintf(err, sizeof err, "%.3g", m.error);
    std::vector<std::string> where;
    if (m.mu >= 0) where.push_back("mu = " + FormatDouble(m.mu));
    for (const auto& [name, value] : m.at) where.push_back(name + " = " + FormatDouble(value));
    s << "\n  " << m.table;
    for (std::size_t k = 0; k < where.size(); ++k) s << (k ? ", " : " at ") << where[k];
    s << ": error estimate " << err;
  }
  if (worst.size() > shown) s << "\n  ... and " << worst.size() - shown << " more";
  return s.str();
}

std::string MissAdvice(const AlbedoTable& table, const std::string& looser_tolerance) {
  return table.params.empty()
             ? "Ask for a looser tolerance (a measured table's interpolation keeps its integrals from converging "
               "much below 1e-4: " + looser_tolerance + ")"
             : "Narrow the parameter range (an alpha axis such as alpha:32:0.001:1)";
}

// --- writers ---------------------------------------------------------------

namespace {

std::string SiblingPath(const std::string& path, const std::string& suffix) {
  const std::filesystem::path p(path);
  std::filesystem::path out = p.parent_path() / (p.stem().string() + suffix + p.extension().string());
  return out.string();
}

std::string Fmt(double v) { return FormatDouble(v); }

std::string AxesText(const AlbedoTable& t) {
  std::string s = "mu:" + std::to_string(t.n_mu());
  for (const Axis& a : t.params) s += "," + a.name + ":" + std::to_string(a.nodes.size());
  return s;
}

}  // namespace

std::string AverageCsvPath(const std::string& path) { return SiblingPath(path, "_avg"); }

void WriteAlbedoCsv(const AlbedoTable& t, const std::string& path) {
  const std::size_t n1 = t.n1(), n2 = t.n2();
  const bool two = t.params.size() > 1;
  // The parameter columns, each followed by its comma (none without parameter axes).
  std::string pnames;
  for (const Axis& a : t.params) pnames.append(a.name).append(",");
  std::ostringstream e, avg, ms;
  e << "mu," << pnames << "E\n";
  avg << pnames << "E_avg\n";
  ms << pnames << "E_avg,ms_norm" << (t.f0_axis >= 0 ? ",F_avg,E1_avg,F_ms" : "") << "\n";
  const std::size_t n_other = t.f0_axis >= 0 ? t.E1_avg.size() : 0;
  for (std::size_t i1 = 0; i1 < n1; ++i1)
    for (std::size_t i2 = 0; i2 < n2; ++i2) {
      std::string pv;
      if (!t.params.empty()) pv.append(Fmt(t.params[0].nodes[i1])).append(",");
      if (two) pv.append(Fmt(t.params[1].nodes[i2])).append(",");
      for (std::size_t m = 0; m < t.n_mu(); ++m) e << Fmt(t.mu.nodes[m]) << "," << pv << Fmt(t.at(m, i1, i2)) << "\n";
      const std::size_t k = i1 * n2 + i2;
      avg << pv << Fmt(t.E_avg[k]) << "\n";
      ms << pv << Fmt(t.E_avg[k]) << "," << Fmt(t.ms_norm[k]);
      if (t.f0_axis >= 0) {
        const std::size_t i_f0 = t.f0_axis == 0 ? i1 : i2, i_other = two ? (t.f0_axis == 0 ? i2 : i1) : 0;
        ms << "," << Fmt(t.F_avg[i_f0]) << "," << Fmt(t.E1_avg[i_other]) << "," << Fmt(t.F_ms[k]);
      }
      ms << "\n";
    }
  std::ostringstream f1;
  if (t.f0_axis >= 0) {
    const Axis* other = two ? &t.params[1 - t.f0_axis] : nullptr;
    f1 << "mu";
    if (other) f1 << "," << other->name;
    f1 << ",E\n";
    for (std::size_t j = 0; j < n_other; ++j)
      for (std::size_t m = 0; m < t.n_mu(); ++m) {
        f1 << Fmt(t.mu.nodes[m]);
        if (other) f1 << "," << Fmt(other->nodes[j]);
        f1 << "," << Fmt(t.E1[j * t.n_mu() + m]) << "\n";
      }
  }
  // All files or none: every temporary is written before any is renamed.
  AtomicFile fe(path), fa(AverageCsvPath(path)), fm(SiblingPath(path, "_ms"));
  std::unique_ptr<AtomicFile> ff;
  if (t.f0_axis >= 0) ff = std::make_unique<AtomicFile>(SiblingPath(path, "_f1"));
  fe.stream() << e.str();
  fa.stream() << avg.str();
  fm.stream() << ms.str();
  if (ff) ff->stream() << f1.str();
  fe.Commit();
  fa.Commit();
  fm.Commit();
  if (ff) ff->Commit();
}

void WriteAlbedoExr(const AlbedoTable& t, const std::string& path) {
  struct Image {
    std::string name;
    int width, height;
    std::vector<float> data;
  };
  std::vector<Image> images;
  const auto to_float = [](const std::vector<double>& v) { return std::vector<float>(v.begin(), v.end()); };
  images.push_back({"E", int(t.n_mu()), int(t.n1() * t.n2()), to_float(t.E)});
  images.push_back({"E_avg", int(t.n2()), int(t.n1()), to_float(t.E_avg)});
  images.push_back({"ms_norm", int(t.n2()), int(t.n1()), to_float(t.ms_norm)});
  if (t.f0_axis >= 0) {
    images.push_back({"E1", int(t.n_mu()), int(t.E1_avg.size()), to_float(t.E1)});
    images.push_back({"E1_avg", 1, int(t.E1_avg.size()), to_float(t.E1_avg)});
    images.push_back({"F_ms", int(t.n2()), int(t.n1()), to_float(t.F_ms)});
  }
  // Parts of one file share the display window; each has its own data window.
  int max_w = 1, max_h = 1;
  for (const Image& im : images) {
    max_w = std::max(max_w, im.width);
    max_h = std::max(max_h, im.height);
  }
  const Imath::Box2i display(Imath::V2i(0, 0), Imath::V2i(max_w - 1, max_h - 1));
  std::vector<Imf::Header> headers;
  for (const Image& im : images) {
    Imf::Header h(display, Imath::Box2i(Imath::V2i(0, 0), Imath::V2i(im.width - 1, im.height - 1)));
    h.setName(im.name);
    h.setType(Imf::SCANLINEIMAGE);
    h.compression() = Imf::ZIP_COMPRESSION;
    // Y: one grey channel, which texture loaders read as luminance.
    h.channels().insert("Y", Imf::Channel(Imf::FLOAT));
    h.insert("brdfkit.model", Imf::StringAttribute(t.model));
    h.insert("brdfkit.params", Imf::StringAttribute(t.params_text));
    if (!t.part.empty()) h.insert("brdfkit.part", Imf::StringAttribute(t.part));
    h.insert("brdfkit.axes", Imf::StringAttribute(AxesText(t)));
    h.insert("brdfkit.nodes.mu", Imf::FloatVectorAttribute(to_float(t.mu.nodes)));
    for (const Axis& a : t.params) h.insert("brdfkit.nodes." + a.name, Imf::FloatVectorAttribute(to_float(a.nodes)));
    headers.push_back(h);
  }
  AtomicFile file(path, std::ios::out | std::ios::binary);
  {
    Imf::StdOFStream os(file.stream(), path.c_str());
    Imf::MultiPartOutputFile out(os, headers.data(), int(headers.size()));
    for (std::size_t i = 0; i < images.size(); ++i) {
      Image& im = images[i];
      Imf::OutputPart part(out, int(i));
      Imf::FrameBuffer fb;
      fb.insert("Y", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(im.data.data()), sizeof(float),
                                sizeof(float) * im.width));
      part.setFrameBuffer(fb);
      part.writePixels(im.height);
    }
  }
  file.Commit();
}

std::string FloatLiteral(double v, const std::string& what) {
  if (!std::isfinite(v) || std::abs(v) > double(std::numeric_limits<float>::max()))
    throw ModelError("albedo header: " + what + " = " + FormatDouble(v) + " has no float literal");
  if (std::abs(v) < double(std::numeric_limits<float>::min())) return "0.0f";
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  std::string out = buf;
  if (out.find_first_of(".e") == std::string::npos) out += ".0";
  return out + "f";
}


void WriteAlbedoHeader(const AlbedoTable& t, const std::string& path, const std::string& prefix) {
  std::string upper;
  for (char c : prefix) upper += static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  std::ostringstream s;
  // An array with its initializer braced per dimension (C's -Wmissing-braces):
  // dims lists the extents, the last running fastest.
  const auto array = [&](const std::string& name, const std::vector<double>& v, const std::vector<std::size_t>& dims,
                         const std::string& comment) {
    s << "/* " << comment << " */\n";
    s << "static const float " << prefix << "_" << name;
    for (std::size_t d : dims) s << "[" << d << "]";
    s << " " << upper << "_UNUSED = ";
    std::size_t next = 0;
    const std::function<void(std::size_t, int)> block = [&](std::size_t level, int indent) {
      const std::string pad(std::size_t(indent), ' ');
      s << "{";
      if (level + 1 == dims.size()) {
        for (std::size_t i = 0; i < dims[level]; ++i, ++next) {
          if (i % 8 == 0) s << "\n" << pad << "  ";
          s << (i % 8 ? " " : "") << FloatLiteral(v[next], name + "[" + std::to_string(next) + "]")
            << (i + 1 < dims[level] ? "," : "");
        }
      } else {
        for (std::size_t i = 0; i < dims[level]; ++i) {
          s << "\n" << pad << "  ";
          block(level + 1, indent + 2);
          if (i + 1 < dims[level]) s << ",";
        }
      }
      s << "\n" << pad << "}";
    };
    block(0, 0);
    s << ";\n\n";
  };
  // Without parameter axes E runs over mu alone and each average is one value.
  std::vector<std::size_t> dims_p;
  for (const Axis& a : t.params) dims_p.push_back(a.nodes.size());
  std::vector<std::size_t> dims_e = dims_p;
  dims_e.push_back(t.n_mu());
  if (dims_p.empty()) dims_p = {1};
  const std::string guard = upper + "_H";
  s << "/* Directional albedo tables generated by brdfkit albedo.\n"
    << " * model: " << t.model << "\n"
    << " * params: " << t.params_text << "\n"
    << " * axes: " << AxesText(t) << " (mu = cos(theta_o); mu runs fastest)\n"
    << (t.part.empty() ? std::string() : " * entries: " + t.part + " (reflected, transmitted or scattered power)\n")
    << " * E at mu = 0 holds the limit mu -> 0. Compensation lobe (Kulla & Conty 2017):\n"
    << " *   f_ms(wi, wo) = (1 - E(mu_i)) (1 - E(mu_o)) * ms_norm, ms_norm = 1 / (pi (1 - E_avg)),\n"
    << " *   and ms_norm = 0 where E_avg >= 1 (nothing is lost, the compensation lobe vanishes).\n"
    << " * Valid C89 and C++: float arrays and node arrays, all finite. */\n"
    << "#ifndef " << guard << "\n#define " << guard << "\n\n#include <math.h>\n\n"
    << "#if defined(__GNUC__) || defined(__clang__)\n#define " << upper << "_UNUSED __attribute__((unused))\n"
    << "#else\n#define " << upper << "_UNUSED\n#endif\n\n";
  s << "enum { " << prefix << "_n_mu = " << t.n_mu();
  for (const Axis& a : t.params) s << ", " << prefix << "_n_" << a.name << " = " << a.nodes.size();
  s << " };\n\n";
  array("mu_nodes", t.mu.nodes, {t.n_mu()}, "mu node values");
  for (const Axis& a : t.params)
    array(a.name + "_nodes", a.nodes, {a.nodes.size()},
          a.name + " node values" + (a.sqrt_spacing ? " (spaced in sqrt(" + a.name + "))" : ""));
  std::string e_index;
  for (const Axis& a : t.params) e_index += "[" + a.name + "]";
  array("E", t.E, dims_e, "E" + e_index + "[mu]");
  array("E_avg", t.E_avg, dims_p, "E_avg = 2 int_0^1 E(mu) mu dmu");
  array("ms_norm", t.ms_norm, dims_p, "1 / (pi (1 - E_avg)); 0 where E_avg >= 1");
  if (t.f0_axis >= 0) {
    const std::size_t n_other = t.E1_avg.size();
    array("F_avg", t.F_avg, {t.F_avg.size()}, "Schlick F_avg = f0 + (1 - f0) / 21");
    array("E1", t.E1, {n_other, t.n_mu()}, "E with F = 1 (f0 = 1), for f_ms");
    array("E1_avg", t.E1_avg, {n_other}, "E_avg with F = 1");
    array("F_ms", t.F_ms, dims_p, "F_avg^2 E1_avg / (1 - F_avg (1 - E1_avg)), multiplies f_ms");
  }
  // Lookups: clamped linear interpolation along every axis, in the axis's
  // node coordinate.
  const std::string loc = prefix + "_locate";
  s << "/* Lookups (C89 and C++): clamped linear interpolation between the nodes of\n"
    << " * every axis, in the coordinate the nodes are spaced in (sqrt(x) for an axis\n"
    << " * spaced in sqrt(x), x otherwise); exact at the nodes. As textures, texel i\n"
    << " * of an axis holds node i: with uniform nodes a renderer's linear filter\n"
    << " * reads the same values at u = (0.5 + (n - 1) t) / n, t = (c(x) - c(x_0)) /\n"
    << " * (c(x_{n-1}) - c(x_0)); Gauss nodes are not evenly spaced and need these\n"
    << " * functions. */\n"
    << "static float " << loc << "(const float *nodes, int n, float x, int sq, int *i) " << upper << "_UNUSED;\n"
    << "static float " << loc << "(const float *nodes, int n, float x, int sq, int *i) {\n"
    << "  int lo = 0, hi = n - 1;\n  float c, c0, c1;\n"
    << "  if (n < 2) {\n    *i = 0;\n    return 0.0f;\n  }\n"
    << "  while (hi - lo > 1) {\n    int mid = (lo + hi) / 2;\n    if (nodes[mid] <= x) lo = mid; else hi = mid;\n  }\n"
    << "  *i = lo;\n"
    << "  c = sq ? (float)sqrt(x > 0.0f ? x : 0.0f) : x;\n"
    << "  c0 = sq ? (float)sqrt(nodes[lo]) : nodes[lo];\n"
    << "  c1 = sq ? (float)sqrt(nodes[lo + 1]) : nodes[lo + 1];\n"
    << "  c = (c - c0) / (c1 - c0);\n"
    << "  return c < 0.0f ? 0.0f : (c > 1.0f ? 1.0f : c);\n}\n\n";
  struct LookupAxis {
    std::string arg, nodes, count;
    bool sq;
  };
  std::vector<LookupAxis> param_axes;
  for (const Axis& a : t.params)
    param_axes.push_back({a.name, prefix + "_" + a.name + "_nodes", prefix + "_n_" + a.name, a.sqrt_spacing});
  const LookupAxis mu_axis{"mu", prefix + "_mu_nodes", prefix + "_n_mu", false};
  // name_lookup(args...) over `dims` (the array's axes, last fastest); the
  // arguments are mu first (when on the array) then the parameters.
  const auto lookup = [&](const std::string& name, const std::vector<LookupAxis>& dims, const std::string& what) {
    std::vector<const LookupAxis*> args;
    for (const LookupAxis& d : dims)
      if (d.arg == "mu") args.push_back(&d);
    for (const LookupAxis& d : dims)
      if (d.arg != "mu") args.push_back(&d);
    std::string sig = "static float " + prefix + "_" + name + "_lookup(";
    for (std::size_t k = 0; k < args.size(); ++k) sig += (k ? ", float " : "float ") + args[k]->arg;
    sig += ")";
    s << "/* " << what << " */\n" << sig << " " << upper << "_UNUSED;\n" << sig << " {\n";
    s << "  int i[" << dims.size() << "], j[" << dims.size() << "];\n  float w[" << dims.size() << "];\n";
    for (std::size_t d = 0; d < dims.size(); ++d) {
      s << "  w[" << d << "] = " << loc << "(" << dims[d].nodes << ", " << dims[d].count << ", " << dims[d].arg << ", "
        << (dims[d].sq ? 1 : 0) << ", &i[" << d << "]);\n";
      s << "  j[" << d << "] = " << dims[d].count << " > 1 ? i[" << d << "] + 1 : i[" << d << "];\n";
    }
    const std::function<std::string(std::size_t, std::string)> term = [&](std::size_t d, std::string idx) {
      if (d == dims.size()) return prefix + "_" + name + idx;
      const std::string w = "w[" + std::to_string(d) + "]";
      return "((1.0f - " + w + ") * " + term(d + 1, idx + "[i[" + std::to_string(d) + "]]") + " + " + w + " * " +
             term(d + 1, idx + "[j[" + std::to_string(d) + "]]") + ")";
    };
    s << "  return " << term(0, "") << ";\n}\n\n";
  };
  std::vector<LookupAxis> e_dims = param_axes;
  e_dims.push_back(mu_axis);
  lookup("E", e_dims, "E at (mu, parameters)");
  // Without parameter axes E_avg and ms_norm are single values: no lookup.
  if (!param_axes.empty()) {
    lookup("E_avg", param_axes, "E_avg at the parameters");
    lookup("ms_norm", param_axes, "ms_norm at the parameters");
  }
  if (t.f0_axis >= 0) lookup("F_ms", param_axes, "F_ms at the parameters");
  s << "#undef " << upper << "_UNUSED\n\n#endif /* " << guard << " */\n";
  WriteFileAtomic(path, s.str());
}

// --- energy compensation -------------------------------------------------

AlbedoLookup::AlbedoLookup(const AlbedoTable& table) : t_(table) {
  if (t_.params.size() != 1) throw ModelError("AlbedoLookup: needs a table with exactly one parameter axis");
  if (t_.n_mu() < 4) throw ModelError("AlbedoLookup: needs at least 4 mu nodes");
  mu_coord_ = t_.mu.nodes;
  for (double x : t_.params[0].nodes) p_coord_.push_back(t_.params[0].sqrt_spacing ? std::sqrt(x) : x);
}

double AlbedoLookup::Interp1(const std::vector<double>& coords, double c, std::size_t& i0) const {
  // Cell index i0 with coords[i0] <= c <= coords[i0 + 1] (clamped) and the
  // linear weight of coords[i0 + 1].
  if (coords.size() == 1) {
    i0 = 0;
    return 0;
  }
  const auto it = std::upper_bound(coords.begin(), coords.end(), c);
  std::size_t i = it == coords.begin() ? 0 : std::size_t(it - coords.begin()) - 1;
  i = std::min(i, coords.size() - 2);
  i0 = i;
  return std::clamp((c - coords[i]) / (coords[i + 1] - coords[i]), 0.0, 1.0);
}

double AlbedoLookup::E(double mu, double p) const {
  std::size_t ip;
  const double wp = Interp1(p_coord_, Coordinate(p), ip);
  // Cubic Lagrange in mu through the four nodes around mu.
  const std::size_t n = t_.n_mu();
  std::size_t im;
  Interp1(mu_coord_, mu, im);
  const std::size_t s = std::min(im > 0 ? im - 1 : 0, n - 4);
  const auto at_p = [&](std::size_t ipp) {
    double sum = 0;
    for (std::size_t a = s; a < s + 4; ++a) {
      double l = 1;
      for (std::size_t b = s; b < s + 4; ++b)
        if (b != a) l *= (mu - mu_coord_[b]) / (mu_coord_[a] - mu_coord_[b]);
      sum += l * t_.at(a, ipp);
    }
    return sum;
  };
  const double e0 = at_p(ip);
  return p_coord_.size() == 1 ? e0 : (1 - wp) * e0 + wp * at_p(ip + 1);
}

double AlbedoLookup::EAvg(double p) const {
  std::size_t ip;
  const double wp = Interp1(p_coord_, Coordinate(p), ip);
  return p_coord_.size() == 1 ? t_.E_avg[0] : (1 - wp) * t_.E_avg[ip] + wp * t_.E_avg[ip + 1];
}

CompensatedBxdf::CompensatedBxdf(const Bxdf<double>& base, const AlbedoTable& table)
    : base_(base), lookup_(table), offset_(base.Info().Offset(table.params[0].param_index)) {}

Rgb<double> CompensatedBxdf::Eval(const double* p, const Vec3<double>& wi, const Vec3<double>& wo) const {
  Rgb<double> f = base_.Eval(p, wi, wo);
  if (!SameUpperHemisphere(wi, wo)) return f;
  const double a = p[offset_];
  const double e_avg = lookup_.EAvg(a);
  // E_avg = 1 means nothing is lost: no compensation.
  if (!(e_avg < 1)) return f;
  const double ms = (1 - lookup_.E(wi.z(), a)) * (1 - lookup_.E(wo.z(), a)) / (kPi * (1 - e_avg));
  return f + ms;
}

}  // namespace brdfkit::validate
