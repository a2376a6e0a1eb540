#include "data_synth/synth.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "brdf/merl.h"
#include "brdf/params.h"

namespace brdfkit::synth {

namespace {

std::vector<PlannedPair> ReadDirectionList(const std::string& path, bool degrees) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read direction list '" + path + "'");
  std::vector<PlannedPair> out;
  std::string line;
  std::size_t line_no = 0;
  const double scale = degrees ? kPi / 180.0 : 1.0;
  bool first = true;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const auto hash = line.find('#');
    if (hash != std::string::npos) line.erase(hash);
    if (line.find_first_not_of(" \t,") == std::string::npos) continue;
    const bool is_first = first;
    first = false;
    if (is_first && line.find("theta_i") != std::string::npos) continue;  // header line
    for (char& c : line)
      if (c == ',' || c == '\t') c = ' ';
    std::stringstream ss(line);
    std::string tok;
    double v[4];
    int n = 0;
    while (ss >> tok) {
      if (n == 4) throw std::runtime_error(path + ":" + std::to_string(line_no) + ": more than 4 values");
      if (!ParseDouble(tok, v[n]) || !std::isfinite(v[n]))
        throw std::runtime_error(path + ":" + std::to_string(line_no) + ": '" + tok + "' is not a number");
      v[n++] *= scale;
    }
    if (n != 4)
      throw std::runtime_error(path + ":" + std::to_string(line_no) +
                               ": expected 4 values theta_i,phi_i,theta_o,phi_o, got " + std::to_string(n));
    for (int k : {0, 2})
      if (v[k] < 0 || v[k] > kPi / 2)
        throw std::runtime_error(path + ":" + std::to_string(line_no) + ": " + (k == 0 ? "theta_i" : "theta_o") +
                                 " outside [0, 90] degrees");
    out.push_back({v[0], v[1], v[2], v[3]});
  }
  if (out.empty()) throw std::runtime_error(path + ": no directions in the file");
  return out;
}

// A cone that reaches below the true horizon: integrated over its part above
// it (PlaceCone); counted in the report.
bool CrossesHorizon(const Eigen::Vector3d& w, double radius, const Eigen::Matrix3d& r) {
  if (radius == 0) return false;
  const Eigen::Vector3d ws = r * w;
  const double theta = std::atan2(std::hypot(ws.x(), ws.y()), ws.z());
  return theta + radius > kPi / 2;
}

double SourceRadius(const Instrument& inst) {
  return inst.source.kind == Source::Kind::kDisc ? inst.source.angular_radius : 0.0;
}

Rgb<double> NoiselessAt(const Bxdf<double>& bxdf, const double* params, const PlannedPair& p,
                        const ApertureQuadrature& q) {
  return MeasuredBrdf(bxdf, params, DirectionFromAngles(p.theta_i, p.phi_i), DirectionFromAngles(p.theta_o, p.phi_o),
                      q);
}

}  // namespace

