#include "validate/check.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>

#include "brdf/params.h"
#include "validate/integrators.h"
#include "validate/sampling_check.h"

namespace brdfkit::validate {

namespace {

using Eigen::Array3d;
using Eigen::Vector3d;

Vector3d Spherical(double theta, double phi) {
  return Vector3d(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
}

Vector3d FromMu(double mu, double phi) {
  const double s = std::sqrt(std::max(0.0, (1 - mu) * (1 + mu)));
  return Vector3d(s * std::cos(phi), s * std::sin(phi), mu);
}

std::string Dir(const Vector3d& w) {
  const double theta = std::acos(std::clamp(w.z(), -1.0, 1.0)) * 180 / kPi;
  const double phi = std::atan2(w.y(), w.x()) * 180 / kPi;
  return "(theta " + FormatShort(theta) + " deg, phi " + FormatShort(phi) + " deg)";
}

// Structured pairs of the reciprocity test, plus random ones.
std::vector<std::pair<Vector3d, Vector3d>> ReciprocityPairs(int random_pairs, std::uint64_t seed) {
  std::vector<std::pair<Vector3d, Vector3d>> pairs;
  const double grazing = kPi / 2 - 1e-6;  // 1e-6 rad above the horizon
  const std::vector<double> thetas = {0.0, 0.1, 0.4, 0.7, 1.0, 1.2, 1.4, 1.5, 1.55, 1.5697, grazing};
  const std::vector<double> phis = {0.0, 0.5, 1.3, kPi / 2, 2.2, 3.0, kPi, 4.0, 5.5};
  const Vector3d normal = Vector3d::UnitZ();
  for (double t : thetas)
    for (double p : phis) {
      const Vector3d w = Spherical(t, p);
      pairs.emplace_back(normal, w);                                  // normal against everything
      pairs.emplace_back(Spherical(grazing, p + 0.7), w);             // grazing against everything
      pairs.emplace_back(Reflect(w), w);                              // mirror
      pairs.emplace_back(Spherical(std::min(t + 1e-3, grazing), p + 1e-3), w);  // near retro-reflection
      pairs.emplace_back(w, w);                                       // wi = wo
    }
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (int i = 0; i < random_pairs; ++i) {
    const double a = uni(rng), b = uni(rng), c = uni(rng), d = uni(rng);
    // Uniform over the hemisphere: cos(theta) uniform; 1 - u keeps it > 0.
    pairs.emplace_back(FromMu(1 - a, 2 * kPi * b), FromMu(1 - c, 2 * kPi * d));
  }
  return pairs;
}

bool RotationInvariant(const Bxdf<double>& bxdf, const double* p) {
  for (int k = 0; k < 16; ++k) {
    const Vector3d wi = Spherical(0.1 + 0.09 * k, 0.37 * k), wo = Spherical(1.4 - 0.08 * k, 2.0 + 0.51 * k);
    const double g = 0.3 + 0.35 * k;
    const Eigen::Matrix3d r = Eigen::AngleAxisd(g, Vector3d::UnitZ()).toRotationMatrix();
    const Array3d a = bxdf.Eval(p, wi, wo), b = bxdf.Eval(p, r * wi, r * wo);
    const double scale = std::max(a.abs().maxCoeff(), b.abs().maxCoeff());
    if ((a - b).abs().maxCoeff() > 1e-9 * scale) return false;
  }
  return true;
}

}  // namespace

CheckResult CheckPlausibility(const Bxdf<double>& bxdf, const double* p, const CheckOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  CheckResult r;

  // A transmitting model scatters over the whole sphere: its pairs, light
  // directions and sampled directions take both sides, and reciprocity is
  // the generalised one, f(wi, wo) eta_r^2 = f(wo, wi), eta_r = RelativeIndex.
  const bool sphere = (bxdf.Kind() & LobeKind::kTransmission) != 0;

  // --- reciprocity and values ---
  r.min_value = std::numeric_limits<double>::infinity();
  std::vector<std::pair<Vector3d, Vector3d>> pairs = ReciprocityPairs(o.random_pairs, o.seed);
  if (sphere) {
    const auto below = [](Vector3d w) {
      w.z() = -w.z();
      return w;
    };
    const std::size_t n = pairs.size();
    for (std::size_t k = 0; k < n; ++k) {
      const auto [wi, wo] = pairs[k];
      pairs.emplace_back(below(wi), wo);
      pairs.emplace_back(wi, below(wo));
      pairs.emplace_back(below(wi), below(wo));
    }
  }
  // Both orders of every pair in two EvalBatch calls.
  std::vector<double> first(3 * pairs.size()), second(3 * pairs.size()), forward(3 * pairs.size()),
      backward(3 * pairs.size());
  for (std::size_t k = 0; k < pairs.size(); ++k)
    for (int c = 0; c < 3; ++c) first[3 * k + c] = pairs[k].first[c], second[3 * k + c] = pairs[k].second[c];
  bxdf.EvalBatch(p, first.data(), 3, second.data(), 3, pairs.size(), forward.data());
  bxdf.EvalBatch(p, second.data(), 3, first.data(), 3, pairs.size(), backward.data());
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const auto& [wi, wo] = pairs[k];
    const double eta_r = sphere ? bxdf.RelativeIndex(p, wi, wo) : 1.0;
    const Array3d a = Array3d::Map(forward.data() + 3 * k) * (eta_r * eta_r), b = Array3d::Map(backward.data() + 3 * k);
    ++r.pairs_checked;
    bool finite = true;
    for (int c = 0; c < 3; ++c)
      for (double v : {a[c], b[c]}) {
        ++r.values_checked;
        if (!std::isfinite(v)) {
          ++r.nonfinite_count;
          finite = false;
        } else {
          r.min_value = std::min(r.min_value, v);
        }
      }
    if (!finite) continue;
    const double scale = std::max(a.abs().maxCoeff(), b.abs().maxCoeff());
    // Values in the subnormal range carry no relative precision.
    if (!(scale > 1e-290)) continue;
    const double rel = (a - b).abs().maxCoeff() / scale;
    if (rel > r.reciprocity_max_rel_error) {
      r.reciprocity_max_rel_error = rel;
      r.reciprocity_worst_wi = wi;
      r.reciprocity_worst_wo = wo;
    }
  }
  if (!std::isfinite(r.min_value)) r.min_value = 0;
  if (r.reciprocity_max_rel_error > o.reciprocity_tolerance)
    r.reasons.push_back("reciprocity: relative asymmetry " + FormatShort(r.reciprocity_max_rel_error) + " > " +
                        FormatShort(o.reciprocity_tolerance) + " at wi " + Dir(r.reciprocity_worst_wi) + ", wo " +
                        Dir(r.reciprocity_worst_wo));
  if (r.nonfinite_count > 0)
    r.reasons.push_back("values: " + std::to_string(r.nonfinite_count) + " of " + std::to_string(r.values_checked) +
                        " evaluated values are not finite");
  if (r.min_value < 0) r.reasons.push_back("values: negative f_r (min " + FormatShort(r.min_value) + ")");

