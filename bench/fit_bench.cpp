// Fitting lambert+ggx (RGB) to a full MERL-size table (90 x 90 x 180 bins,
// the bin centres above the horizon), for every metric and linear solver:
// wall time to convergence on 2 threads (and the process CPU time), final
// metric RMSE, and the largest relative parameter error against the
// material that wrote the table (meaningful for material 0).
//
//   build/bench/fit_bench --benchmark_filter=Fit
//
// The MERL-format table is tabulated from a known material in memory (the
// measured database cannot be downloaded here); the fit starts from the
// default multi-start, not from the truth.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <ctime>
#include <string>

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

// material 0: written by lambert+ggx itself (the fit must recover it);
// material 1: lambert+beckmann, which lambert+ggx cannot match exactly, so
// the solver has real work to do and the metrics disagree.
const fit::Dataset& Table(int material) {
  static const fit::Dataset d[2] = {[] {
                                      const auto b = TheModel().Make<double>();
                                      return fit::FromMerl(MerlTable::FromFunction(
                                          [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
                                            return b->Eval(Truth().data(), wi, wo);
                                          }));
                                    }(),
                                    [] {
                                      const Model m = Model::Parse("lambert+beckmann");
                                      const std::vector<double> p = ParseParams(
                                          m.Info(),
                                          "lambert.albedo=0.12:0.09:0.05,beckmann.alpha=0.08,"
                                          "beckmann.f0=0.9:0.75:0.55");
                                      const auto b = m.Make<double>();
                                      return fit::FromMerl(MerlTable::FromFunction(
                                          [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
                                            return b->Eval(p.data(), wi, wo);
                                          }));
                                    }()};
  return d[material];
}

void BM_Fit(benchmark::State& state) {
  const int material = static_cast<int>(state.range(3));
  const fit::Dataset& data = Table(material);
  fit::Options o;
  o.metric = static_cast<fit::Metric>(state.range(0));
  o.solver = static_cast<fit::LinearSolver>(state.range(1));
  o.num_threads = 2;
  o.covariance = state.range(2) != 0;
  fit::Result r;
  // Process CPU time (all threads): wall time depends on the machine's load.
  const std::clock_t c0 = std::clock();
  for (auto _ : state) {
    r = fit::Fit(TheModel(), data, o);
    benchmark::DoNotOptimize(r.cost);
  }
  state.counters["cpu_s_all_threads"] = static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC;
  double max_err = 0;
  for (std::size_t k = 0; k < r.params.size(); ++k)
    max_err = std::max(max_err, std::abs(r.params[k] / Truth()[k] - 1));
  state.counters["alpha"] = r.params[3];
  state.counters["samples"] = static_cast<double>(r.used);
  state.counters["rmse"] = r.rmse;
  state.counters["max_rel_err"] = max_err;
  state.counters["iterations"] = r.iterations;
  state.counters["init_s"] = r.init_seconds;
  state.counters["solve_s"] = r.solve_seconds;
  state.counters["converged"] = r.converged ? 1 : 0;
  state.SetLabel(std::string(material ? "lambert+beckmann" : "lambert+ggx") + "/" + fit::MetricName(o.metric) +
                 "/" + fit::LinearSolverName(o.solver) + (o.covariance ? "/covariance" : ""));
}

// {metric, solver, covariance, material}: every metric and linear solver on
// the lambert+ggx table, the uncertainty computation, and the mismatched
// material with each solver under the l2 metric (its optimum puts the
// albedo on its upper bound: slow, about 100 s CPU each).
void Args(benchmark::internal::Benchmark* b) {
  for (int metric = 0; metric < 5; ++metric)
    for (int solver = 0; solver < 4; ++solver) b->Args({metric, solver, 0, 0});
  b->Args({0, 0, 1, 0});
  for (int solver = 0; solver < 4; ++solver) b->Args({0, solver, 0, 1});
}

BENCHMARK(BM_Fit)->Apply(Args)->Iterations(1)->UseRealTime()->Unit(benchmark::kSecond);

}  // namespace

BENCHMARK_MAIN();
