// Synthetic measurement throughput: a full MERL grid (90 x 90 x 180 =
// 1,458,000 direction pairs, RGB) through the forward model, with point
// apertures and with finite apertures integrated to 1e-6 (automatic order),
// in parallel over samples (TBB); and one forward-model evaluation for fits.
#include <benchmark/benchmark.h>
#include <ceres/jet.h>

#include <ctime>

#include "brdf/model.h"
#include "brdf/params.h"
#include "data_synth/forward_model.h"
#include "data_synth/synth.h"

namespace {

using namespace brdfkit;
using namespace brdfkit::synth;

constexpr double kDeg = kPi / 180;

Instrument MerlInstrument(double source_deg, double detector_deg) {
  Instrument inst = DefaultInstrument();
  inst.plan.kind = SamplingPlan::Kind::kMerl;
  if (source_deg > 0) {
    inst.source.kind = Source::Kind::kDisc;
    inst.source.angular_radius = source_deg * kDeg;
    inst.source.radiance = Eigen::Array3d::Constant(1e4);
  }
  inst.detector.angular_radius = detector_deg * kDeg;
  inst.quadrature.order = 0;
  inst.quadrature.tolerance = 1e-6;
  return inst;
}

// Arguments: source and detector angular radius in tenths of a degree.
void BM_MerlGrid(benchmark::State& state) {
  const Instrument inst = MerlInstrument(state.range(0) / 10.0, state.range(1) / 10.0);
  const Model model = Model::Parse("lambert+ggx");
  const std::vector<double> p = ParseParams(model.Info(), "lambert.albedo=0.1:0.2:0.3,ggx.alpha=0.15");
  const ExpandedPlan plan = ExpandPlan(inst.plan);
  SynthReport report;
  // Process CPU time (all TBB threads): wall time depends on the machine's load.
  const std::clock_t c0 = std::clock();
  for (auto _ : state) {
    const SynthResult r = Synthesize(inst, model, p, 1, plan);
    report = r.report;
    benchmark::DoNotOptimize(r.samples.data());
  }
  state.counters["cpu_s_all_threads"] = double(std::clock() - c0) / CLOCKS_PER_SEC;
  state.counters["pairs"] = double(plan.pairs.size());
  state.counters["samples/s"] =
      benchmark::Counter(double(plan.pairs.size()) * double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["order"] = report.order;
  state.counters["quad_rel_err"] = report.quadrature_error;
  state.counters["mean_order"] = report.mean_order;
  state.counters["pair_rel_err"] = report.pair_error;
}
BENCHMARK(BM_MerlGrid)->Args({0, 0})->Args({0, 10})->Args({5, 10})->Unit(benchmark::kSecond)->UseRealTime()->Iterations(1);

// One MeasuredBrdf call (order 2: 64 x 64 BRDF evaluations), double and Jet.
template <class T>
void BM_MeasuredBrdf(benchmark::State& state) {
  const Instrument inst = MerlInstrument(0.5, 1.0);
  const ApertureQuadrature q = MakeApertureQuadrature(inst, 2);
  const Model model = Model::Parse("ggx");
  const auto bxdf = model.Make<T>();
  const std::vector<double> pd = ParseParams(model.Info(), "alpha=0.1");
  std::vector<T> p(pd.begin(), pd.end());
  const Eigen::Vector3d wi = DirectionFromAngles(30 * kDeg, 0), wo = DirectionFromAngles(32 * kDeg, kPi);
  for (auto _ : state) benchmark::DoNotOptimize(MeasuredBrdf(*bxdf, p.data(), wi, wo, q));
}
BENCHMARK(BM_MeasuredBrdf<double>);
BENCHMARK(BM_MeasuredBrdf<ceres::Jet<double, 4>>);

}  // namespace

BENCHMARK_MAIN();
