// The measurement equation: point apertures reproduce f_r, a Lambertian
// sample reads rho/pi through any apertures, finite apertures give the
// cosine-weighted cone average (checked against an independent cubature),
// and the forward model differentiates through ceres::Jet.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "brdf/model.h"
#include "brdf/params.h"
#include "data_synth/forward_model.h"
#include "data_synth/synth.h"
#include "brdf/quadrature.h"
#include "validate/jet_models.h"

namespace brdfkit::synth {
namespace {

Instrument PointInstrument() {
  Instrument inst = DefaultInstrument();
  inst.source.kind = Source::Kind::kCollimated;
  inst.detector.angular_radius = 0;
  return inst;
}

Instrument DiscInstrument(double source_deg, double detector_deg) {
  Instrument inst = DefaultInstrument();
  inst.source.kind = Source::Kind::kDisc;
  inst.source.angular_radius = source_deg * kDeg;
  inst.source.radiance = Eigen::Array3d::Constant(1e4);
  inst.detector.angular_radius = detector_deg * kDeg;
  return inst;
}

Eigen::Vector3d Dir(double theta_deg, double phi_deg) { return DirectionFromAngles(theta_deg * kDeg, phi_deg * kDeg); }

TEST(ForwardModel, PointAperturesReproduceTheBrdf) {
  const Model model = Model::Parse("lambert+ggx");
  const auto bxdf = model.Make<double>();
  const std::vector<double> p = ParseParams(model.Info(), "lambert.albedo=0.3:0.4:0.5,ggx.alpha=0.15");
  const ApertureQuadrature q = MakeApertureQuadrature(PointInstrument(), 3);
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0, 1);
  for (int k = 0; k < 500; ++k) {
    // One draw per statement: the order of a call's arguments is unspecified.
    const double phi_i = 2 * kPi * u(rng), theta_i = std::acos(u(rng));
    const double phi_o = 2 * kPi * u(rng), theta_o = std::acos(u(rng));
    const Eigen::Vector3d wi = DirectionFromAngles(theta_i, phi_i), wo = DirectionFromAngles(theta_o, phi_o);
    const Rgb<double> f = bxdf->Eval(p.data(), wi, wo);
    const Rgb<double> m = MeasuredBrdf(*bxdf, p.data(), wi, wo, q);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(m[c], f[c], 1e-12 * std::abs(f[c])) << k;
  }
}

TEST(ForwardModel, SynthesizeWithPointAperturesMatchesTheBrdf) {
  Instrument inst = PointInstrument();
  inst.plan.kind = SamplingPlan::Kind::kRandom;
  inst.plan.random_count = 2000;
  inst.plan.random_seed = 5;
  const Model model = Model::Parse("ggx");
  const std::vector<double> p = ParseParams(model.Info(), "alpha=0.2");
  const SynthResult r = Synthesize(inst, model, p, 1);
  const auto bxdf = model.Make<double>();
  ASSERT_EQ(r.samples.size(), 2000u);
  EXPECT_EQ(r.report.quadrature_error, 0.0);
  for (std::size_t n = 0; n < r.samples.size(); ++n) {
    const PlannedPair& pp = r.plan.pairs[n];
    const Rgb<double> f =
        bxdf->Eval(p.data(), DirectionFromAngles(pp.theta_i, pp.phi_i), DirectionFromAngles(pp.theta_o, pp.phi_o));
    ASSERT_TRUE(r.samples[n].valid);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(r.samples[n].f[c], f[c], 1e-12 * std::abs(f[c]));
      EXPECT_EQ(r.samples[n].sigma[c], 0.0);
    }
  }
}

