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

void Run(benchmark::State& state, const Instrument& inst) {
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
  state.counters["src_deg"] = report.source_degree;
  state.counters["det_deg"] = report.detector_degree;
  state.counters["quad_rel_err"] = report.quadrature_error;
  state.counters["evals_per_pair"] = report.mean_evaluations;
  state.counters["pair_rel_err"] = report.pair_error;
  state.counters["at_max"] = double(report.pairs_at_max_order);
  state.counters["at_max_err"] = report.max_order_error;
  state.counters["horizon"] = double(report.horizon_crossing);
}

// Arguments: source and detector angular radius in tenths of a degree.
void BM_MerlGrid(benchmark::State& state) { Run(state, MerlInstrument(state.range(0) / 10.0, state.range(1) / 10.0)); }
BENCHMARK(BM_MerlGrid)->Args({0, 0})->Args({0, 10})->Args({5, 10})->Args({10, 10})->Unit(benchmark::kSecond)->UseRealTime()->Iterations(1);

// Baseline in the same run: the MERL grid at stride 2 (182,250 pairs), 0.5
// degree source and 1 degree detector, with the automatic order (argument
// 0) and with the product rule of a fixed order (argument n).
void BM_MerlStride2(benchmark::State& state) {
  Instrument inst = MerlInstrument(0.5, 1.0);
  for (int& s : inst.plan.merl_stride) s = 2;
  inst.quadrature.order = static_cast<int>(state.range(0));
  Run(state, inst);
}
BENCHMARK(BM_MerlStride2)->Arg(0)->Arg(3)->Arg(4)->Unit(benchmark::kSecond)->UseRealTime()->Iterations(1);

// One MeasuredBrdf call (order 2: 16 x 16 BRDF evaluations), double and Jet.
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
