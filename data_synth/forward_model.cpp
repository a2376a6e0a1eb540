#include "data_synth/forward_model.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "brdf/quadrature.h"

namespace brdfkit::synth {

ConeRule MakeConeRule(double radius, int order) {
  if (order < 1) throw std::invalid_argument("aperture quadrature order must be >= 1, got " + std::to_string(order));
  return MakeConeRuleOfDegree(radius, 4 * order - 1);
}

ConeRule MakeConeRuleOfDegree(double radius, int degree) {
  if (!(radius >= 0) || !(radius < kPi / 2))
    throw std::invalid_argument("aperture angular radius must be in [0, 90) degrees");
  if (degree < 3 || degree % 2 == 0)
    throw std::invalid_argument("aperture rule degree must be odd and >= 3, got " + std::to_string(degree));
  ConeRule rule;
  rule.angular_radius = radius;
  rule.degree = degree;
  if (radius == 0) {
    rule.offsets.push_back(Eigen::Vector3d::UnitZ());
    rule.weights.push_back(1.0);
    return rule;
  }
  // Degree k: k + 1 trapezoid nodes in beta, and Gauss-Legendre in u exact
  // to degree (k - 1) / 2 (u ~ rho^2 / 2).
  const int m = degree + 1, n = (degree - 1) / 4 + 1;
  // 1 - cos r written as 2 sin^2(r/2): no cancellation for small apertures.
  const double s = std::sin(radius / 2);
  const double u_max = 2 * s * s;
  const GaussLegendre gl(n), clip(m / 2);
  for (int k = 0; k < clip.size(); ++k) {
    rule.clip_nodes.push_back(clip.node01(k));
    rule.clip_weights.push_back(clip.weight01(k));
  }
  for (int k = 0; k < n; ++k) {
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

namespace {

// The part of a cone above a horizon: node directions and solid-angle
// weights in a frame whose z axis is the horizon's normal; `axis` is the
// cone's axis in that frame. Returns false when the whole cone is above the
// horizon (the rule's own nodes apply). See PlaceCone.
bool ClipCone(const ConeRule& rule, const Eigen::Vector3d& axis, std::vector<Eigen::Vector3d>& dirs,
              std::vector<double>& weights) {
  const double r = rule.angular_radius;
  const double theta_a = std::atan2(std::hypot(axis.x(), axis.y()), axis.z());
  if (theta_a + r <= kPi / 2) return false;
  dirs.clear();
  weights.clear();
  if (theta_a - r >= kPi / 2) return true;  // wholly below the horizon
  const double phi_a = std::atan2(axis.y(), axis.x());
  // theta = theta_a + r sin(psi): the half-width in phi of the cone at theta,
  // which opens as a square root at theta_a - r (and would close as one at
  // theta_a + r, past the horizon), is smooth in psi.
  const double psi_max = std::asin(std::clamp((kPi / 2 - theta_a) / r, -1.0, 1.0));
  const double psi_len = psi_max + kPi / 2;
  const double cos_r = std::cos(r), cos_a = std::cos(theta_a), sin_a = std::sin(theta_a);
  for (std::size_t a = 0; a < rule.clip_nodes.size(); ++a) {
    const double psi = -kPi / 2 + psi_len * rule.clip_nodes[a];
    const double theta = theta_a + r * std::sin(psi);
    const double sin_t = std::sin(theta), cos_t = std::cos(theta);
    // Clamped: rounding at the cone's top and bottom rows; a cone over the pole spans every phi.
    const double half = std::acos(std::clamp((cos_r - cos_t * cos_a) / (sin_t * sin_a), -1.0, 1.0));
    const double w_theta = psi_len * rule.clip_weights[a] * r * std::cos(psi) * sin_t;
    for (std::size_t b = 0; b < rule.clip_nodes.size(); ++b) {
      const double phi = phi_a + half * (2 * rule.clip_nodes[b] - 1);
      dirs.emplace_back(sin_t * std::cos(phi), sin_t * std::sin(phi), cos_t);
      weights.push_back(w_theta * 2 * half * rule.clip_weights[b]);
    }
  }
  return true;
}

}  // namespace

PlacedCone PlaceCone(const ConeRule& rule, const Eigen::Vector3d& actual, const Eigen::Vector3d& nominal,
                     const Eigen::Matrix3d& sample_from_lab) {
  PlacedCone c;
  const bool point = rule.IsPoint();
  const Eigen::Matrix3d fa = ArmFrame(actual), fn = ArmFrame(nominal);
  const Eigen::Matrix3d to_sample = sample_from_lab * fa;
  std::vector<Eigen::Vector3d> clip_dirs;
  std::vector<double> clip_weights;
  // Signal: the cone around the actual arm, cut by the true horizon.
  c.clipped = !point && ClipCone(rule, sample_from_lab * actual, clip_dirs, clip_weights);
  const std::size_t count = c.clipped ? clip_dirs.size() : rule.offsets.size();
  c.directions.reserve(count);
  c.weights.reserve(count);
  for (std::size_t k = 0; k < count; ++k) {
    const Eigen::Vector3d ws = c.clipped ? clip_dirs[k] : Eigen::Vector3d(to_sample * rule.offsets[k]);
    if (!(ws.z() > 0)) continue;  // below the true horizon (a point cone, or rounding on the cut): f_r = 0
    c.directions.push_back(ws);
    c.weights.push_back((c.clipped ? clip_weights[k] : rule.weights[k]) * ws.z());
  }
  // Normalisation: the cone around the nominal arm, cut by the instrument's horizon.
  if (!point && ClipCone(rule, nominal, clip_dirs, clip_weights)) {
    for (std::size_t k = 0; k < clip_dirs.size(); ++k) c.nominal_projected += clip_weights[k] * clip_dirs[k].z();
  } else {
    for (std::size_t k = 0; k < rule.offsets.size(); ++k)
      c.nominal_projected += rule.weights[k] * std::max(0.0, (fn * rule.offsets[k]).z());
  }
  return c;
}

ApertureQuadrature MakeApertureQuadrature(const Instrument& inst, int order) {
  ApertureQuadrature q;
  q.order = order;
  q.source = MakeConeRule(inst.source.kind == Source::Kind::kDisc ? inst.source.angular_radius : 0.0, order);
  q.detector = MakeConeRule(inst.detector.angular_radius, order);
  q.sample_from_lab = inst.sample.SampleFromLab();
  return q;
}

ApertureLadder MakeApertureLadder(const Instrument& inst, int max_source_degree, int max_detector_degree) {
  ApertureLadder l;
  const double rs = inst.source.kind == Source::Kind::kDisc ? inst.source.angular_radius : 0.0;
  const double rd = inst.detector.angular_radius;
  for (int k = 3; k <= (rs > 0 ? max_source_degree : 3); k += 2) l.source.push_back(MakeConeRuleOfDegree(rs, k));
  for (int k = 3; k <= (rd > 0 ? max_detector_degree : 3); k += 2) l.detector.push_back(MakeConeRuleOfDegree(rd, k));
  l.sample_from_lab = inst.sample.SampleFromLab();
  return l;
}

AdaptiveMeasurement MeasureAdaptive(const Bxdf<double>& bxdf, const double* params, const Eigen::Vector3d& actual_i,
                                    const Eigen::Vector3d& nominal_i, const Eigen::Vector3d& actual_o,
                                    const Eigen::Vector3d& nominal_o, const ApertureLadder& ladder, double tolerance) {
  const int ns = static_cast<int>(ladder.source.size()), nd = static_cast<int>(ladder.detector.size());
  if (ns < 1 || nd < 1) throw std::invalid_argument("MeasureAdaptive: empty aperture ladder");
  std::vector<PlacedCone> src(ns), det(nd);
  std::vector<char> src_placed(ns, 0), det_placed(nd, 0);
  const int stride = nd + 1;
  std::vector<Rgb<double>> value((ns + 1) * stride, Rgb<double>::Zero());
  std::vector<char> have(value.size(), 0);
  AdaptiveMeasurement out;

  const auto source_cone = [&](int i) -> const PlacedCone& {
    if (!src_placed[i - 1]) {
      src[i - 1] = PlaceCone(ladder.source[i - 1], actual_i, nominal_i, ladder.sample_from_lab);
      src_placed[i - 1] = 1;
    }
    return src[i - 1];
  };
  const auto detector_cone = [&](int j) -> const PlacedCone& {
    if (!det_placed[j - 1]) {
      det[j - 1] = PlaceCone(ladder.detector[j - 1], actual_o, nominal_o, ladder.sample_from_lab);
      det_placed[j - 1] = 1;
    }
    return det[j - 1];
  };
  // I(i, j): the product of the order-i source rule and the order-j detector rule.
  const auto I = [&](int i, int j) -> const Rgb<double>& {
    const int k = i * stride + j;
    if (!have[k]) {
      const PlacedCone& s = source_cone(i);
      const PlacedCone& d = detector_cone(j);
      const ApertureIntegral<double> a = IntegrateApertures(bxdf, params, s, d);
      out.evaluations += static_cast<long>(s.directions.size() * d.directions.size());
      const double norm = a.Norm();
      // No nominal flux at this order: nothing is measured, f_hat reads 0.
      value[k] = norm > 0 ? Rgb<double>(a.weighted / norm) : Rgb<double>::Zero();
      have[k] = 1;
    }
    return value[k];
  };

  // a, b: levels of the source and detector rules (degree 2 level + 1).
  int a = 1, b = 1;
  // Steps of each cone. A cone at the ladder's top keeps its last step (the
  // error of the level below, an over-estimate for its own); a finite cone
  // with a one-rule ladder has no step at all, so it is never converged.
  Rgb<double> ds = Rgb<double>::Zero(), dd = Rgb<double>::Zero();
  double es_previous = 0, ed_previous = 0;  // each cone's step at its level below
  const bool unverifiable = (ns == 1 && !ladder.source.front().IsPoint()) ||
                            (nd == 1 && !ladder.detector.front().IsPoint());
  for (;;) {
    const Rgb<double> p = I(a, b);
    const bool raise_s = a < ns, raise_d = b < nd;
    if (raise_s) ds = I(a + 1, b) - p;
    if (raise_d) dd = I(a, b + 1) - p;
    // I(a+1, b) + I(a, b+1) - I(a, b): both leading errors removed.
    out.f = p;
    if (raise_s) out.f += ds;
    if (raise_d) out.f += dd;
    const double scale = out.f.abs().maxCoeff();
    const double es = ds.abs().maxCoeff(), ed = dd.abs().maxCoeff();
    out.error = scale > 0 ? (es + ed) / scale : (es + ed > 0 ? 1.0 : 0.0);
    if (es + ed <= tolerance * scale && !unverifiable) {
      out.converged = true;
      break;
    }
    // Raise the cone (or both) whose step exceeds its half of the tolerance.
    const double goal = 0.5 * tolerance * scale;
    const bool up_s = raise_s && es > goal;
    const bool up_d = raise_d && ed > goal;
    if (!up_s && !up_d) break;  // the steps that remain too large are at the ladder's top
    // A cone whose steps shrink too slowly to reach the goal within its
    // ladder stops the pair here: climbing to the top would cost the most
    // evaluations and still miss the tolerance (a lobe narrower than the
    // cone). Predicted from the ratio of its last two steps (geometric
    // convergence).
    const auto hopeless = [&](double step, double previous, int level, int top) {
      if (!(previous > 0) || level < 4) return false;  // no rate yet, or still pre-asymptotic
      const double ratio = step / previous;
      if (!(ratio < 1)) return level >= 6;  // not shrinking: a lobe narrower than this rule resolves
      return level + std::log(goal / step) / std::log(ratio) > top;
    };
    if ((up_s && hopeless(es, es_previous, a, ns)) || (up_d && hopeless(ed, ed_previous, b, nd))) break;
    if (up_s) es_previous = es;
    if (up_d) ed_previous = ed;
    a += up_s;
    b += up_d;
  }
  out.source_level = a;
  out.detector_level = b;
  // Highest levels used: the levels only rise, and each step also reads the next one.
  const int top_s = std::min(a + 1, ns), top_d = std::min(b + 1, nd);
  out.norm = source_cone(top_s).nominal_projected * detector_cone(top_d).nominal_projected;
  out.source_degree = ladder.source.front().IsPoint() ? 0 : ladder.source[top_s - 1].degree;
  out.detector_degree = ladder.detector.front().IsPoint() ? 0 : ladder.detector[top_d - 1].degree;
  return out;
}

}  // namespace brdfkit::synth