TEST(ForwardModel, LambertianReadsRhoOverPiThroughAnyAperture) {
  const Model model = Model::Parse("lambert");
  const auto bxdf = model.Make<double>();
  const std::vector<double> p = ParseParams(model.Info(), "albedo=0.2:0.5:0.9");
  for (const auto& [rs, rd] : {std::pair{0.5, 1.0}, {3.0, 0.0}, {0.0, 5.0}, {10.0, 8.0}}) {
    for (int order : {1, 2, 5}) {
      const ApertureQuadrature q = MakeApertureQuadrature(DiscInstrument(rs, rd), order);
      // Grazing directions included: cones that dip below the horizon lose the
      // same nodes in signal and normalisation.
      for (const auto& [wi, wo] : {std::pair{Dir(0, 0), Dir(30, 180)}, {Dir(60, 10), Dir(45, 200)},
                                   {Dir(85, 0), Dir(88, 90)}, {Dir(20, 0), Dir(89.5, 180)}}) {
        const Rgb<double> m = MeasuredBrdf(*bxdf, p.data(), wi, wo, q);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(m[c], p[c] / kPi, 1e-13) << rs << " " << rd << " " << order;
      }
    }
  }
}

// Independent cone average: polar angle alpha (not 1 - cos alpha) with
// Gauss-Legendre in alpha and in beta, a different tangent frame
// (BasisFromZ), and the closed-form projected solid angle
// pi sin^2(r) cos(theta_axis) of a cone wholly above the horizon.
Rgb<double> ReferenceConeAverage(const Bxdf<double>& bxdf, const double* p, const Eigen::Vector3d& wi,
                                 const Eigen::Vector3d& wo, double ri, double ro, int n_alpha, int n_beta) {
  const GaussLegendre ga(n_alpha), gb(n_beta);
  auto nodes = [&](const Eigen::Vector3d& axis, double r) {
    Eigen::Vector3d b1, b2;
    BasisFromZ(axis, b1, b2);
    std::vector<std::pair<Eigen::Vector3d, double>> out;
    for (int a = 0; a < ga.size(); ++a) {
      const double alpha = r * ga.node01(a);
      for (int b = 0; b < gb.size(); ++b) {
        const double beta = 2 * kPi * gb.node01(b);
        const Eigen::Vector3d w =
            std::cos(alpha) * axis + std::sin(alpha) * (std::cos(beta) * b1 + std::sin(beta) * b2);
        out.push_back({w, r * ga.weight01(a) * 2 * kPi * gb.weight01(b) * std::sin(alpha) * w.z()});
      }
    }
    return out;
  };
  const auto ni = nodes(wi, ri), no = nodes(wo, ro);
  Rgb<double> sum = Rgb<double>::Zero();
  for (const auto& [a, wa] : ni)
    for (const auto& [b, wb] : no) sum += bxdf.Eval(p, a, b) * (wa * wb);
  const double si = std::sin(ri), so = std::sin(ro);
  return sum / (kPi * si * si * wi.z() * kPi * so * so * wo.z());
}

TEST(ForwardModel, FiniteAperturesAverageANarrowGgxLobe) {
  const Model model = Model::Parse("ggx");
  const auto bxdf = model.Make<double>();
  const std::vector<double> p = ParseParams(model.Info(), "alpha=0.05");
  const Instrument inst = DiscInstrument(1.0, 1.0);
  const ApertureQuadrature q = MakeApertureQuadrature(inst, 4);
  // On the specular peak, on its flank, and off-plane.
  const std::pair<Eigen::Vector3d, Eigen::Vector3d> geometries[] = {
      {Dir(30, 0), Dir(30, 180)}, {Dir(45, 0), Dir(50, 180)}, {Dir(10, 0), Dir(17, 175)}, {Dir(60, 30), Dir(58, 212)}};
  for (const auto& [wi, wo] : geometries) {
    const Rgb<double> ref = ReferenceConeAverage(*bxdf, p.data(), wi, wo, 1.0 * kDeg, 1.0 * kDeg, 14, 40);
    const Rgb<double> m = MeasuredBrdf(*bxdf, p.data(), wi, wo, q);
    const Rgb<double> point = bxdf->Eval(p.data(), wi, wo);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(m[c], ref[c], 1e-6 * ref[c]);
      // The apertures matter at this level: the average is not the point value.
      EXPECT_GT(std::abs(point[c] - ref[c]), 1e-4 * ref[c]);
    }
  }
}

