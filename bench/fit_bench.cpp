// Fitting lambert+ggx (RGB) to a full MERL-size table (90 x 90 x 180 bins,
// the bin centres above the horizon), for every metric and linear solver:
// wall time to convergence on 2 threads, final metric RMSE and the largest
// relative parameter error against the material that wrote the table.
//
//   build/bench/fit_bench --benchmark_filter=Fit
//
// The MERL-format table is tabulated from a known material in memory (the
// measured database cannot be downloaded here); the fit starts from the
// default multi-start, not from the truth.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>

#include "brdf/merl.h"
#include "brdf/model.h"
#include "brdf/params.h"
#include "fit/fit.h"

namespace {

using namespace brdfkit;

const Model& TheModel() {
  static const Model m = Model::Parse("lambert+ggx");
  return m;
}

const std::vector<double>& Truth() {
  static const std::vector<double> p =
      ParseParams(TheModel().Info(), "lambert.albedo=0.12:0.09:0.05,ggx.alpha=0.06,ggx.f0=0.9:0.75:0.55");
  return p;
}

const fit::Dataset& Table() {
  static const fit::Dataset d = [] {
    const auto b = TheModel().Make<double>();
    const MerlTable t = MerlTable::FromFunction(
        [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return b->Eval(Truth().data(), wi, wo); });
    return fit::FromMerl(t);
  }();
  return d;
}

void BM_Fit(benchmark::State& state) {
  const fit::Dataset& data = Table();
  fit::Options o;
  o.metric = static_cast<fit::Metric>(state.range(0));
  o.solver = static_cast<fit::LinearSolver>(state.range(1));
  o.num_threads = 2;
  o.covariance = state.range(2) != 0;
  fit::Result r;
  for (auto _ : state) {
    r = fit::Fit(TheModel(), data, o);
    benchmark::DoNotOptimize(r.cost);
  }
  double max_err = 0;
  for (std::size_t k = 0; k < r.params.size(); ++k)
    max_err = std::max(max_err, std::abs(r.params[k] / Truth()[k] - 1));
  state.counters["samples"] = static_cast<double>(r.used);
  state.counters["rmse"] = r.rmse;
  state.counters["max_rel_err"] = max_err;
  state.counters["iterations"] = r.iterations;
  state.counters["init_s"] = r.init_seconds;
  state.counters["solve_s"] = r.solve_seconds;
  state.counters["converged"] = r.converged ? 1 : 0;
  state.SetLabel(fit::MetricName(o.metric) + "/" + fit::LinearSolverName(o.solver) +
                 (o.covariance ? "/covariance" : ""));
}

void Args(benchmark::internal::Benchmark* b) {
  for (int metric = 0; metric < 5; ++metric)
    for (int solver = 0; solver < 4; ++solver) b->Args({metric, solver, 0});
  b->Args({0, 0, 1});  // with the uncertainty computation
}

BENCHMARK(BM_Fit)->Apply(Args)->Iterations(1)->UseRealTime()->Unit(benchmark::kSecond);

}  // namespace

BENCHMARK_MAIN();
