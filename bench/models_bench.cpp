// Evaluations per second of every registered model, single thread, double
// and float, per call (Eval) and in batches (EvalBatch). Lambert, the cheapest model, runs in the same process as the
// baseline: RESULTS.md reports each model's cost as a ratio to it.
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "brdf/model.h"

namespace {

using namespace brdfkit;

constexpr int kDirs = 1024;

// kDirs random pairs of unit directions above the horizon.
template <typename T>
void RandomPairs(std::vector<Vec3<T>>& wi, std::vector<Vec3<T>>& wo) {
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(0, 1);
  wi.resize(kDirs);
  wo.resize(kDirs);
  for (int k = 0; k < kDirs; ++k) {
    for (auto* w : {&wi[k], &wo[k]}) {
      const double z = 0.02 + 0.98 * u(rng), phi = 2 * kPi * u(rng), s = std::sqrt(1 - z * z);
      *w = Vec3<T>(T(s * std::cos(phi)), T(s * std::sin(phi)), T(z));
    }
  }
}

template <typename T>
void EvalModel(benchmark::State& state, const std::string& name) {
  const Model model = Model::Parse(name);
  const auto b = model.Make<T>();
  const std::vector<double> pd = model.Info().Defaults();
  const std::vector<T> p(pd.begin(), pd.end());
  std::vector<Vec3<T>> wi, wo;
  RandomPairs(wi, wo);
  int k = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(b->Eval(p.data(), wi[k], wo[k]));
    k = (k + 1) & (kDirs - 1);
  }
  state.SetItemsProcessed(state.iterations());
}

// The same pairs through Bxdf<T>::EvalBatch (brdf/batch.h): one virtual
// call per batch of kDirs pairs, the model's Eval inlined in the loop.
template <typename T>
void EvalModelBatch(benchmark::State& state, const std::string& name) {
  const Model model = Model::Parse(name);
  const auto b = model.Make<T>();
  const std::vector<double> pd = model.Info().Defaults();
  const std::vector<T> p(pd.begin(), pd.end());
  std::vector<Vec3<T>> wi, wo;
  RandomPairs(wi, wo);
  std::vector<T> out(3 * kDirs);
  // Vec3<T> is three packed scalars: the rows of an (n, 3) array.
  for (auto _ : state) {
    b->EvalBatch(p.data(), wi[0].data(), 3, wo[0].data(), 3, kDirs, out.data());
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * kDirs);
}

}  // namespace

int main(int argc, char** argv) {
  for (const ModelInfo& info : RegisteredModelInfos()) {
    if (!info.settings.empty()) continue;  // file-backed models have their own benchmark data
    benchmark::RegisterBenchmark(("Eval<double>/" + info.name).c_str(),
                                 [name = info.name](benchmark::State& s) { EvalModel<double>(s, name); });
    benchmark::RegisterBenchmark(("Eval<float>/" + info.name).c_str(),
                                 [name = info.name](benchmark::State& s) { EvalModel<float>(s, name); });
    benchmark::RegisterBenchmark(("EvalBatch<double>/" + info.name).c_str(),
                                 [name = info.name](benchmark::State& s) { EvalModelBatch<double>(s, name); });
    benchmark::RegisterBenchmark(("EvalBatch<float>/" + info.name).c_str(),
                                 [name = info.name](benchmark::State& s) { EvalModelBatch<float>(s, name); });
  }
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