  // --- energy conservation: search for the largest directional albedo ---
  r.rotation_invariant = RotationInvariant(bxdf, p);
  IntegrateOptions io;
  io.budget = o.albedo_budget;
  io.abs_tolerance = 1e-8;
  io.rel_tolerance = 1e-9;
  // mu < 0: the direction below the surface (transmitting models). The
  // albedo is the power scattered from light arriving along the direction
  // (ScatteredPower): over the sphere for a transmitting model, over the
  // hemisphere for a non-reciprocal one (a measured table, Phong's
  // original); for a reciprocal reflection model that is E(wo).
  const bool light_side = sphere || !bxdf.Info().reciprocal;
  struct Sample {
    double mu, phi, value, error;
    Array3d channels;
    bool tightened = false;  // integrated again with the larger budget
  };
  const auto directional = [&](double mu, double phi, const IntegrateOptions& opt) {
    if (light_side) return ScatteredPower(bxdf, p, FromMu(mu, phi), opt).Total();
    return DirectionalAlbedo(bxdf, p, FromMu(mu, phi), Method::kAdaptive, opt);
  };
  const auto albedo = [&](double mu, double phi) {
    const Estimate e = directional(mu, phi, io);
    ++r.albedo_evaluations;
    r.albedo_integrand_evals += e.evals;
    int c;
    const double v = e.value.maxCoeff(&c);
    return Sample{mu, phi, std::isfinite(v) ? v : std::numeric_limits<double>::infinity(), e.error[c], e.value};
  };
  const std::vector<double> mus = {1.0, 0.85, 0.7, 0.5, 0.3, 0.15, 0.05, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7};
  std::vector<double> phis = {0.0};
  if (!r.rotation_invariant)
    for (int k = 1; k < 8; ++k) phis.push_back(k * kPi / 8);
  Sample best{1, 0, -std::numeric_limits<double>::infinity(), 0, Array3d::Zero()};
  std::size_t best_i = 0;
  double best_phi = 0, best_side = 1;
  r.albedo_max_per_channel = Array3d::Constant(-std::numeric_limits<double>::infinity());
  std::vector<Sample> searched;  // every albedo evaluated, for the verdict
  const auto take = [&](const Sample& s) {
    r.albedo_max_per_channel = r.albedo_max_per_channel.max(s.channels);
    if (s.value > best.value) best = s;
    searched.push_back(s);
  };
  for (double side : sphere ? std::vector<double>{1.0, -1.0} : std::vector<double>{1.0})
      for (double phi : phis)
      for (std::size_t i = 0; i < mus.size(); ++i) {
        const Sample s = albedo(side * mus[i], phi);
        if (s.value > best.value) {
          best_i = i;
          best_phi = phi;
          best_side = side;
        }
        take(s);
        if (i == 0) r.albedo_at_normal = std::max(r.albedo_at_normal, s.value);
        if (i + 1 == mus.size()) r.albedo_at_grazing = std::max(r.albedo_at_grazing, s.value);
      }
  // Golden-section refinement in log(mu) between the grid neighbours of the
  // best node, then in phi for models that are not rotation invariant.
  const double golden = 0.5 * (std::sqrt(5.0) - 1);
  // Golden-section search for the maximum of at(x) on [lo, hi]; every
  // evaluated point is offered to take().
  const auto golden_max = [&](double lo, double hi, int steps, double min_width, const auto& at) {
    double x1 = hi - golden * (hi - lo), x2 = lo + golden * (hi - lo);
    Sample s1 = at(x1), s2 = at(x2);
    take(s1);
    take(s2);
    for (int it = 0; it < steps && hi - lo > min_width; ++it) {
      if (s1.value > s2.value) {
        hi = x2;
        x2 = x1;
        s2 = s1;
        x1 = hi - golden * (hi - lo);
        s1 = at(x1);
        take(s1);
      } else {
        lo = x1;
        x1 = x2;
        s1 = s2;
        x2 = lo + golden * (hi - lo);
        s2 = at(x2);
        take(s2);
      }
    }
  };
  golden_max(std::log(mus[std::min(best_i + 1, mus.size() - 1)]), std::log(mus[best_i > 0 ? best_i - 1 : 0]),
             o.golden_steps, 1e-6, [&](double x) { return albedo(best_side * std::exp(x), best_phi); });
  if (!r.rotation_invariant) {
    const double mu = best.mu;
    golden_max(best.phi - kPi / 8, best.phi + kPi / 8, o.golden_steps / 2, 0.0,
               [&](double x) { return albedo(mu, x); });
  }
  // Verdict: a pass needs every albedo's error bar below 1 + slack, a fail
  // one albedo whose error bar lies wholly above it. Albedos whose bar
  // straddles the bound are integrated again with a larger budget first;
  // what still straddles it leaves the property inconclusive.
  const double bound = 1 + o.albedo_slack;
  const auto above = [&](const Sample& s) { return !(s.value - s.error <= bound); };  // NaN counts as above
  const auto straddles = [&](const Sample& s) { return !above(s) && s.value + s.error > bound; };
  if (std::none_of(searched.begin(), searched.end(), above)) {
    std::vector<Sample*> open;
    for (Sample& s : searched)
      if (straddles(s)) open.push_back(&s);
    std::sort(open.begin(), open.end(), [](const Sample* a, const Sample* b) { return a->value + a->error > b->value + b->error; });
    if (open.size() > std::size_t(o.tighten_points)) open.resize(std::size_t(o.tighten_points));
    IntegrateOptions tight = io;
    tight.budget = io.budget * o.tighten_factor;
    for (Sample* s : open) {
      const Estimate e = directional(s->mu, s->phi, tight);
      ++r.albedo_evaluations;
      r.albedo_integrand_evals += e.evals;
      ++r.albedo_tightened;
      int c;
      const double v = e.value.maxCoeff(&c);
      *s = Sample{s->mu, s->phi, std::isfinite(v) ? v : std::numeric_limits<double>::infinity(), e.error[c], e.value,
                  true};
    }
  }
  best = searched.front();
  for (const Sample& s : searched)
    if (s.value > best.value) best = s;
  const Sample* worst_open = nullptr;
  for (const Sample& s : searched)
    if (straddles(s) && (!worst_open || s.value + s.error > worst_open->value + worst_open->error)) worst_open = &s;
  r.albedo_max = best.value;
  r.albedo_max_error = best.error;
  r.albedo_max_at_mu = best.mu;
  r.albedo_max_at_phi = best.phi;
  const auto at = [&](const Sample& s) {
    return "mu = " + FormatShort(s.mu) +
           (r.rotation_invariant ? "" : ", phi = " + FormatShort(s.phi * 180 / kPi) + " deg");
  };
  // The highest albedo among those wholly above the bound.
  auto hit = searched.end();
  for (auto it = searched.begin(); it != searched.end(); ++it)
    if (above(*it) && (hit == searched.end() || !(it->value <= hit->value))) hit = it;
  if (hit != searched.end())
    r.reasons.push_back("energy: directional albedo " + FormatShort(hit->value) + " > 1 at " + at(*hit) +
                        " (error estimate " + FormatShort(hit->error) + ")");
  else if (worst_open)
    r.inconclusive.push_back(
        "energy: directional albedo " + FormatShort(worst_open->value) + " +- " + FormatShort(worst_open->error) +
        " at " + at(*worst_open) + ": the error bar reaches past 1" +
        (worst_open->tightened
             ? ", also with a budget of " + std::to_string(io.budget * o.tighten_factor) + " evaluations"
             : " (only the " + std::to_string(o.tighten_points) + " highest error bars are integrated again)"));

