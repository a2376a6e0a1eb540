// Reading measured-data files and evaluating the models that read them,
// with MERL as the baseline in the same run. The files are written from
// lambert+ggx by this process into a folder of its own under the temporary
// folder (removed at exit, so that no run reads a file an older writer
// made): MERL (34,992,012 bytes), RGL at the writer's default resolution
// (isotropic and anisotropic), UTIA (1,990,656 bytes) and an ASTM table on a
// 2.5 degree grid.
#include <benchmark/benchmark.h>

#include <filesystem>
#include <random>
#include <string>
#include <system_error>

#include <unistd.h>

#include "brdf/astm.h"
#include "brdf/merl.h"
#include "brdf/model.h"
#include "brdf/params.h"
#include "brdf/rgl.h"
#include "brdf/utia.h"
#include "formats/convert.h"

namespace brdfkit {
namespace {

// This process's folder of files, removed with them at exit.
struct Folder {
  std::filesystem::path path = std::filesystem::temp_directory_path() /
                               ("brdfkit_formats_bench_" + std::to_string(::getpid()));
  Folder() { std::filesystem::create_directories(path); }
  ~Folder() {
    std::error_code ignored;  // a folder left behind costs disk, not correctness
    std::filesystem::remove_all(path, ignored);
  }
};

std::string File(const std::string& name, formats::ConvertOptions o = {}) {
  static const Folder folder;
  const std::string path = (folder.path / name).string();
  if (!std::filesystem::exists(path)) {
    const Model m = Model::Parse("lambert+ggx");
    const auto b = m.Make<double>();
    const std::vector<double> p = ParseParams(m.Info(), "lambert.albedo=0.3:0.4:0.5,ggx.alpha=0.2,ggx.f0=0.8");
    formats::WriteFormat(path, [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
      return b->Eval(p.data(), wi, wo);
    }, o);
  }
  return path;
}

formats::ConvertOptions Aniso() {
  formats::ConvertOptions o;
  o.rgl.phi_i = formats::kRglAnisotropicPhiI;
  return o;
}
formats::ConvertOptions Fine() {
  formats::ConvertOptions o;
  o.step_deg = 2.5;
  return o;
}

void BM_ReadMerl(benchmark::State& s) {
  const std::string f = File("read.binary");
  for (auto _ : s) benchmark::DoNotOptimize(MerlTable::Read(f));
  s.counters["bytes"] = double(std::filesystem::file_size(f));
}
void BM_ReadRglIsotropic(benchmark::State& s) {
  const std::string f = File("read_iso.bsdf");
  for (auto _ : s) benchmark::DoNotOptimize(RglBsdf::Read(f));
  s.counters["bytes"] = double(std::filesystem::file_size(f));
}
void BM_ReadRglAnisotropic(benchmark::State& s) {
  const std::string f = File("read_aniso.bsdf", Aniso());
  for (auto _ : s) benchmark::DoNotOptimize(RglBsdf::Read(f));
  s.counters["bytes"] = double(std::filesystem::file_size(f));
}
void BM_ReadUtia(benchmark::State& s) {
  const std::string f = File("read.utia");
  for (auto _ : s) benchmark::DoNotOptimize(UtiaTable::Read(f));
  s.counters["bytes"] = double(std::filesystem::file_size(f));
}
void BM_ReadAstm(benchmark::State& s) {
  const std::string f = File("read.astm", Fine());
  for (auto _ : s) benchmark::DoNotOptimize(AstmTable::Read(f));
  s.counters["bytes"] = double(std::filesystem::file_size(f));
}

// Eval of the model over 1024 random upper-hemisphere pairs.
void Evaluate(benchmark::State& s, const std::string& name, const std::string& path, const std::string& interp = "") {
  Settings set{{"path", path}};
  if (!interp.empty()) set["interp"] = interp;
  const Model m = Model::Parse(name, set);
  const auto b = m.Make<double>();
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<Eigen::Vector3d> wi, wo;
  for (int k = 0; k < 1024; ++k) {
    wi.push_back(SampleCosineHemisphere<double>(u(rng), u(rng)));
    wo.push_back(SampleCosineHemisphere<double>(u(rng), u(rng)));
  }
  for (auto _ : s)
    for (int k = 0; k < 1024; ++k) benchmark::DoNotOptimize(b->Eval(nullptr, wi[k], wo[k]));
  s.SetItemsProcessed(s.iterations() * 1024);
}
void BM_EvalMerlNearest(benchmark::State& s) { Evaluate(s, "merl", File("read.binary")); }
void BM_EvalMerlTrilinear(benchmark::State& s) { Evaluate(s, "merl", File("read.binary"), "trilinear"); }
void BM_EvalRglIsotropic(benchmark::State& s) { Evaluate(s, "rgl", File("read_iso.bsdf")); }
void BM_EvalRglAnisotropic(benchmark::State& s) { Evaluate(s, "rgl", File("read_aniso.bsdf", Aniso())); }
void BM_EvalUtia(benchmark::State& s) { Evaluate(s, "utia", File("read.utia")); }
void BM_EvalAstmNearest(benchmark::State& s) { Evaluate(s, "astm", File("read.astm", Fine())); }

BENCHMARK(BM_ReadMerl)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadRglIsotropic)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadRglAnisotropic)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadUtia)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadAstm)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_EvalMerlNearest);
BENCHMARK(BM_EvalMerlTrilinear);
BENCHMARK(BM_EvalRglIsotropic);
BENCHMARK(BM_EvalRglAnisotropic);
BENCHMARK(BM_EvalUtia);
BENCHMARK(BM_EvalAstmNearest);

}  // namespace
}  // namespace brdfkit

BENCHMARK_MAIN();