TEST(ForwardModel, ReportedQuadratureErrorBoundsTheTrueError) {
  const Model model = Model::Parse("ggx");
  const auto bxdf = model.Make<double>();
  const std::vector<double> p = ParseParams(model.Info(), "alpha=0.05");
  Instrument inst = DiscInstrument(1.0, 1.0);
  inst.plan.kind = SamplingPlan::Kind::kList;
  ExpandedPlan plan;
  plan.pairs = {{30 * kDeg, 0, 30 * kDeg, kPi}, {45 * kDeg, 0, 50 * kDeg, kPi}, {60 * kDeg, 0.5, 58 * kDeg, 3.7}};
  std::vector<Rgb<double>> ref;
  for (const PlannedPair& pp : plan.pairs)
    ref.push_back(ReferenceConeAverage(*bxdf, p.data(), DirectionFromAngles(pp.theta_i, pp.phi_i),
                                       DirectionFromAngles(pp.theta_o, pp.phi_o), 1.0 * kDeg, 1.0 * kDeg, 14, 40));
  for (int order = 1; order <= 3; ++order) {
    inst.quadrature.order = order;
    const OrderChoice c = ChooseApertureOrder(inst, *bxdf, p.data(), plan);
    EXPECT_EQ(c.order, order);
    const ApertureQuadrature q = MakeApertureQuadrature(inst, order);
    double worst = 0;
    for (std::size_t k = 0; k < plan.pairs.size(); ++k) {
      const PlannedPair& pp = plan.pairs[k];
      const Rgb<double> m = MeasuredBrdf(*bxdf, p.data(), DirectionFromAngles(pp.theta_i, pp.phi_i),
                                         DirectionFromAngles(pp.theta_o, pp.phi_o), q);
      worst = std::max(worst, ((m - ref[k]).abs() / ref[k]).maxCoeff());
    }
    // The difference to the next order estimates this order's error (the
    // next order is far more accurate), within a modest factor.
    EXPECT_LE(worst, 1.5 * c.error + 1e-12) << order;
    EXPECT_GE(worst, 0.5 * c.error) << order;
  }
  // Automatic order meets the tolerance.
  inst.quadrature.order = 0;
  inst.quadrature.tolerance = 1e-7;
  const OrderChoice c = ChooseApertureOrder(inst, *bxdf, p.data(), plan);
  EXPECT_LT(c.error, 1e-7);
  EXPECT_GE(c.order, 2);
}

// Automatic order in Synthesize: every pair raises its own degrees; each
// result matches the independent cone average to the tolerance, and the
// report's error estimates are below it.
TEST(ForwardModel, SynthesizeRaisesTheOrderPerPair) {
  // A narrow specular lobe on a bright diffuse base: off the peak the
  // reading converges at low orders.
  const Model model = Model::Parse("lambert+ggx");
  const auto bxdf = model.Make<double>();
  const std::vector<double> p = ParseParams(model.Info(), "lambert.albedo=0.8,ggx.alpha=0.05");
  Instrument inst = DiscInstrument(1.0, 1.0);
  inst.quadrature.order = 0;
  inst.quadrature.tolerance = 1e-7;
  ExpandedPlan plan;
  plan.pairs = {{30 * kDeg, 0, 30 * kDeg, kPi},  {45 * kDeg, 0, 50 * kDeg, kPi}, {60 * kDeg, 0.5, 58 * kDeg, 3.7},
                {20 * kDeg, 0, 60 * kDeg, 0.3}, {40 * kDeg, 1.0, 10 * kDeg, 2.0}, {10 * kDeg, 0, 50 * kDeg, 0},
                {30 * kDeg, 0, 60 * kDeg, 1.6}};
  const SynthResult r = Synthesize(inst, model, p, 1, plan);
  ASSERT_EQ(r.samples.size(), plan.pairs.size());
  for (std::size_t k = 0; k < plan.pairs.size(); ++k) {
    const PlannedPair& pp = plan.pairs[k];
    const Rgb<double> ref =
        ReferenceConeAverage(*bxdf, p.data(), DirectionFromAngles(pp.theta_i, pp.phi_i),
                             DirectionFromAngles(pp.theta_o, pp.phi_o), 1.0 * kDeg, 1.0 * kDeg, 14, 40);
    ASSERT_TRUE(r.samples[k].valid);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(r.samples[k].f[c], ref[c], 1e-6 * ref[c]) << k;
  }
  // The pairs off the peak stop at lower degrees: on average fewer
  // evaluations than one common order n checked against n + 1 would spend
  // on every pair.
  const int n = r.report.order;
  EXPECT_GE(r.report.detector_degree, 9);
  EXPECT_LT(r.report.mean_evaluations, 16.0 * (std::pow(n, 4) + std::pow(n + 1, 4)));
  EXPECT_LT(r.report.pair_error, 1e-7);
  EXPECT_LT(r.report.quadrature_error, 1e-7);
}

