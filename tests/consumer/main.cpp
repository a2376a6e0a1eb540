// Builds against an installed brdfkit::brdf only (no Ceres, OpenCV, OpenEXR)
// and checks one closed form: GGX alpha = 1, F = 1, height-correlated Smith
// at normal incidence, D(n) = 1/pi.
#include <cmath>
#include <cstdio>

#include "brdf/model.h"

int main() {
  using namespace brdfkit;
  const Model m = Model::Parse("ggx");
  const double p[4] = {1.0, 1.0, 1.0, 1.0};
  const auto ggx = m.Make<double>();
  const Eigen::Vector3d n(0, 0, 1);
  const double d = ggx->Microfacet()->D(p, n);
  if (std::abs(d - kInvPi) > 1e-15) {
    std::printf("D(n) = %.17g, expected 1/pi\n", d);
    return 1;
  }
  std::printf("consumer ok: %zu models, D(n) = %.17g\n", RegisteredModelInfos().size(), d);
  return 0;
}