  // --- sampling consistency ---
  // The chi-square bins (20 x 40 over the hemisphere, 6 x 6 Gauss points
  // each) cannot resolve the pdf of a lobe much narrower than a bin.
  const double lobe_width = bxdf.Width(p).Min();
  if (o.sampling && !bxdf.CanSample())
    r.sampling_note = "not checked: the model provides no Sample/Pdf";
  else if (o.sampling && lobe_width > 0 && lobe_width < kMinSampledLobeWidth)
    r.sampling_note =
        "not checked: lobe width " + FormatShort(lobe_width) + " rad is below the chi-square bins' resolution";
  if (o.sampling && r.sampling_note.empty()) {
    r.sampling_checked = true;
    std::vector<Vector3d> wos;
    for (double deg : {0.0, 30.0, 60.0, 80.0}) wos.push_back(Spherical(deg * kPi / 180, 0.0));
    if (!r.rotation_invariant)
      for (double deg : {30.0, 80.0}) wos.push_back(Spherical(deg * kPi / 180, 1.0));
    if (sphere)
      for (std::size_t k = 0, n = wos.size(); k < n; ++k) wos.push_back(Vector3d(wos[k].x(), wos[k].y(), -wos[k].z()));
    SamplingCheckOptions so;
    so.samples = o.sampling_samples;
    so.seed = o.seed;
    double worst_gap = -1;
    bool pdf_bad = false;
    std::string pdf_note;
    for (const Vector3d& wo : wos) {
      const SamplingCheckResult s = CheckSampling(bxdf, p, wo, so);
      ++r.sampling_directions;
      r.chi2_min_p = std::min(r.chi2_min_p, s.p_value);
      r.pdf_mismatch += s.pdf_mismatch;
      const double vf = s.valid_fraction;
      const double se = std::sqrt(std::max(vf * (1 - vf), 0.0) / double(std::max<std::int64_t>(so.samples, 1)));
      const double gap = std::abs(s.pdf_integral - vf);
      if (gap > worst_gap) {
        worst_gap = gap;
        r.pdf_integral = s.pdf_integral;
        r.valid_fraction = vf;
      }
      if (!std::isfinite(s.pdf_integral) || gap > 5 * se + 2e-3 || s.pdf_integral > 1 + 2e-3 || s.nonfinite > 0) {
        if (!pdf_bad)
          pdf_note = "sampling: pdf integral " + FormatShort(s.pdf_integral) + " vs valid sample fraction " +
                     FormatShort(vf) + " at wo " + Dir(wo) + (s.nonfinite > 0 ? ", non-finite samples" : "");
        pdf_bad = true;
      }
    }
    const int m = r.sampling_directions;
    // Sidak: P(min of m independent p-values <= p) = 1 - (1 - p)^m.
    r.chi2_p_value = 1 - std::pow(1 - r.chi2_min_p, m);
    if (pdf_bad) r.reasons.push_back(pdf_note);
    if (r.chi2_p_value < o.significance)
      r.reasons.push_back("sampling: chi-square p-value " + FormatShort(r.chi2_p_value) + " (Sidak over " +
                          std::to_string(m) + " directions) < " + FormatShort(o.significance));
  }

