// Hemisphere integrators for directional albedo and reference integrals.
//
//   E(wo) = int_{H+} f_r(wi, wo) cos(theta_i) dwi
//
// Methods:
//  - uniform:        Monte Carlo, uniform over the hemisphere (pdf 1 / 2 pi);
//  - cosine:         Monte Carlo, cosine-weighted (pdf cos / pi);
//  - importance:     Monte Carlo with the model's own Sample/Pdf;
//  - sobol:          scrambled Sobol' points (Joe & Kuo 2008 direction numbers,
//                    random digital shift per replicate) through the model's
//                    sampling; the error comes from independent replicates;
//  - gauss_legendre: deterministic product rule in (cos theta, phi);
//  - adaptive:       deterministic, nested globally adaptive Gauss-Kronrod
//                    (7, 15) over the half vector (phi_m, theta_m), with the
//                    horizon as the exact end of every inner range and
//                    breakpoints at multiples of the declared lobe width,
//                    accurate for mirror-like lobes (alpha down to 1e-4) and
//                    grazing wo (mu down to 1e-15); models that declare no
//                    lobe width (Bxdf::Width) are integrated in
//                    (phi, cos theta). The one directional-albedo rule of
//                    brdfkit: check, convergence and the albedo tables
//                    (validate/albedo.h) all call it.
//
// Every estimate carries an honest absolute error: the standard error (times
// a safety factor) for Monte Carlo, the spread of replicates for QMC, the
// difference to a coarser rule for Gauss-Legendre, and the sum of embedded
// Kronrod-Gauss differences (QUADPACK scaling) for the adaptive rule. Monte
// Carlo estimates given a peak they rarely sample add the error such a peak
// can hide (see PeakFloor in integrators.cpp).
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "brdf/core.h"

namespace brdfkit::validate {

enum class Method { kUniform, kCosine, kImportance, kSobol, kGaussLegendre, kAdaptive };

// "uniform", "cosine", "importance", "sobol", "gauss_legendre", "adaptive".
const char* MethodName(Method method);
// Inverse of MethodName; throws std::invalid_argument naming the text.
Method ParseMethod(const std::string& text);
// Every method, in declaration order.
const std::vector<Method>& AllMethods();

struct Estimate {
  Eigen::Array3d value = Eigen::Array3d::Zero();  // per RGB channel
  Eigen::Array3d error = Eigen::Array3d::Zero();  // honest error estimate (absolute)
  std::int64_t evals = 0;                         // BRDF (or integrand) evaluations
  double seconds = 0;                             // wall time
};

// Facts about a model at one parameter point that steer the adaptive rule.
struct LobeShape {
  double width = 1.0;            // angular width of the narrowest glossy lobe in wm, radians (about alpha)
  bool mirror_symmetric = true;  // f(wi, wo) unchanged by reflecting both about the xz plane
};

// Width from the model's declared lobe width (Bxdf::Width; 1 when it has
// no glossy lobe), mirror symmetry tested on fixed direction pairs.
LobeShape EstimateLobeShape(const Bxdf<double>& bxdf, const double* params);

struct IntegrateOptions {
  std::int64_t budget = 4096;   // samples (MC/QMC), nodes (Gauss-Legendre), max evaluations (adaptive)
  std::uint64_t seed = 1;
  double abs_tolerance = 1e-9;  // adaptive: stop when the error estimate is below this (or the budget is spent)
  double rel_tolerance = 1e-9;
  int max_subdivisions = 400;   // adaptive: bisections per one-dimensional integral
  // Adaptive: the lobe facts of this parameter point when already known
  // (tables call the rule many times per point); empty: EstimateLobeShape.
  std::optional<LobeShape> shape;
  // Adaptive, over the microfacet normal m: values of w.m (w the fixed
  // direction) where the integrand has a kink, such as the onset of total
  // internal reflection, where Fresnel's reflectance reaches 1 with an
  // infinite slope. Both levels of the rule get breakpoints there.
  std::vector<double> facet_kinks;
};

// E(wo) = int over the upper hemisphere of f_r(wi, wo) cos(theta_i) dwi.
Estimate DirectionalAlbedo(const Bxdf<double>& bxdf, const double* params, const Eigen::Vector3d& wo,
                           Method method, const IntegrateOptions& options = {});

// Same for an arbitrary integrand g(wi) (already including any cosine), used
// for references such as the weak white furnace or int D cos. `peak` is an
// optional hint: a unit direction where g is sharply peaked (zero vector if
// none) and `width` its angular width in radians (0 if unknown); importance
// methods fall back to cosine sampling for a generic integrand.
// width_y > 0 (with the peak at the normal) makes the peak anisotropic:
// `width` along x and `width_y` along y. A non-zero `cut` declares that g
// vanishes where cut.w <= 0 (as max(0, wo.m) in the weak white furnace); with
// the peak at the normal the adaptive rule then puts that kink on the edges
// of its rectangles instead of refining around it.
Estimate IntegrateHemisphere(const std::function<Eigen::Array3d(const Eigen::Vector3d&)>& g, Method method,
                             const IntegrateOptions& options, const Eigen::Vector3d& peak = Eigen::Vector3d::Zero(),
                             double width = 0, double width_y = 0, const Eigen::Vector3d& cut = Eigen::Vector3d::Zero());

// Power scattered over the sphere from light arriving along w (either side
// of the surface), by the adaptive rule, for a model that transmits
// (LobeKind::kTransmission):
//   reflected   = int over w's side of f(w, v) |v.z| dv: DirectionalAlbedo of
//                 the model with w and v turned to the upper side and its
//                 arguments swapped (the half-vector rule, exact for any f);
//   transmitted = int over the other side: IntegrateHemisphere with the peak
//                 at w refracted through the macro surface (Snell with
//                 Bxdf::RelativeIndex), none past the critical angle.
// Energy conservation is reflected + transmitted <= 1 for every w. For a
// model that does not transmit, transmitted is 0 and reflected is E(w) when
// it is reciprocal.
// `parts` selects what is computed; a part left out is a zero estimate.
struct ScatteredEstimate {
  Estimate reflected, transmitted;
  Estimate Total() const;
};
enum class ScatteredParts { kBoth, kReflected, kTransmitted };
ScatteredEstimate ScatteredPower(const Bxdf<double>& bxdf, const double* params, const Eigen::Vector3d& w,
                                 const IntegrateOptions& options = {}, ScatteredParts parts = ScatteredParts::kBoth);

}  // namespace brdfkit::validate