double RelativeError(const Rgb<double>& a, const Rgb<double>& ref) {
  return (a - ref).abs().maxCoeff() / ref.abs().maxCoeff();
}

// Product rule of one order through the same cone placement (actual and
// nominal arms may differ).
Rgb<double> ProductRule(const Bxdf<double>& bxdf, const double* p, const Instrument& inst, int order,
                        const Eigen::Vector3d& ai, const Eigen::Vector3d& wi, const Eigen::Vector3d& ao,
                        const Eigen::Vector3d& wo) {
  const ApertureQuadrature q = MakeApertureQuadrature(inst, order);
  const ApertureIntegral<double> a = IntegrateApertures(bxdf, p, PlaceCone(q.source, ai, wi, q.sample_from_lab),
                                                        PlaceCone(q.detector, ao, wo, q.sample_from_lab));
  return a.weighted / a.Norm();
}

// The automatic order (MeasureAdaptive) against the independent cone
// average: a narrow GGX lobe through a 0.5 degree source and a 1 degree
// detector. At every tolerance the result meets it, the error estimate is
// not below the true error (where either is above a tenth of the
// tolerance), and the smaller source cone needs no higher degree than the
// detector.
TEST(ForwardModel, AdaptiveOrderMeetsTheTolerance) {
  const Model model = Model::Parse("ggx");
  const auto bxdf = model.Make<double>();
  const std::vector<double> p = ParseParams(model.Info(), "alpha=0.05");
  const Instrument inst = DiscInstrument(0.5, 1.0);
  const ApertureLadder ladder = MakeApertureLadder(inst, 39, 39);
  const std::pair<Eigen::Vector3d, Eigen::Vector3d> geometries[] = {
      {Dir(30, 0), Dir(30, 180)}, {Dir(45, 0), Dir(50, 180)}, {Dir(10, 0), Dir(17, 175)}, {Dir(60, 30), Dir(58, 212)}};
  for (const auto& [wi, wo] : geometries) {
    const Rgb<double> ref = ReferenceConeAverage(*bxdf, p.data(), wi, wo, 0.5 * kDeg, 1.0 * kDeg, 14, 40);
    for (double tol : {1e-4, 1e-6, 1e-8}) {
      const AdaptiveMeasurement a = MeasureAdaptive(*bxdf, p.data(), wi, wi, wo, wo, ladder, tol);
      const double err = RelativeError(a.f, ref);
      ASSERT_TRUE(a.converged) << tol << " err " << a.error << " deg " << a.source_degree << " " << a.detector_degree << " evals " << a.evaluations;
      EXPECT_LT(a.error, tol);
      EXPECT_LE(err, tol) << tol;
      EXPECT_LE(err, std::max(a.error, 0.1 * tol)) << tol;
      EXPECT_LE(a.source_degree, a.detector_degree) << tol;
    }
  }
}

