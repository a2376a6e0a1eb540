#include "validate/sampling_check.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

#include "brdf/quadrature.h"

namespace brdfkit::validate {

double GammaQ(double a, double x) {
  if (x < 0 || a <= 0) throw std::invalid_argument("GammaQ: need a > 0 and x >= 0");
  if (x == 0) return 1.0;
  const double gln = std::lgamma(a);
  if (x < a + 1) {
    // Series for P(a, x) (Numerical Recipes 6.2.5).
    double ap = a, sum = 1.0 / a, del = sum;
    for (int n = 0; n < 10000; ++n) {
      ap += 1;
      del *= x / ap;
      sum += del;
      if (std::abs(del) < std::abs(sum) * 1e-16) break;
    }
    return 1.0 - sum * std::exp(-x + a * std::log(x) - gln);
  }
  // Continued fraction for Q(a, x) (modified Lentz, Numerical Recipes 6.2.7).
  const double tiny = 1e-300;
  double b = x + 1 - a, c = 1 / tiny, d = 1 / b, h = d;
  for (int i = 1; i < 10000; ++i) {
    const double an = -i * (i - a);
    b += 2;
    d = an * d + b;
    if (std::abs(d) < tiny) d = tiny;
    c = b + an / c;
    if (std::abs(c) < tiny) c = tiny;
    d = 1 / d;
    const double del = d * c;
    h *= del;
    if (std::abs(del - 1) < 1e-16) break;
  }
  return std::exp(-x + a * std::log(x) - gln) * h;
}

double ChiSquareSurvival(double chi2, int dof) {
  if (dof <= 0) return 1.0;
  return GammaQ(0.5 * dof, 0.5 * chi2);
}

SamplingCheckResult CheckSampling(const Bxdf<double>& bxdf, const double* params, const Eigen::Vector3d& wo,
                                  const SamplingCheckOptions& o) {
  SamplingCheckResult r;
  const int nt = o.theta_bins, np = o.phi_bins;
  std::vector<double> expected(static_cast<std::size_t>(nt) * np, 0.0);
  std::vector<double> observed(expected.size(), 0.0);
  const GaussLegendre gl(o.quadrature);
  // A transmitting model scatters over the whole sphere: the bins span
  // cos(theta) in [-1, 1] instead of [0, 1].
  const bool sphere = (bxdf.Kind() & LobeKind::kTransmission) != 0;
  const double c_lo = sphere ? -1.0 : 0.0;

  // Expected probability per bin: integrate the pdf over d(cos theta) d(phi).
  for (int i = 0; i < nt; ++i) {
    const double c0 = c_lo + (1 - c_lo) * i / nt, c1 = c_lo + (1 - c_lo) * (i + 1) / nt;
    for (int j = 0; j < np; ++j) {
      const double p0 = 2 * kPi * j / np, p1 = 2 * kPi * (j + 1) / np;
      double sum = 0;
      for (int a = 0; a < gl.size(); ++a) {
        const double c = c0 + (c1 - c0) * gl.node01(a);
        const double s = std::sqrt(std::max(0.0, 1 - c * c));
        for (int b = 0; b < gl.size(); ++b) {
          const double phi = p0 + (p1 - p0) * gl.node01(b);
          const Eigen::Vector3d wi(s * std::cos(phi), s * std::sin(phi), c);
          sum += gl.weight01(a) * gl.weight01(b) * bxdf.Pdf(params, wo, wi);
        }
      }
      expected[static_cast<std::size_t>(i) * np + j] = sum * (c1 - c0) * (p1 - p0);
    }
  }
  for (double e : expected) r.pdf_integral += e;

  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::int64_t valid = 0;
  for (std::int64_t n = 0; n < o.samples; ++n) {
    const double u1 = uni(rng), u2 = uni(rng);
    const BsdfSample<double> s = bxdf.Sample(params, wo, u1, u2);
    if (!s.valid) continue;
    if (!std::isfinite(s.pdf) || !s.wi.allFinite()) {
      ++r.nonfinite;
      continue;
    }
    const double pdf = bxdf.Pdf(params, wo, s.wi);
    if (std::abs(pdf - s.pdf) > 1e-6 * std::max(pdf, s.pdf)) ++r.pdf_mismatch;
    if (sphere ? s.wi.z() == 0 : s.wi.z() <= 0) continue;
    ++valid;
    const double c = std::clamp(s.wi.z(), c_lo, 1.0);
    double phi = std::atan2(s.wi.y(), s.wi.x());
    if (phi < 0) phi += 2 * kPi;
    const int i = std::min(nt - 1, static_cast<int>((c - c_lo) / (1 - c_lo) * nt));
    const int j = std::min(np - 1, static_cast<int>(phi / (2 * kPi) * np));
    observed[static_cast<std::size_t>(i) * np + j] += 1;
  }
  r.valid_fraction = double(valid) / double(o.samples);

  // Expected counts over all samples drawn (invalid ones fall outside every bin).
  std::vector<std::pair<double, double>> cells;  // (expected, observed)
  for (std::size_t k = 0; k < expected.size(); ++k) cells.emplace_back(expected[k] * o.samples, observed[k]);
  std::sort(cells.begin(), cells.end());
  double pool_e = 0, pool_o = 0;
  int used = 0;
  for (const auto& [e, obs] : cells) {
    if (e < o.min_expected) {
      pool_e += e;
      pool_o += obs;
      continue;
    }
    r.chi2 += (obs - e) * (obs - e) / e;
    ++used;
  }
  if (pool_e > o.min_expected) {
    r.chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
    ++used;
  } else if (pool_o > 0 && pool_e < 1e-12) {
    // Samples where the pdf claims (next to) nothing: certain mismatch.
    r.chi2 = 1e300;
    ++used;
  }
  r.dof = used - 1;
  r.p_value = ChiSquareSurvival(r.chi2, r.dof);
  return r;
}

}  // namespace brdfkit::validate
