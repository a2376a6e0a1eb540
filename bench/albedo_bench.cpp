// Albedo table speed: a 32 x 32 GGX table (mu uniform on [0, 1], alpha
// uniform in sqrt on [1e-3, 1]) plus E_avg, at the default tolerance (1e-6,
// the tables' accuracy contract) and at 1e-8, against importance-sampled
// Monte Carlo at the same accuracy. cpu_s_all_threads is the process CPU
// time (all TBB threads) per table: wall time depends on the machine's load. The Monte Carlo row reports the samples per
// cell it needs for a standard error equal to the table's largest error
// estimate, and the seconds that costs, measured on a sample of cells.
#include <benchmark/benchmark.h>

#include <cmath>
#include <ctime>
#include <random>

#include "brdf/model.h"
#include "brdf/params.h"
#include "validate/albedo.h"
#include "validate/integrators.h"

namespace {

using namespace brdfkit;

const Model& Ggx() {
  static const Model m = Model::Parse("ggx");
  return m;
}

void BM_AlbedoTableGgx32x32(benchmark::State& state) {
  const Model& m = Ggx();
  validate::AlbedoTableRequest req;
  req.axes = validate::ParseAxes("mu:32,alpha:32:0.001:1");
  // Argument: -log10 of the tolerance.
  req.quadrature.abs_tolerance = std::pow(10.0, -double(state.range(0)));
  const std::vector<double> p = ParseParams(m.Info(), "f0=1");
  double max_error = 0;
  const std::clock_t c0 = std::clock();
  for (auto _ : state) {
    const validate::AlbedoTable t = validate::BuildAlbedoTable(m, p, req);
    max_error = t.max_error;
    benchmark::DoNotOptimize(t.E.data());
  }
  state.counters["cpu_s_all_threads"] = double(std::clock() - c0) / CLOCKS_PER_SEC / double(state.iterations());
  state.counters["max_error"] = max_error;
}
BENCHMARK(BM_AlbedoTableGgx32x32)->Arg(6)->Arg(8)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(2);

// The same table with the quadrature's batches evaluated pair by pair (the
// Bxdf default EvalBatch: one virtual Eval per node), the baseline of the
// batched rule above in the same run.
class PerCallView final : public Bxdf<double> {
 public:
  explicit PerCallView(const Bxdf<double>& b) : b_(b) {}
  const ModelInfo& Info() const override { return b_.Info(); }
  Rgb<double> Eval(const double* p, const Vec3<double>& wi, const Vec3<double>& wo) const override {
    return b_.Eval(p, wi, wo);
  }
  BsdfSample<double> Sample(const double* p, const Vec3<double>& wo, double u1, double u2) const override {
    return b_.Sample(p, wo, u1, u2);
  }
  double Pdf(const double* p, const Vec3<double>& wo, const Vec3<double>& wi) const override { return b_.Pdf(p, wo, wi); }
  double SampleWeight(const double* p) const override { return b_.SampleWeight(p); }
  bool CanSample() const override { return b_.CanSample(); }
  unsigned Kind() const override { return b_.Kind(); }
  LobeWidth Width(const double* p) const override { return b_.Width(p); }
  bool ChannelsIndependent() const override { return b_.ChannelsIndependent(); }
  const MicrofacetView<double>* Microfacet() const override { return b_.Microfacet(); }

 private:
  const Bxdf<double>& b_;
};

void BM_AlbedoTableGgx32x32Batch(benchmark::State& state) {
  const Model& m = Ggx();
  const auto own = m.Make<double>();
  const PerCallView per_call(*own);
  const Bxdf<double>& b = state.range(0) ? static_cast<const Bxdf<double>&>(*own) : per_call;
  validate::AlbedoTableRequest req;
  req.axes = validate::ParseAxes("mu:32,alpha:32:0.001:1");
  const std::vector<double> p = ParseParams(m.Info(), "f0=1");
  double e00 = 0;
  const std::clock_t c0 = std::clock();
  for (auto _ : state) {
    const validate::AlbedoTable t = validate::BuildAlbedoTable(b, "ggx", p, req);
    e00 = t.E[0];
    benchmark::DoNotOptimize(t.E.data());
  }
  state.counters["cpu_s_all_threads"] = double(std::clock() - c0) / CLOCKS_PER_SEC / double(state.iterations());
  state.counters["E_first"] = e00;
  state.SetLabel(state.range(0) ? "EvalBatch per rule" : "Eval per node");
}
BENCHMARK(BM_AlbedoTableGgx32x32Batch)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(2);

// Importance-sampled Monte Carlo at a target standard error: measure the
// per-sample variance and speed on a few cells, then scale to 1024 cells.
void BM_MonteCarloEquivalent(benchmark::State& state) {
  const Model& m = Ggx();
  const auto b = m.Make<double>();
  const double target = 1e-6;  // the table's accuracy requirement (its error estimates are below)
  double seconds_per_table = 0, samples_per_cell = 0;
  for (auto _ : state) {
    double var_sum = 0, time_per_sample = 0;
    int cells = 0;
    for (double alpha : {0.001, 0.1, 0.5, 1.0})
      for (double mu : {0.05, 0.5, 1.0}) {
        const std::vector<double> p = ParseParams(m.Info(), "f0=1,alpha=" + FormatDouble(alpha));
        const Eigen::Vector3d wo(std::sqrt(1 - mu * mu), 0, mu);
        validate::IntegrateOptions o;
        o.budget = 1 << 16;
        const validate::Estimate e = validate::DirectionalAlbedo(*b, p.data(), wo, validate::Method::kImportance, o);
        // The estimate's error is 3 standard errors: per-sample variance n (err / 3)^2.
        const double se = e.error[0] / 3;
        var_sum += double(e.evals) * se * se;
        time_per_sample += e.seconds / double(e.evals);
        ++cells;
      }
    const double var = var_sum / cells;
    samples_per_cell = var / (target * target);
    seconds_per_table = samples_per_cell * (time_per_sample / cells) * 1024;
  }
  state.counters["samples_per_cell"] = samples_per_cell;
  state.counters["seconds_per_32x32_table"] = seconds_per_table;
}
BENCHMARK(BM_MonteCarloEquivalent)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);

}  // namespace

BENCHMARK_MAIN();
