// Helpers shared by the tests: random directions and parameters, and an
// independent deterministic hemisphere quadrature.
#pragma once

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>
#include <vector>

#include "brdf/model.h"
#include "brdf/quadrature.h"

namespace brdfkit::test {

inline Eigen::Vector3d DirectionFromAngles(double theta, double phi) {
  return Eigen::Vector3d(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
}

inline Eigen::Vector3d RandomUpperDirection(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0, 1);
  const double z = u(rng), phi = 2 * kPi * u(rng), s = std::sqrt(std::max(0.0, 1 - z * z));
  return Eigen::Vector3d(s * std::cos(phi), s * std::sin(phi), z);
}

// Random parameters strictly inside the bounds (log-uniform on log-scale
// parameters), so finite differences stay in range.
inline std::vector<double> RandomParams(const ModelInfo& info, std::mt19937_64& rng, double margin = 0.05) {
  std::uniform_real_distribution<double> u(margin, 1 - margin);
  std::vector<double> p;
  for (const ParamInfo& q : info.params) {
    for (int c = 0; c < (q.colour ? 3 : 1); ++c) {
      double v;
      if (q.scale == ParamInfo::Scale::kLog && q.lower > 0)
        v = q.lower * std::pow(q.upper / q.lower, u(rng));
      else
        v = q.lower + (q.upper - q.lower) * u(rng);
      p.push_back(v);
    }
  }
  return p;
}

// int over the upper hemisphere of g(w) dw by a composite Gauss-Legendre rule
// in theta, graded geometrically towards the normal (to resolve lobes down to
// about 1e-4 rad wide there), times Gauss-Legendre in phi.
// With `clip`, only the part where w.clip > 0 is integrated, arc by arc, so a
// factor max(0, w.clip) leaves no kink inside the rule.
inline double HemisphereIntegral(const std::function<double(const Eigen::Vector3d&)>& g, int theta_nodes = 24,
                                 int phi_nodes = 96, double theta_min = 1e-5,
                                 const Eigen::Vector3d& clip = Eigen::Vector3d::Zero()) {
  const GaussLegendre gt(theta_nodes), gp(phi_nodes);
  std::vector<double> breaks = {0.0};
  for (double t = theta_min; t < kPi / 2; t *= 2) breaks.push_back(t);
  breaks.push_back(kPi / 2);
  if (clip.squaredNorm() > 0) {
    // Where the rings start to be clipped the arc length has a square-root
    // singularity in theta: grade the breaks towards it from both sides.
    const double tc = kPi / 2 - std::acos(std::min(1.0, std::abs(clip.z()) / clip.norm()));
    for (double d = 0.25; d > 1e-9; d *= 0.5) {
      if (tc - d > 0) breaks.push_back(tc - d);
      if (tc + d < kPi / 2) breaks.push_back(tc + d);
    }
    if (tc > 0 && tc < kPi / 2) breaks.push_back(tc);
    std::sort(breaks.begin(), breaks.end());
  }
  double sum = 0;
  for (std::size_t k = 0; k + 1 < breaks.size(); ++k) {
    const double a = breaks[k], b = breaks[k + 1];
    for (int i = 0; i < gt.size(); ++i) {
      const double theta = a + (b - a) * gt.node01(i);
      const double wt = (b - a) * gt.weight01(i) * std::sin(theta);
      double phi0 = 0, phi1 = 2 * kPi;
      const double rho = std::hypot(clip.x(), clip.y());
      if (clip.squaredNorm() > 0) {
        // w.clip > 0  <=>  rho sin(theta) cos(phi - phi_c) > -clip.z cos(theta)
        const double st = rho * std::sin(theta), rhs = -clip.z() * std::cos(theta);
        if (st <= std::abs(rhs)) {
          if (rhs >= 0) continue;  // the whole ring is clipped away
        } else {
          const double phi_c = std::atan2(clip.y(), clip.x()), half = std::acos(rhs / st);
          phi0 = phi_c - half;
          phi1 = phi_c + half;
        }
      }
      for (int j = 0; j < gp.size(); ++j) {
        const double phi = phi0 + (phi1 - phi0) * gp.node01(j);
        sum += wt * (phi1 - phi0) * gp.weight01(j) * g(DirectionFromAngles(theta, phi));
      }
    }
  }
  return sum;
}

// Directional albedo of GGX with alpha = 1, height-correlated Smith and
// F = 1, in closed form: E(mu) = 1 - mu ln(1 + 1 / mu), which tends to 1 at
// mu = 0 (the formula itself is 0 * inf there).
inline double GgxAlbedoAlpha1(double mu) { return mu == 0 ? 1.0 : 1 - mu * std::log1p(1 / mu); }

}  // namespace brdfkit::test