ExpandedPlan ExpandPlan(const SamplingPlan& plan) {
  ExpandedPlan e;
  switch (plan.kind) {
    case SamplingPlan::Kind::kFull: {
      const std::size_t ni = plan.theta_i.size() * plan.phi_i.size();
      const std::size_t no = plan.theta_o.size() * plan.phi_o.size();
      e.image_height = static_cast<int>(ni);
      e.image_width = static_cast<int>(no);
      e.image_layout = "rows: (theta_i, phi_i) with phi_i fastest; columns: (theta_o, phi_o) with phi_o fastest";
      for (std::size_t a = 0; a < plan.theta_i.size(); ++a)
        for (std::size_t b = 0; b < plan.phi_i.size(); ++b)
          for (std::size_t c = 0; c < plan.theta_o.size(); ++c)
            for (std::size_t d = 0; d < plan.phi_o.size(); ++d) {
              e.pairs.push_back({plan.theta_i[a], plan.phi_i[b], plan.theta_o[c], plan.phi_o[d]});
              const std::size_t row = a * plan.phi_i.size() + b, col = c * plan.phi_o.size() + d;
              e.pixel.push_back(static_cast<std::int64_t>(row * no + col));
            }
      break;
    }
    case SamplingPlan::Kind::kInPlane: {
      e.image_height = static_cast<int>(plan.theta_i.size());
      e.image_width = static_cast<int>(plan.theta_o.size());
      e.image_layout = "rows: theta_i (phi_i = 0); columns: signed theta_o (>= 0 at phi_o = pi, < 0 at phi_o = 0)";
      for (std::size_t a = 0; a < plan.theta_i.size(); ++a)
        for (std::size_t c = 0; c < plan.theta_o.size(); ++c) {
          const double t = plan.theta_o[c];
          e.pairs.push_back({plan.theta_i[a], 0.0, std::abs(t), t >= 0 ? kPi : 0.0});
          e.pixel.push_back(static_cast<std::int64_t>(a * plan.theta_o.size() + c));
        }
      break;
    }
    case SamplingPlan::Kind::kMerl: {
      const int s0 = plan.merl_stride[0], s1 = plan.merl_stride[1], s2 = plan.merl_stride[2];
      const int nh = (MerlTable::kThetaH + s0 - 1) / s0, nd = (MerlTable::kThetaD + s1 - 1) / s1,
                np = (MerlTable::kPhiD + s2 - 1) / s2;
      e.image_width = nd;
      e.image_height = nh * np;
      e.image_layout =
          "phi_d blocks of theta_h x theta_d slices: row = phi_d_bin * n_theta_h + theta_h_bin, column = theta_d_bin "
          "(bins of the strided MERL grid)";
      e.pairs.reserve(std::size_t(nh) * nd * np);
      for (int i = 0; i < MerlTable::kThetaH; i += s0)
        for (int j = 0; j < MerlTable::kThetaD; j += s1)
          for (int k = 0; k < MerlTable::kPhiD; k += s2) {
            Eigen::Vector3d wi, wo;
            MerlTable::BinDirections(i, j, k, wi, wo);
            auto angles = [](const Eigen::Vector3d& w, double& t, double& p) {
              t = std::atan2(std::hypot(w.x(), w.y()), w.z());
              p = std::atan2(w.y(), w.x());
            };
            PlannedPair pp;
            angles(wi, pp.theta_i, pp.phi_i);
            angles(wo, pp.theta_o, pp.phi_o);
            e.pairs.push_back(pp);
            e.merl_cell.push_back(static_cast<std::int64_t>(MerlTable::Index(i, j, k)));
            e.pixel.push_back(std::int64_t(k / s2) * nh * nd + std::int64_t(i / s0) * nd + j / s1);
          }
      break;
    }
    case SamplingPlan::Kind::kList:
      e.pairs = ReadDirectionList(plan.list_file, plan.list_degrees);
      break;
    case SamplingPlan::Kind::kRandom: {
      SampleRng rng(plan.random_seed, 0);
      e.pairs.reserve(plan.random_count);
      for (std::size_t n = 0; n < plan.random_count; ++n) {
        // Uniform over the hemisphere: cos(theta) uniform in (0, 1].
        const double ci = 1 - rng.Uniform(), pi = 2 * kPi * rng.Uniform();
        const double co = 1 - rng.Uniform(), po = 2 * kPi * rng.Uniform();
        e.pairs.push_back({std::acos(ci), pi, std::acos(co), po});
      }
      break;
    }
  }
  return e;
}

