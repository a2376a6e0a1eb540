// Evaluations per second of every registered model, single thread, double
// and float, per call (Eval) and in batches (EvalBatch; for Lambert and GGX
// also on each instruction set of their vectorised kernels, EvalBatchIsa).
// Lambert, the cheapest model, runs in the same process as the baseline:
// RESULTS.md reports each model's cost as a ratio to it.
#include <benchmark/benchmark.h>

#include <memory>
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

// EvalBatch on 10^6 pairs into a freshly allocated output each time, as
// Python's Model.eval does: the memory traffic (72 MB in double) and the
// first touch of the output's pages included, for bench/python_bench.py.
template <typename T>
void EvalModelBatchLarge(benchmark::State& state, const std::string& name) {
  constexpr std::size_t kPairs = 1'000'000;
  const Model model = Model::Parse(name);
  const auto b = model.Make<T>();
  const std::vector<double> pd = model.Info().Defaults();
  const std::vector<T> p(pd.begin(), pd.end());
  std::vector<Vec3<T>> wi0, wo0;
  RandomPairs(wi0, wo0);
  std::vector<T> wi(3 * kPairs), wo(3 * kPairs);
  for (std::size_t k = 0; k < kPairs; ++k)
    for (int c = 0; c < 3; ++c) {
      wi[3 * k + c] = wi0[k % kDirs][c];
      wo[3 * k + c] = wo0[(k / kDirs + k) % kDirs][c];
    }
  for (auto _ : state) {
    const std::unique_ptr<T[]> out(new T[3 * kPairs]);
    b->EvalBatch(p.data(), wi.data(), 3, wo.data(), 3, kPairs, out.get());
    benchmark::DoNotOptimize(out.get());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * kPairs);
}

// EvalBatch with the vectorised kernels capped at one instruction set
// (brdf/batch.h): the baseline, AVX2 and AVX-512 versions side by side.
template <typename T>
void EvalModelBatchIsa(benchmark::State& state, const std::string& name, BatchIsa isa) {
  LimitBatchIsa(isa);
  EvalModelBatch<T>(state, name);
  LimitBatchIsa(BatchIsa::kAvx512);
}

}  // namespace

int main(int argc, char** argv) {
  for (const char* name : {"lambert", "ggx"})
    benchmark::RegisterBenchmark((std::string("EvalBatch1M<double>/") + name).c_str(),
                                 [name](benchmark::State& s) { EvalModelBatchLarge<double>(s, name); });
  const char* kIsaNames[] = {"baseline", "avx2", "avx512"};
  for (const char* name : {"lambert", "ggx"})
    for (BatchIsa isa : {BatchIsa::kBaseline, BatchIsa::kAvx2, BatchIsa::kAvx512}) {
      if (isa > DetectedBatchIsa()) continue;
      const std::string suffix = std::string(name) + "/" + kIsaNames[static_cast<int>(isa)];
      benchmark::RegisterBenchmark(("EvalBatchIsa<double>/" + suffix).c_str(),
                                   [name, isa](benchmark::State& s) { EvalModelBatchIsa<double>(s, name, isa); });
      benchmark::RegisterBenchmark(("EvalBatchIsa<float>/" + suffix).c_str(),
                                   [name, isa](benchmark::State& s) { EvalModelBatchIsa<float>(s, name, isa); });
    }
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
