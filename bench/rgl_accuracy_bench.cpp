// The RGL writer's reconstruction error (formats::MeasureRglAccuracy, the
// measure of `brdfkit convert`'s sidecar) for lambert and GGX and Beckmann
// lobes: at the default resolution on the measure's grid (theta_i = 1.25 ..
// 78.75 degrees), on the same grid extended towards grazing incidence
// (to 83.75 and 86.25 degrees), and at half the default resolution on every
// axis. Optional arguments: pairs of model and parameters to measure instead.
#include <cstdio>
#include <string>
#include <vector>

#include "brdf/model.h"
#include "brdf/params.h"
#include "brdf/rgl.h"
#include "formats/rgl_writer.h"

int main(int argc, char** argv) {
  using namespace brdfkit;
  using formats::MeasureRglAccuracy;
  std::vector<std::string> sources = {"lambert",  "albedo=0.8", "ggx",      "alpha=0.05", "ggx",      "alpha=0.1",
                                      "ggx",      "alpha=0.2",  "ggx",      "alpha=0.5",  "ggx",      "alpha=1",
                                      "beckmann", "alpha=0.05", "beckmann", "alpha=0.3",  "beckmann", "alpha=0.5",
                                      "beckmann", "alpha=1"};
  if (argc > 1) sources.assign(argv + 1, argv + argc);
  formats::RglOptions half;
  half.theta_i = 40;
  half.ndf = 256;
  half.vndf = 128;
  half.vndf_theta = 64;
  half.samples = 104;
  std::printf("| source | default: mean / p99 / max | max to theta_i 83.75 | max to 86.25 | half: p99 / max |\n");
  std::printf("|---|---|---|---|---|\n");
  for (std::size_t a = 0; a + 1 < sources.size(); a += 2) {
    const Model model = Model::Parse(sources[a]);
    const std::vector<double> p = ParseParams(model.Info(), sources[a + 1]);
    const auto m = model.Make<double>();
    const formats::BrdfFunction f = [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
      return m->Eval(p.data(), wi, wo);
    };
    const RglBsdf file = RglBsdf::FromTensors(formats::MakeRgl(f, {}), "default");
    const formats::RglAccuracy d = MeasureRglAccuracy(file, f);
    const double to85 = MeasureRglAccuracy(file, f, 85).max_relative;
    const double to87 = MeasureRglAccuracy(file, f, 87.5).max_relative;
    const formats::RglAccuracy h = MeasureRglAccuracy(RglBsdf::FromTensors(formats::MakeRgl(f, half), "half"), f);
    std::printf("| `%s` %s | %.2g / %.2g / %.2g | %.2g | %.2g | %.2g / %.2g |\n", sources[a].c_str(),
                sources[a + 1].c_str(), d.mean_relative, d.p99_relative, d.max_relative, to85, to87, h.p99_relative,
                h.max_relative);
    std::fflush(stdout);
  }
}
