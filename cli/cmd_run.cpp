// `brdfkit run`: with no scene, a short demonstration of the model library
// and its checks over every registered model at default parameters.
#include <cstdio>
#include <random>

#include "cli/common.h"
#include "validate/sampling_check.h"

namespace brdfkit::cli {

namespace {

void Demo() {
  std::printf("brdfkit demonstration: every model at its default parameters\n\n");
  std::printf("%-20s %12s %12s %12s %10s %9s\n", "model", "f(n,45deg)", "recip.err", "E(mu=1)", "E(mu=0.1)",
              "chi2 p");
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> uni(0, 1);
  auto random_dir = [&] {
    const double z = uni(rng), phi = 2 * kPi * uni(rng), s = std::sqrt(1 - z * z);
    return Eigen::Vector3d(s * std::cos(phi), s * std::sin(phi), z);
  };
  for (const ModelInfo& info : RegisteredModelInfos()) {
    if (!info.settings.empty()) continue;  // needs a file (e.g. merl)
    const Model model = Model::Parse(info.name);
    const auto bxdf = model.Make<double>();
    const std::vector<double> p = info.Defaults();
    const Eigen::Vector3d n(0, 0, 1), w45(std::sqrt(0.5), 0, std::sqrt(0.5));
    double recip = 0;
    for (int k = 0; k < 2000; ++k) {
      const Eigen::Vector3d a = random_dir(), b = random_dir();
      const Rgb<double> f1 = bxdf->Eval(p.data(), a, b), f2 = bxdf->Eval(p.data(), b, a);
      const double scale = std::max(f1.abs().maxCoeff(), f2.abs().maxCoeff());
      if (scale > 0) recip = std::max(recip, (f1 - f2).abs().maxCoeff() / scale);
    }
    auto albedo = [&](double mu) {
      const Eigen::Vector3d wo(std::sqrt(1 - mu * mu), 0, mu);
      double sum = 0;
      const int n_samples = 20000;
      std::mt19937_64 r2(3);
      for (int k = 0; k < n_samples; ++k) {
        const BsdfSample<double> s = bxdf->Sample(p.data(), wo, uni(r2), uni(r2));
        if (s.valid) sum += bxdf->Eval(p.data(), s.wi, wo).mean() * s.wi.z() / s.pdf;
      }
      return sum / n_samples;
    };
    validate::SamplingCheckOptions opt;
    opt.samples = 50000;
    const auto sc = validate::CheckSampling(*bxdf, p.data(), w45, opt);
    std::printf("%-20s %12.5g %12.2e %12.5f %10.5f %9.3f\n", info.name.c_str(),
                bxdf->Eval(p.data(), n, w45).mean(), recip, albedo(1.0), albedo(0.1), sc.p_value);
  }
  std::printf("\nrecip.err: largest |f(wi,wo) - f(wo,wi)| / max f over 2000 random pairs;\n"
              "E: directional albedo (mean over RGB), importance-sampled, 20000 samples;\n"
              "chi2 p: sampling against the pdf at wo = 45 degrees.\n");
}

}  // namespace

void RegisterRun(CLI::App& app) {
  auto* cmd = app.add_subcommand("run", "run a job; with no scene, a demonstration of the models and checks");
  cmd->callback([] { Demo(); });
}

}  // namespace brdfkit::cli
