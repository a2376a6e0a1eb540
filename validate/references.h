// Hemisphere integrals with known exact values, used to test the
// integrators and by `brdfkit convergence`:
//  - Lambert: E = rho per channel (Lambert 1760);
//  - GGX, F = 1, height-correlated Smith, alpha = 1: E(mu) = 1 - mu ln(1 + 1/mu);
//    with separable Smith: E(mu) = 2 (1 - ln 2) / (1 + mu) (D = 1/pi at alpha 1);
//  - weak white furnace (Heitz 2014, "Understanding the Masking-Shadowing
//    Function", eq. 24): int D(m) G1(wo, m) max(0, wo.m) / cos(theta_o) dm = 1,
//    GGX and Beckmann, isotropic and anisotropic;
//  - projected-area normalisation int D(m) cos(theta_m) dm = 1 (Heitz 2014 eq. 4);
//  - cos^n lobes: int_H (n + 1)/(2 pi) cos^n(theta) dw = 1, and the albedo of
//    Phong's original lobe, ks 2 pi / (n + 1) while the lobe is clear of the
//    horizon (Phong 1975);
//  - Fujii's Oren-Nayar (Fujii 2012): E(1) = pi A and
//    E_avg = 2 int E(mu) mu dmu = pi A + (2 pi - 5.6) / 3 B.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "validate/integrators.h"

namespace brdfkit::validate {

struct ReferenceCase {
  std::string name;     // unique, e.g. "ggx_alpha1_mu0.1"
  std::string group;    // family, e.g. "ggx_alpha1"
  Eigen::Array3d exact = Eigen::Array3d::Zero();
  // Narrow lobe (width below 1e-2) or grazing view (mu below 1e-2): only the
  // adaptive rule is expected to be accurate at modest budgets.
  bool stiff = false;
  std::function<Estimate(Method, const IntegrateOptions&)> integrate;
};

// All reference integrals. Model-based cases need their model registered;
// throws ModelError naming it otherwise.
std::vector<ReferenceCase> ReferenceCases();

// Absolute error of an estimate against the exact value (largest channel),
// and the estimate's own error (largest channel).
double TrueError(const ReferenceCase& c, const Estimate& e);
double EstimatedError(const Estimate& e);

}  // namespace brdfkit::validate
