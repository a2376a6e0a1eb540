// Evaluations per second of every registered model, single thread, double
// and float. Lambert, the cheapest model, runs in the same process as the
// baseline: RESULTS.md reports each model's cost as a ratio to it.
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "brdf/model.h"

namespace {

using namespace brdfkit;

template <typename T>
void EvalModel(benchmark::State& state, const std::string& name) {
  const Model model = Model::Parse(name);
  const auto b = model.Make<T>();
  const std::vector<double> pd = model.Info().Defaults();
  const std::vector<T> p(pd.begin(), pd.end());
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(0, 1);
  constexpr int kDirs = 1024;
  std::vector<Vec3<T>> wi(kDirs), wo(kDirs);
  for (int k = 0; k < kDirs; ++k) {
    for (auto* w : {&wi[k], &wo[k]}) {
      const double z = 0.02 + 0.98 * u(rng), phi = 2 * kPi * u(rng), s = std::sqrt(1 - z * z);
      *w = Vec3<T>(T(s * std::cos(phi)), T(s * std::sin(phi)), T(z));
    }
  }
  int k = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(b->Eval(p.data(), wi[k], wo[k]));
    k = (k + 1) & (kDirs - 1);
  }
  state.SetItemsProcessed(state.iterations());
}

}  // namespace

int main(int argc, char** argv) {
  for (const ModelInfo& info : RegisteredModelInfos()) {
    if (!info.settings.empty()) continue;  // file-backed models have their own benchmark data
    benchmark::RegisterBenchmark(("Eval<double>/" + info.name).c_str(),
                                 [name = info.name](benchmark::State& s) { EvalModel<double>(s, name); });
    benchmark::RegisterBenchmark(("Eval<float>/" + info.name).c_str(),
                                 [name = info.name](benchmark::State& s) { EvalModel<float>(s, name); });
  }
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
