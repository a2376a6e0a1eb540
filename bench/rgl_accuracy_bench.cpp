// The RGL writer's reconstruction error (formats::MeasureRglAccuracy, the
// measure of `brdfkit convert`'s sidecar) for lambert and GGX and Beckmann
// lobes: at the default resolution on the measure's grid (theta_i = 1.25 ..
// 78.75 degrees), on the same grid extended towards grazing incidence
// (to 83.75 and 86.25 degrees), and at half the default resolution on every
// axis. Optional arguments: --samples N, --vndf N, --vndf-theta N, --theta-i N (the
// resolution measured in place of the default; the half-resolution column
// is then left out), then pairs of model and parameters to measure instead
// of the list below.
#include <cstdio>
#include <stdexcept>
#include <string>
#include <vector>

#include "brdf/model.h"
#include "brdf/params.h"
#include "brdf/rgl.h"
#include "formats/rgl_writer.h"

namespace {

int Run(int argc, char** argv) {
  using namespace brdfkit;
  using formats::MeasureRglAccuracy;
  std::vector<std::string> sources = {"lambert",  "albedo=0.8", "ggx",      "alpha=0.05", "ggx",      "alpha=0.1",
                                      "ggx",      "alpha=0.2",  "ggx",      "alpha=0.5",  "ggx",      "alpha=1",
                                      "beckmann", "alpha=0.05", "beckmann", "alpha=0.3",  "beckmann", "alpha=0.5",
                                      "beckmann", "alpha=1"};
  formats::RglOptions full;
  int a = 1;
  for (; a + 1 < argc && std::string(argv[a]).rfind("--", 0) == 0; a += 2) {
    const std::string name = argv[a];
    int& field = name == "--samples"      ? full.samples
                 : name == "--vndf"       ? full.vndf
                 : name == "--vndf-theta" ? full.vndf_theta
                 : name == "--theta-i"    ? full.theta_i
                 : throw std::invalid_argument("unknown option " + name + " (--samples, --vndf, --vndf-theta, --theta-i)");
    std::size_t used = 0;
    try {
      field = std::stoi(argv[a + 1], &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || argv[a + 1][used] != '\0')
      throw std::invalid_argument(name + " needs a whole number, got '" + argv[a + 1] + "'");
  }
  if (a < argc) sources.assign(argv + a, argv + argc);
  formats::RglOptions half;
  half.theta_i = 40;
  half.ndf = 256;
  half.vndf = 256;
  half.vndf_theta = 64;
  half.samples = 104;
  const bool given = full.samples != 0 || full.vndf != 0 || full.vndf_theta != 0 || full.theta_i != 0;
  std::printf("| source | %s: mean / p99 / max | max to theta_i 83.75 | max to 86.25 |%s\n",
              given ? "given resolution" : "default", given ? "" : " half: p99 / max |");
  std::printf("|---|---|---|---|%s\n", given ? "" : "---|");
  for (std::size_t k = 0; k + 1 < sources.size(); k += 2) {
    const Model model = Model::Parse(sources[k]);
    const std::vector<double> p = ParseParams(model.Info(), sources[k + 1]);
    const auto m = model.Make<double>();
    const formats::BrdfFunction f = [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
      return m->Eval(p.data(), wi, wo);
    };
    const RglBsdf file = RglBsdf::FromTensors(formats::MakeRgl(f, full), "default");
    const formats::RglAccuracy d = MeasureRglAccuracy(file, f);
    const double to85 = MeasureRglAccuracy(file, f, 85).max_relative;
    const double to87 = MeasureRglAccuracy(file, f, 87.5).max_relative;
    std::printf("| `%s` %s | %.2g / %.2g / %.2g | %.2g | %.2g |", sources[k].c_str(), sources[k + 1].c_str(),
                d.mean_relative, d.p99_relative, d.max_relative, to85, to87);
    if (!given) {
      const formats::RglAccuracy h = MeasureRglAccuracy(RglBsdf::FromTensors(formats::MakeRgl(f, half), "half"), f);
      std::printf(" %.2g / %.2g |", h.p99_relative, h.max_relative);
    }
    std::printf("\n");
    std::fflush(stdout);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return Run(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "rgl_accuracy_bench: %s\n", e.what());
    return 2;
  }
}