// What the separate orders save, on the benchmark's material (lambert+ggx,
// alpha = 0.15) through a 0.5 degree source and a 1 degree detector, over
// random pairs away from grazing: against raising one common order n until
// I_n and I_(n+1) agree (16 + 256 + ... + 16 (n+1)^4 evaluations), at the
// same tolerance, both checked against the product rule of order 8.
TEST(ForwardModel, AdaptiveOrderNeedsFewerEvaluationsThanACommonOrder) {
  const Model model = Model::Parse("lambert+ggx");
  const auto bxdf = model.Make<double>();
  const std::vector<double> p = ParseParams(model.Info(), "lambert.albedo=0.1:0.2:0.3,ggx.alpha=0.15");
  const Instrument inst = DiscInstrument(0.5, 1.0);
  const ApertureLadder ladder = MakeApertureLadder(inst, 39, 39);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(0, 1);
  double adaptive = 0, common = 0;
  const double tol = 1e-6;
  for (int k = 0; k < 60; ++k) {
    // Near the mirror direction half of the time, where the lobe matters.
    // One draw per statement: the order of a call's arguments is unspecified.
    const double ti = 75 * u(rng), pi = 360 * u(rng), u1 = u(rng), u2 = u(rng);
    const Eigen::Vector3d wi = Dir(ti, pi);
    const Eigen::Vector3d mirror(-wi.x(), -wi.y(), wi.z());
    const Eigen::Vector3d wo = k % 2 ? Dir(75 * u1, 360 * u2)
                                     : Dir(std::acos(mirror.z()) / kDeg + 10 * (u1 - 0.5),
                                           std::atan2(mirror.y(), mirror.x()) / kDeg + 10 * (u2 - 0.5));
    const Rgb<double> ref = ProductRule(*bxdf, p.data(), inst, 8, wi, wi, wo, wo);
    const AdaptiveMeasurement a = MeasureAdaptive(*bxdf, p.data(), wi, wi, wo, wo, ladder, tol);
    ASSERT_TRUE(a.converged) << k;
    EXPECT_LE(RelativeError(a.f, ref), tol) << k;
    adaptive += double(a.evaluations);
    int n = 1;
    Rgb<double> lower = ProductRule(*bxdf, p.data(), inst, 1, wi, wi, wo, wo);
    common += 16;
    for (;; ++n) {
      const Rgb<double> higher = ProductRule(*bxdf, p.data(), inst, n + 1, wi, wi, wo, wo);
      common += 16.0 * std::pow(n + 1, 4);
      if (RelativeError(lower, higher) <= tol) break;
      lower = higher;
    }
    EXPECT_LE(RelativeError(lower, ref), 10 * tol) << k;
  }
  EXPECT_LT(adaptive, 0.35 * common) << "adaptive " << adaptive / 60 << " common " << common / 60;
}

// Apertures as wide as the lobe (3 degree cones on alpha = 0.05): both cones
// must rise together. Also a tilted sample with jittered arms (cones around
// the actual arms, normalised by the nominal ones). Reference: the product
// rule of order 9 (324 nodes per cone), itself checked against order 10.
TEST(ForwardModel, AdaptiveOrderHandlesWideConesTiltAndJitter) {
  const Model model = Model::Parse("lambert+ggx");
  const auto bxdf = model.Make<double>();
  const std::vector<double> p = ParseParams(model.Info(), "lambert.albedo=0.02:0.05:0.1,ggx.alpha=0.05");
  Instrument wide = DiscInstrument(3.0, 3.0);
  Instrument tilted = DiscInstrument(0.5, 1.0);
  tilted.sample.tilt_x = 0.7 * kDeg;
  tilted.sample.tilt_y = -0.4 * kDeg;
  for (const Instrument* inst : {&wide, &tilted}) {
    const ApertureLadder ladder = MakeApertureLadder(*inst, 39, 39);
    for (const auto& [wi, wo] : {std::pair{Dir(30, 0), Dir(30, 180)}, {Dir(45, 0), Dir(50, 180)}, {Dir(60, 30), Dir(58, 212)}}) {
      // The actual arms are off by a fraction of a degree.
      const Eigen::Vector3d ai = Dir(std::acos(wi.z()) / kDeg + 0.3, std::atan2(wi.y(), wi.x()) / kDeg - 0.2);
      const Eigen::Vector3d ao = Dir(std::acos(wo.z()) / kDeg - 0.25, std::atan2(wo.y(), wo.x()) / kDeg + 0.1);
      const Rgb<double> ref = ProductRule(*bxdf, p.data(), *inst, 9, ai, wi, ao, wo);
      ASSERT_LT(RelativeError(ProductRule(*bxdf, p.data(), *inst, 10, ai, wi, ao, wo), ref), 1e-10);
      const AdaptiveMeasurement a = MeasureAdaptive(*bxdf, p.data(), ai, wi, ao, wo, ladder, 1e-6);
      ASSERT_TRUE(a.converged) << a.error << " deg " << a.source_degree << " " << a.detector_degree;
      const double err = RelativeError(a.f, ref);
      EXPECT_LE(err, 1e-6);
      // Cones this wide couple strongly (the lobe follows the half vector):
      // the estimate stays within a factor 2 of the true error.
      EXPECT_LE(err, std::max(2 * a.error, 1e-7));
      if (inst == &wide) {
        EXPECT_GE(std::min(a.source_degree, a.detector_degree), 9) << "both wide cones refined";
      }
    }
  }
}

