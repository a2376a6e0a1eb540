// Fit: the steps of a fit in order. Each step lives with its concern
// (fit_internal.h lists the files).
#include <tbb/info.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>

#include "brdf/params.h"
#include "fit/fit_internal.h"

namespace brdfkit::fit {

namespace {

// The samples within the angle cut; throws when there are none, or too few
// for the parameters.
Selection SelectSamples(const Dataset& data, const Options& o, std::size_t n, Result& res) {
  const Selection sel = Select(data, o);
  res.dropped_angle = sel.dropped_angle;
  res.used = sel.index.size();
  if (sel.index.empty())
    throw std::invalid_argument("no samples to fit" + (data.source.empty() ? "" : " in '" + data.source + "'") +
                                " (" + std::to_string(data.samples.size()) + " read, " +
                                std::to_string(sel.dropped_angle) + " beyond the angle cut, " +
                                std::to_string(data.missing) + " missing)");
  if (3 * sel.index.size() < n)
    throw std::invalid_argument("too few samples (" + std::to_string(sel.index.size()) + ") for " +
                                std::to_string(n) + " parameters");
  return sel;
}

Options WithoutLoss(const Options& o) {
  Options plain = o;
  plain.loss = Loss::kNone;
  return plain;
}

// The final solve on all samples from internal parameters u (updated in
// place), which records the solution, its cost and the solver's report;
// returns the normal matrix (J^T J) at the solution or, where Ceres ended
// the solve, at its last Jacobian (the point before its last step, or the
// solution). With `from` (J^T J and J^T r at u: a solve that goes on after
// held bounds are released) the secant end phase runs alone (SolveToEnd).
// With `pause` (Start::pause) the end phase may pause where the cost
// creeps; `paused` says whether it did.
std::optional<NormalCache::Normal> FinalSolve(const FitState& s, const Engine& engine, std::vector<double>& u,
                                              const NormalCache::Normal* from, const Pause& pause, bool& paused) {
  Result& res = s.res;
  const Options& o = s.o;
  const std::size_t m = 3 * s.full.size();
  const bool weights_are_metric = !s.sigma && o.loss == Loss::kNone;
  const Solved solved = SolveToEnd(
      engine, s.full, s.chunk, u, SolverOptions(o, o.solver, o.max_iterations), from,
      [&](int iteration, double cost, const std::vector<double>& at) {
        TracePoint tp;
        tp.stage = "final";
        tp.iteration = iteration;
        tp.seconds = s.elapsed();
        tp.cost = cost;
        tp.rmse = RmseAt(engine, s.full, at, cost, weights_are_metric);
        res.trace.push_back(tp);
        if (o.progress) o.progress(iteration, tp.seconds, cost);
      },
      std::numeric_limits<double>::infinity(),
      pause ? [&](const std::vector<double>& at) { return pause(engine.ToUser(at)); } : Pause());
  paused = solved.paused;
  const ceres::Solver::Summary& summary = solved.summary;
  res.solve_seconds = s.elapsed();
  res.params = engine.ToUser(u);
  res.cost = summary.final_cost;
  res.iterations = summary.num_successful_steps + summary.num_unsuccessful_steps;
  res.converged = summary.termination_type == ceres::CONVERGENCE;
  res.message = summary.message;
  if (summary.termination_type == ceres::FAILURE)
    res.message = "the solver failed: " + summary.message;
  res.residuals = m;
  return solved.normal;
}

// The final solve, holding the bounds that are active at its start
// (HoldingBounds).
std::optional<NormalCache::Normal> SolveWithActiveSet(const FitState& s, const Evaluators& model, double loss_scale,
                                                      const Engine& engine, std::vector<double>& u,
                                                      const Pause& pause, bool& paused) {
  std::optional<NormalCache::Normal> last;
  std::optional<NormalCache::Normal> held =
      HoldingBounds(model, s.o, loss_scale, engine, s.full, s.chunk, u,
                    [&](const Engine& e, std::vector<double>& v, const NormalCache::Normal* from) {
                      last = FinalSolve(s, e, v, from, pause, paused);
                    });
  return held ? held : last;
}

// Residual variance: chi^2 / dof with sigma weights; otherwise the scale
// of the unweighted residuals, which only the covariance uses.
double ResidualVariance(const FitState& s) {
  const std::size_t m = 3 * s.full.size(), nf = s.layout.Free();
  return m > nf ? 2 * s.res.cost / static_cast<double>(m - nf) : 0.0;
}

// What the result reports beside the parameters: the fixed and tied slots,
// the local optimum of a fit without a start search, the goodness of fit
// and warnings.
void Summarise(const FitState& s, const Engine& engine, const std::vector<double>& u, double residual_variance) {
  Result& res = s.res;
  const Layout& layout = s.layout;
  const std::size_t n = engine.packed();
  res.fixed.assign(n, false);
  res.tied_to.assign(n, "");
  for (std::size_t k = 0; k < n; ++k) {
    res.fixed[k] = layout.free_of[k] < 0;
    if (layout.leader[k] >= 0) res.tied_to[k] = res.packed_names[std::size_t(layout.leader[k])];
  }
  if (res.local_optima.empty()) {
    res.local_optima.push_back({res.cost, res.params, s.o.initial.empty() ? "multi-start" : "initial"});
    res.kept = 0;
  }
  res.chi2_reduced = s.sigma ? residual_variance : std::numeric_limits<double>::quiet_NaN();
  res.rmse = RmseAt(engine, s.full, u, res.cost, !s.sigma && s.o.loss == Loss::kNone);
  RelativeErrors(engine, s.full, res.params, res);
  const Dataset& data = s.data;
  if (!s.o.instrument && !data.apertures.empty())
    res.warnings.push_back("the data were measured through finite apertures (" + data.apertures +
                           ", sidecar '" + data.sidecar +
                           "'): a plain fit takes the aperture-averaged values for f_r and biases narrow lobes; "
                           "fit through the instrument (brdfkit fit --instrument " + data.sidecar +
                           ", or \"instrument\" in a scene's fit task)");
  // Residuals more than twice the stated noise (chi^2 / dof > 4): the model
  // does not describe the data, whatever the standard deviations say.
  if (s.sigma && residual_variance > 4)
    res.warnings.push_back("model mismatch: the residuals are " + FormatDouble(std::round(std::sqrt(residual_variance) * 10) / 10) +
                           " times the noise the data state (reduced chi-square " +
                           FormatDouble(std::round(residual_variance * 100) / 100) +
                           "); the standard deviations, statistical given the model, understate how far it is from "
                           "the material");
}

Result FitInArena(const Evaluators& model, const Dataset& data, const Options& o) {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  auto elapsed = [&] { return std::chrono::duration<double>(Clock::now() - t0).count(); };

  const ModelInfo& info = model.Info();
  Result res;
  res.metric = o.metric;
  res.missing = data.missing;
  res.packed_names = PackedNames(info);
  Selection sel = SelectSamples(data, o, info.PackedSize(), res);
  const Prepared full = Prepare(data, std::move(sel.index), o);
  const Layout layout = MakeLayout(info, o);
  // Engine without a robust loss for the start search; its scale is chosen below.
  const Engine plain(model, WithoutLoss(o), 1.0, layout);
  const FitState s{model, data, o, full, layout, plain, data.has_sigma && o.use_sigma,
                   std::max<std::size_t>(1, o.chunk), elapsed, res};

  const Start start = StartingPoint(s);
  std::vector<double> u = start.u;
  const double loss_scale = LossScale(s, u);
  res.loss_scale = o.loss != Loss::kNone ? loss_scale : 0.0;
  const Engine engine(model, o, loss_scale, layout);
  res.init_seconds = elapsed();
  bool paused = false;
  std::optional<NormalCache::Normal> jtj = SolveWithActiveSet(s, model, loss_scale, engine, u, start.pause, paused);
  if (start.after_final) {
    // A new final solve from the better point after_final finds, or the
    // paused one resumed.
    std::optional<std::vector<double>> again = start.after_final(res.params, paused);
    if (again) {
      u = *again;
      res.init_seconds = elapsed();
    }
    if (again || paused) jtj = SolveWithActiveSet(s, model, loss_scale, engine, u, {}, paused);
  }
  const double residual_variance = ResidualVariance(s);
  Summarise(s, engine, u, residual_variance);
  Uncertainty(s, engine, u, residual_variance, jtj);
  res.seconds = elapsed();
  return res;
}

}  // namespace

Result Fit(const Model& model, const Dataset& data, const Options& options) {
  Result res = Fit(ModelEvaluators(model), data, options);
  res.model = model;
  return res;
}

void CheckOptions(const Options& o, const std::function<std::string(const std::string&)>& spell) {
  const auto fail = [&](const std::string& field, const std::string& what) {
    throw std::invalid_argument((spell ? spell(field) : field) + " must be " + what);
  };
  if (o.max_theta_deg != -1 && !(o.max_theta_deg > 0 && o.max_theta_deg <= 90)) fail("max_theta_deg", "in (0, 90]");
  if (o.max_iterations < 1) fail("max_iterations", "at least 1");
  if (o.starts_per_param < 1) fail("starts_per_param", "at least 1");
  if (o.start_subset < 1) fail("start_subset", "at least 1");
  if (o.start_iterations < 1) fail("start_iterations", "at least 1");
  if (o.random_starts < 0 || o.random_starts > kMaxRandomStarts)
    fail("random_starts", "in [0, " + std::to_string(kMaxRandomStarts) + "]");
}

Result Fit(const Evaluators& model, const Dataset& data, const Options& options) {
  CheckOptions(options);
  // More worker threads than the machine offers only cost memory and
  // start-up (a count such as 100000 would exhaust the process's thread limit).
  Options o = options;
  o.num_threads = std::clamp(o.num_threads, 1, std::max(1, tbb::info::default_concurrency()));
  // The project's TBB pool, limited to num_threads for this fit; Ceres runs
  // its solver threads itself.
  tbb::task_arena arena(o.num_threads);
  return arena.execute([&] { return FitInArena(model, data, o); });
}

}  // namespace brdfkit::fit
