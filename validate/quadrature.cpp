#include "validate/quadrature.h"

#include <cmath>
#include <stdexcept>

namespace brdfkit::validate {

GaussLegendre::GaussLegendre(int n) : x_(n), w_(n) {
  if (n < 1) throw std::invalid_argument("GaussLegendre: need at least one node");
  const double pi = 3.14159265358979323846;
  for (int i = 0; i < (n + 1) / 2; ++i) {
    double z = std::cos(pi * (i + 0.75) / (n + 0.5));  // Tricomi's initial guess
    double pp = 1;
    for (int it = 0; it < 100; ++it) {
      double p1 = 1, p2 = 0;
      for (int j = 0; j < n; ++j) {
        const double p3 = p2;
        p2 = p1;
        p1 = ((2.0 * j + 1.0) * z * p2 - j * p3) / (j + 1);
      }
      pp = n * (z * p1 - p2) / (z * z - 1.0);
      const double dz = p1 / pp;
      z -= dz;
      if (std::abs(dz) < 1e-16) break;
    }
    x_[i] = -z;
    x_[n - 1 - i] = z;
    w_[i] = w_[n - 1 - i] = 2.0 / ((1.0 - z * z) * pp * pp);
  }
}

}  // namespace brdfkit::validate