OrderChoice ChooseApertureOrder(const Instrument& inst, const Bxdf<double>& bxdf, const double* params,
                                const ExpandedPlan& plan, std::size_t max_checked) {
  OrderChoice out;
  const double rs = SourceRadius(inst), rd = inst.detector.angular_radius;
  if (rs == 0 && rd == 0) return out;  // point cones: every order is the same single node
  const Eigen::Matrix3d r = inst.sample.SampleFromLab();
  std::vector<std::size_t> eligible;
  for (std::size_t n = 0; n < plan.pairs.size(); ++n) {
    const PlannedPair& p = plan.pairs[n];
    const Eigen::Vector3d wi = DirectionFromAngles(p.theta_i, p.phi_i), wo = DirectionFromAngles(p.theta_o, p.phi_o);
    if (!(wi.z() > 0 && wo.z() > 0)) continue;
    if (CrossesHorizon(wi, rs, r) || CrossesHorizon(wo, rd, r)) ++out.horizon_crossing;
    eligible.push_back(n);
  }
  std::vector<std::size_t> checked;
  const std::size_t step = std::max<std::size_t>(1, (eligible.size() + max_checked - 1) / std::max<std::size_t>(max_checked, 1));
  for (std::size_t k = 0; k < eligible.size(); k += step) checked.push_back(eligible[k]);
  out.checked = checked.size();
  const QuadratureSettings& s = inst.quadrature;
  const auto degree = [](double radius, int d) { return radius > 0 ? d : 0; };
  if (s.order > 0) {
    out.order = s.order;
    out.source_degree = degree(rs, 4 * s.order - 1);
    out.detector_degree = degree(rd, 4 * s.order - 1);
  }
  if (checked.empty()) return out;  // nothing measurable: no error to estimate
  if (s.order == 0) {
    const ApertureLadder ladder = MakeApertureLadder(inst, 4 * s.max_order - 1, 4 * s.max_order - 1);
    std::vector<AdaptiveMeasurement> m(checked.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, checked.size(), 16), [&](const auto& range) {
      for (std::size_t k = range.begin(); k < range.end(); ++k) {
        const PlannedPair& p = plan.pairs[checked[k]];
        const Eigen::Vector3d wi = DirectionFromAngles(p.theta_i, p.phi_i), wo = DirectionFromAngles(p.theta_o, p.phi_o);
        m[k] = MeasureAdaptive(bxdf, params, wi, wi, wo, wo, ladder, s.tolerance);
      }
    });
    // Caps: the degrees 99 % of the checked pairs need. The few pairs that
    // need more (a lobe narrower than the cones, as at grazing specular
    // geometries, where the half vector turns 1 / (2 cos theta) times faster
    // than the arms) would otherwise set the orders of every pair; they stop
    // at the caps, and the measurement counts them with their error.
    std::vector<int> so, dor;
    for (const AdaptiveMeasurement& a : m) {
      so.push_back(a.source_degree);
      dor.push_back(a.detector_degree);
    }
    const std::size_t q = (m.size() * 99 + 99) / 100 - 1;
    std::nth_element(so.begin(), so.begin() + q, so.end());
    std::nth_element(dor.begin(), dor.begin() + q, dor.end());
    out.source_degree = so[q];
    out.detector_degree = dor[q];
    for (const AdaptiveMeasurement& a : m)
      if (a.converged && a.source_degree <= out.source_degree && a.detector_degree <= out.detector_degree)
        out.error = std::max(out.error, a.error);
    out.order = (std::max(out.source_degree, out.detector_degree) + 1 + 3) / 4;
    return out;
  }
  auto values = [&](int order) {
    const ApertureQuadrature q = MakeApertureQuadrature(inst, order);
    std::vector<Rgb<double>> v(checked.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, checked.size(), 16), [&](const auto& range) {
      for (std::size_t k = range.begin(); k < range.end(); ++k)
        v[k] = NoiselessAt(bxdf, params, plan.pairs[checked[k]], q);
    });
    return v;
  };
  double worst = 0;
  const std::vector<Rgb<double>> a = values(s.order), b = values(s.order + 1);
  for (std::size_t k = 0; k < a.size(); ++k) {
    const double scale = b[k].abs().maxCoeff();
    if (!(scale > 0)) continue;  // black in every channel at both orders: nothing to compare
    worst = std::max(worst, (a[k] - b[k]).abs().maxCoeff() / scale);
  }
  out.error = worst;
  return out;
}

SynthResult Synthesize(const Instrument& inst, const Model& model, const std::vector<double>& params,
                       std::uint64_t seed, const SynthProgress& progress) {
  return Synthesize(inst, model, params, seed, ExpandPlan(inst.plan), progress);
}

SynthResult Synthesize(const Instrument& inst, const Model& model, const std::vector<double>& params,
                       std::uint64_t seed, ExpandedPlan plan, const SynthProgress& progress) {
  return Synthesize(inst, *model.Make<double>(), params, seed, std::move(plan), progress);
}