  // --- microfacet normalisation ---
  if (const MicrofacetView<double>* mf = bxdf.Microfacet()) {
    r.microfacet = true;
    const double width = std::max(bxdf.Width(p).Min(), 1e-7);
    IntegrateOptions mo = io;
    mo.abs_tolerance = 1e-9;
    const Estimate dn = IntegrateHemisphere(
        [&](const Vector3d& m) { return Array3d::Constant(mf->D(p, m) * m.z()); }, Method::kAdaptive, mo,
        Vector3d::UnitZ(), width);
    r.d_normalisation = dn.value[0];
    r.d_normalisation_error = dn.error[0];
    if (!(std::abs(r.d_normalisation - 1) <= r.d_normalisation_error + o.normalisation_tolerance))
      r.reasons.push_back("microfacet: int D cos = " + FormatShort(r.d_normalisation) + " != 1");
    r.has_smith_g1 = mf->HasSmithG1();
    if (r.has_smith_g1) {
      r.furnace_min = std::numeric_limits<double>::infinity();
      r.furnace_max = -std::numeric_limits<double>::infinity();
      std::vector<Vector3d> wos;
      for (double deg : {0.0, 45.0, 80.0, 89.0}) wos.push_back(Spherical(deg * kPi / 180, 0.0));
      if (!r.rotation_invariant) wos.push_back(Spherical(70 * kPi / 180, 1.0));
      for (const Vector3d& wo : wos) {
        const Estimate f = IntegrateHemisphere(
            [&](const Vector3d& m) {
              return Array3d::Constant(mf->D(p, m) * mf->G1(p, wo, m) * std::max(0.0, wo.dot(m)) / wo.z());
            },
            Method::kAdaptive, mo, Vector3d::UnitZ(), width);
        r.furnace_min = std::min(r.furnace_min, f.value[0]);
        r.furnace_max = std::max(r.furnace_max, f.value[0]);
        r.furnace_error = std::max(r.furnace_error, f.error[0]);
      }
      const double dev = std::max(std::abs(r.furnace_min - 1), std::abs(r.furnace_max - 1));
      if (!(dev <= r.furnace_error + o.normalisation_tolerance))
        r.reasons.push_back("microfacet: weak white furnace in [" + FormatShort(r.furnace_min) + ", " +
                            FormatShort(r.furnace_max) + "], not 1");
    }
  }