// Projected solid angle of the part of a cone (axis at polar angle
// theta_a, radius r) above the horizon, by an independent 1D integral over
// the polar angle theta: the cone spans the azimuths |phi - phi_a| <=
// acos((cos r - cos theta cos theta_a) / (sin theta sin theta_a)). The
// substitution theta = theta_low + t^2 removes the square-root end point.
double ClippedProjectedSolidAngle(double theta_a, double r) {
  const double lo = theta_a - r, hi = std::min(kPi / 2, theta_a + r);
  const GaussLegendre gl(400);
  const double t_max = std::sqrt(hi - lo);
  double sum = 0;
  for (int k = 0; k < gl.size(); ++k) {
    const double t = t_max * gl.node01(k), theta = lo + t * t;
    const double c = (std::cos(r) - std::cos(theta) * std::cos(theta_a)) / (std::sin(theta) * std::sin(theta_a));
    const double dphi = std::acos(std::clamp(c, -1.0, 1.0));
    sum += t_max * gl.weight01(k) * 2 * t * 2 * dphi * std::cos(theta) * std::sin(theta);
  }
  return sum;
}

// A cone the horizon cuts is integrated over its part above it with a rule
// fitted to that part: its projected solid angle matches the independent
// integral to 1e-12 from order 6, with the axis above, on, and below the
// true horizon (a tilted sample). Dropping the nodes below the horizon
// instead leaves errors of 1e-5 to 1e-3.
TEST(ForwardModel, HorizonCutsTheConeExactly) {
  const double r = 2 * kDeg;
  for (double theta_a : {88.1, 89.0, 89.9, 90.0, 90.7, 91.5}) {
    // The arm points at 80 degrees; the sample tilts the true axis to theta_a.
    Instrument inst = DiscInstrument(0.0, 2.0);
    inst.sample.tilt_y = (80 - theta_a) * kDeg;
    const Eigen::Vector3d arm = Dir(80, 0);
    const Eigen::Matrix3d tilt = inst.sample.SampleFromLab();
    ASSERT_NEAR(std::acos((tilt * arm).z()) / kDeg, theta_a, 1e-9) << "tilt sign";
    const double ref = ClippedProjectedSolidAngle(theta_a * kDeg, r);
    for (int order : {6, 8}) {
      const PlacedCone c = PlaceCone(MakeConeRule(r, order), arm, arm, tilt);
      EXPECT_TRUE(c.clipped);
      double sum = 0;
      for (double w : c.weights) sum += w;
      EXPECT_NEAR(sum, ref, 1e-12 * ref) << theta_a << " order " << order;
    }
    const ConeRule rule = MakeConeRule(r, 6);
    double dropped = 0;
    for (std::size_t k = 0; k < rule.offsets.size(); ++k)
      dropped += rule.weights[k] * std::max(0.0, (tilt * ArmFrame(arm) * rule.offsets[k]).z());
    EXPECT_GT(std::abs(dropped - ref), 1e-5 * ref) << theta_a;
  }
}

