#include "data_synth/forward_model.h"

#include <stdexcept>
#include <string>

#include "validate/quadrature.h"

namespace brdfkit::synth {

ConeRule MakeConeRule(double radius, int order) {
  if (!(radius >= 0) || !(radius < kPi / 2))
    throw std::invalid_argument("aperture angular radius must be in [0, 90) degrees");
  if (order < 1) throw std::invalid_argument("aperture quadrature order must be >= 1, got " + std::to_string(order));
  ConeRule rule;
  rule.angular_radius = radius;
  if (radius == 0) {
    rule.offsets.push_back(Eigen::Vector3d::UnitZ());
    rule.weights.push_back(1.0);
    return rule;
  }
  // 1 - cos r written as 2 sin^2(r/2): no cancellation for small apertures.
  const double s = std::sin(radius / 2);
  const double u_max = 2 * s * s;
  const validate::GaussLegendre gl(order);
  const int m = 4 * order;
  for (int k = 0; k < order; ++k) {
    const double u = u_max * gl.node01(k);
    const double cos_a = 1 - u;
    const double sin_a = std::sqrt(u * (2 - u));
    const double w = u_max * gl.weight01(k) * 2 * kPi / m;
    for (int j = 0; j < m; ++j) {
      const double beta = 2 * kPi * (j + 0.5) / m;
      rule.offsets.emplace_back(sin_a * std::cos(beta), sin_a * std::sin(beta), cos_a);
      rule.weights.push_back(w);
    }
  }
  return rule;
}

ApertureQuadrature MakeApertureQuadrature(const Instrument& inst, int order) {
  ApertureQuadrature q;
  q.order = order;
  q.source = MakeConeRule(inst.source.kind == Source::Kind::kDisc ? inst.source.angular_radius : 0.0, order);
  q.detector = MakeConeRule(inst.detector.angular_radius, order);
  q.sample_from_lab = inst.sample.SampleFromLab();
  return q;
}

}  // namespace brdfkit::synth
