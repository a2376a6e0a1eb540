// Sampling consistency of a model's Sample/Pdf: the pdf's integral over the
// upper hemisphere (over the whole sphere for a model whose Kind() has
// LobeKind::kTransmission) against the fraction of valid samples, and a
// chi-square goodness-of-fit test of sampled directions against the pdf on
// equal-area (cos theta, phi) bins, cells with small expected counts pooled (the test
// used by pbrt-v4 and Mitsuba 3).
#pragma once

#include <cstdint>
#include <vector>

#include "brdf/core.h"

namespace brdfkit::validate {

struct SamplingCheckOptions {
  int theta_bins = 20;        // bins in cos(theta), equal solid angle
  int phi_bins = 40;          // bins in phi
  int quadrature = 12;        // Gauss-Legendre points per bin side for the expected counts
  std::int64_t samples = 200000;
  std::uint64_t seed = 1;
  double min_expected = 5.0;  // cells expecting fewer samples are pooled
};

struct SamplingCheckResult {
  double pdf_integral = 0;        // int over the upper hemisphere (sphere: transmitting models) of Pdf(wo, wi) dwi
  double valid_fraction = 0;      // share of samples returned valid
  double chi2 = 0;
  int dof = 0;
  double p_value = 1;             // chance of a chi2 this large if sampling matches the pdf
  std::int64_t pdf_mismatch = 0;  // samples whose returned pdf differs from Pdf() by > 1e-6 relative
  std::int64_t nonfinite = 0;     // samples with a non-finite direction or pdf
};

SamplingCheckResult CheckSampling(const Bxdf<double>& bxdf, const double* params, const Eigen::Vector3d& wo,
                                  const SamplingCheckOptions& options = {});

// Regularised upper incomplete gamma Q(a, x); chi-square survival function
// is Q(dof / 2, chi2 / 2).
double GammaQ(double a, double x);
double ChiSquareSurvival(double chi2, int dof);

}  // namespace brdfkit::validate