SynthResult Synthesize(const Instrument& inst, const Bxdf<double>& model, const std::vector<double>& params,
                       std::uint64_t seed, ExpandedPlan plan, const SynthProgress& progress) {
  const auto start = std::chrono::steady_clock::now();
  ValidateParams(model.Info(), params);
  SynthResult result;
  result.plan = std::move(plan);
  const Bxdf<double>* const bxdf = &model;

  const OrderChoice choice = ChooseApertureOrder(inst, *bxdf, params.data(), result.plan);
  result.report.order = choice.order;
  result.report.quadrature_error = choice.error;
  result.report.checked_pairs = choice.checked;
  result.report.horizon_crossing = choice.horizon_crossing;

  // Automatic order: every pair raises each cone's rule on its own
  // (MeasureAdaptive) up to the degrees the checked pairs needed. A fixed
  // order from the settings is the product rule of that order.
  const bool adaptive = inst.quadrature.order == 0 && (choice.source_degree > 0 || choice.detector_degree > 0);
  const ApertureLadder ladder =
      MakeApertureLadder(inst, std::max(3, choice.source_degree), std::max(3, choice.detector_degree));
  const ApertureQuadrature q = MakeApertureQuadrature(inst, choice.order);
  result.report.source_degree = choice.source_degree;
  result.report.detector_degree = choice.detector_degree;
  std::vector<long> pair_evaluations(adaptive ? result.plan.pairs.size() : 0, 0);
  std::vector<double> pair_error(pair_evaluations.size(), 0.0);
  std::vector<char> pair_converged(pair_evaluations.size(), 0);
  const Imperfections& m = inst.imperfections;
  const SensorModel sensor(m, inst.detector.exposure_time);
  const bool noisy = m.AnyNoise();
  result.noisy = noisy;
  // Photo-electron rate per unit of aperture integral: responsivity times
  // source radiance (or beam irradiance) times sample area.
  const Eigen::Array3d rate_scale = inst.detector.responsivity * inst.source.RadianceScale() * inst.sample.area;

  const std::size_t count = result.plan.pairs.size();
  result.samples.assign(count, SynthSample{});
  std::atomic<std::size_t> pairs_done{0};
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 256), [&](const auto& range) {
    if (progress) progress(pairs_done.fetch_add(range.size()), count);
    for (std::size_t n = range.begin(); n < range.end(); ++n) {
      const PlannedPair& p = result.plan.pairs[n];
      const Eigen::Vector3d wi = DirectionFromAngles(p.theta_i, p.phi_i);
      const Eigen::Vector3d wo = DirectionFromAngles(p.theta_o, p.phi_o);
      SynthSample& out = result.samples[n];
      if (!(wi.z() > 0 && wo.z() > 0)) continue;  // the instrument cannot reach this geometry
      SampleRng rng(seed, n);
      const Eigen::Vector3d ai = JitterDirection(wi, m.jitter_source, rng);
      const Eigen::Vector3d ao = JitterDirection(wo, m.jitter_detector, rng);
      Rgb<double> weighted;
      double norm;
      if (adaptive) {
        const AdaptiveMeasurement a =
            MeasureAdaptive(*bxdf, params.data(), ai, wi, ao, wo, ladder, inst.quadrature.tolerance);
        pair_error[n] = a.error;
        pair_evaluations[n] = a.evaluations;
        pair_converged[n] = a.converged;
        norm = a.norm;
        weighted = a.f * norm;
      } else {
        const PlacedCone src = PlaceCone(q.source, ai, wi, q.sample_from_lab);
        const PlacedCone det = PlaceCone(q.detector, ao, wo, q.sample_from_lab);
        const ApertureIntegral<double> a = IntegrateApertures(*bxdf, params.data(), src, det);
        norm = a.Norm();
        weighted = a.weighted;
      }
      if (!(norm > 0)) continue;  // no nominal flux reaches the detector
      out.valid = true;
      const double drift = 1 + m.drift_per_sample * double(n);
      if (!noisy) {
        out.f = weighted * drift / norm;
        continue;
      }
      for (int c = 0; c < 3; ++c) {
        const double scale = rate_scale[c] * norm;
        const RateEstimate e = sensor.Measure(rate_scale[c] * weighted[c] * drift, rng);
        out.f[c] = e.rate / scale;
        out.sigma[c] = std::sqrt(e.variance) / scale;
        out.saturated = out.saturated || e.saturated;
      }
    }
  });
  if (adaptive) {
    double evaluation_sum = 0;
    std::size_t counted = 0;
    for (std::size_t n = 0; n < pair_evaluations.size(); ++n) {
      if (pair_evaluations[n] == 0) continue;  // not measured
      evaluation_sum += double(pair_evaluations[n]);
      ++counted;
      if (!pair_converged[n]) {
        ++result.report.pairs_at_max_order;
        result.report.max_order_error = std::max(result.report.max_order_error, pair_error[n]);
      } else {
        result.report.pair_error = std::max(result.report.pair_error, pair_error[n]);
      }
    }
    result.report.mean_evaluations = counted ? evaluation_sum / double(counted) : 0.0;
  }
  for (const SynthSample& s : result.samples) {
    if (s.valid) ++result.report.measured;
    else ++result.report.not_measured;
    if (s.saturated) ++result.report.saturated;
  }
  result.report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

}  // namespace brdfkit::synth