  r.plausible = r.reasons.empty() && r.inconclusive.empty();
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

std::vector<std::vector<double>> SweepGrid(const ModelInfo& info, const std::vector<double>& base, int per_axis,
                                           const std::vector<std::size_t>& fixed, std::size_t max_points) {
  std::vector<std::size_t> free;
  for (std::size_t i = 0; i < info.params.size(); ++i)
    if (std::find(fixed.begin(), fixed.end(), i) == fixed.end() && info.params[i].lower < info.params[i].upper)
      free.push_back(i);
  int n = std::max(per_axis, 2);
  const auto count = [&](int k) {
    double c = 1;
    for (std::size_t j = 0; j < free.size(); ++j) c *= k;
    return c;
  };
  while (n > 2 && count(n) > double(max_points)) --n;
  std::vector<std::vector<double>> values(free.size());
  for (std::size_t j = 0; j < free.size(); ++j) {
    const ParamInfo& pi = info.params[free[j]];
    const bool log_scale = pi.scale == ParamInfo::Scale::kLog && pi.lower > 0;
    for (int k = 0; k < n; ++k) {
      const double t = double(k) / (n - 1);
      double v = log_scale ? std::exp(std::log(pi.lower) + t * (std::log(pi.upper) - std::log(pi.lower)))
                           : pi.lower + t * (pi.upper - pi.lower);
      if (k == 0) v = pi.lower;
      if (k == n - 1) v = pi.upper;
      values[j].push_back(v);
    }
  }
  std::vector<std::vector<double>> points;
  std::vector<int> idx(free.size(), 0);
  while (true) {
    std::vector<double> pt = base;
    for (std::size_t j = 0; j < free.size(); ++j) {
      const std::size_t off = info.Offset(free[j]);
      for (int c = 0; c < (info.params[free[j]].colour ? 3 : 1); ++c) pt[off + c] = values[j][idx[j]];
    }
    points.push_back(pt);
    std::size_t j = 0;
    for (; j < free.size(); ++j) {
      if (++idx[j] < n) break;
      idx[j] = 0;
    }
    if (j == free.size()) break;
  }
  return points;
}

SweepResult SweepPlausibility(const Model& model, const std::vector<std::vector<double>>& points,
                              const CheckOptions& options) {
  SweepResult out;
  out.points = points;
  out.results.resize(points.size());
  const auto bxdf = model.Make<double>();
  tbb::parallel_for(std::size_t(0), points.size(), [&](std::size_t i) {
    out.results[i] = CheckPlausibility(*bxdf, points[i].data(), options);
  });
  return out;
}

}  // namespace brdfkit::validate