// Near the horizon the measured reading still converges geometrically:
// lambert+ggx at theta_o = 89.6 degrees with a 1 degree detector (cut by the
// horizon), product orders 2 to 6 against order 12.
TEST(ForwardModel, ReadingsThroughACutConeConverge) {
  const Model model = Model::Parse("lambert+ggx");
  const auto bxdf = model.Make<double>();
  const std::vector<double> p = ParseParams(model.Info(), "lambert.albedo=0.3,ggx.alpha=0.3");
  const Instrument inst = DiscInstrument(0.0, 1.0);
  const Eigen::Vector3d wi = Dir(60, 0), wo = Dir(89.6, 180);
  const Rgb<double> ref = ProductRule(*bxdf, p.data(), inst, 12, wi, wi, wo, wo);
  double previous = 1;
  for (int order = 2; order <= 6; ++order) {
    const double err = RelativeError(ProductRule(*bxdf, p.data(), inst, order, wi, wi, wo, wo), ref);
    EXPECT_LT(err, std::max(0.1 * previous, 1e-13)) << order;
    previous = err;
  }
  EXPECT_LT(previous, 1e-12);
  const AdaptiveMeasurement a = MeasureAdaptive(*bxdf, p.data(), wi, wi, wo, wo, MakeApertureLadder(inst, 39, 39), 1e-8);
  ASSERT_TRUE(a.converged);
  EXPECT_LT(RelativeError(a.f, ref), 1e-8);
}

TEST(ForwardModel, TiltedSampleChangesTheProjectedFlux) {
  const Model model = Model::Parse("lambert");
  const auto bxdf = model.Make<double>();
  const std::vector<double> p = ParseParams(model.Info(), "albedo=0.5");
  Instrument inst = PointInstrument();
  inst.sample.tilt_x = 3 * kDeg;
  const ApertureQuadrature q = MakeApertureQuadrature(inst, 1);
  // True normal: R_x(3 deg) e_z = (0, -sin 3, cos 3).
  const Eigen::Vector3d n(0, -std::sin(3 * kDeg), std::cos(3 * kDeg));
  for (const auto& [wi, wo] : {std::pair{Dir(30, 90), Dir(40, 270)}, {Dir(60, 0), Dir(20, 180)}}) {
    const Rgb<double> m = MeasuredBrdf(*bxdf, p.data(), wi, wo, q);
    const double expected = 0.5 / kPi * wi.dot(n) * wo.dot(n) / (wi.z() * wo.z());
    EXPECT_NEAR(m[0], expected, 1e-14);
  }
}

TEST(ForwardModel, DifferentiatesThroughJets) {
  using J = JetN<4>;
  const Model model = Model::Parse("ggx");
  const auto bd = model.Make<double>();
  const auto bj = model.Make<J>();
  std::vector<double> p = ParseParams(model.Info(), "alpha=0.08");
  const ApertureQuadrature q = MakeApertureQuadrature(DiscInstrument(1.0, 1.5), 2);
  const Eigen::Vector3d wi = Dir(35, 0), wo = Dir(33, 182);
  // alpha is the first parameter; perturb it in the jet's first slot.
  std::vector<J> pj(p.size());
  for (std::size_t k = 0; k < p.size(); ++k) pj[k] = J(p[k]);
  pj[0].v[0] = 1;
  const Rgb<J> mj = MeasuredBrdf(*bj, pj.data(), wi, wo, q);
  const Rgb<double> md = MeasuredBrdf(*bd, p.data(), wi, wo, q);
  const double h = 1e-6;
  std::vector<double> pp = p, pm = p;
  pp[0] += h;
  pm[0] -= h;
  const Rgb<double> fd = (MeasuredBrdf(*bd, pp.data(), wi, wo, q) - MeasuredBrdf(*bd, pm.data(), wi, wo, q)) / (2 * h);
  for (int c = 0; c < 3; ++c) {
    EXPECT_DOUBLE_EQ(mj[c].a, md[c]);
    EXPECT_NEAR(mj[c].v[0], fd[c], 1e-6 * std::abs(fd[c]));
    EXPECT_EQ(mj[c].v[1], 0.0);
  }
}

}  // namespace
}  // namespace brdfkit::synth
