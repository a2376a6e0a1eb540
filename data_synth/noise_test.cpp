// The instrument's imperfections: sensor noise is unbiased with the model's
// variance (z-test on the mean, chi-square on the variance, over many seeds),
// HDR merging recovers saturated signals, drift and pointing jitter act as
// their closed forms predict.
#include <gtest/gtest.h>

#include <cmath>

#include "brdf/model.h"
#include "brdf/params.h"
#include "data_synth/synth.h"

namespace brdfkit::synth {
namespace {

// Collimated 10 W/m^2 beam, 1 cm^2 sample, 1 degree detector.
Instrument NoisyInstrument() {
  Instrument inst = DefaultInstrument();
  inst.source.kind = Source::Kind::kCollimated;
  inst.source.irradiance = Eigen::Array3d::Constant(10.0);
  inst.sample.area = 1e-4;
  inst.detector.angular_radius = 1.0 * kDeg;
  inst.detector.responsivity = Eigen::Array3d(3e13, 1.5e13, 6e13);
  inst.detector.exposure_time = 1e-3;
  return inst;
}

// Photo-electron rate per unit f for a collimated beam and a cone detector
// wholly above the horizon: R E A cos(theta_i) pi sin^2(r) cos(theta_o).
double RatePerF(const Instrument& inst, int c, const PlannedPair& p) {
  const double s = std::sin(inst.detector.angular_radius);
  return inst.detector.responsivity[c] * inst.source.irradiance[c] * inst.sample.area * std::cos(p.theta_i) * kPi *
         s * s * std::cos(p.theta_o);
}

struct ZStats {
  double n = 0, sum = 0, sum2 = 0, sigma_ratio = 0;
  void Add(double z, double reported_over_true) {
    n += 1;
    sum += z;
    sum2 += z * z;
    sigma_ratio += reported_over_true;
  }
  // Mean of z ~ N(0, 1/n): a z-test at about 4.5 standard errors.
  void ExpectUnbiased() const { EXPECT_LT(std::abs(sum / n) * std::sqrt(n), 4.5) << "mean z = " << sum / n; }
  // sum z^2 ~ chi-square(n) with mean n and variance 2n.
  void ExpectModelVariance() const {
    EXPECT_LT(std::abs(sum2 - n) / std::sqrt(2 * n), 4.5) << "mean z^2 = " << sum2 / n;
  }
};

ExpandedPlan GridPlan() {
  ExpandedPlan plan;
  for (double ti : {0.0, 30.0, 60.0})
    for (double to : {10.0, 35.0, 70.0}) plan.pairs.push_back({ti * kDeg, 0.0, to * kDeg, kPi * (to > 30)});
  return plan;
}

// Runs `seeds` measurements of a grey Lambertian sample and tests the
// normalised residuals against the expected charge variance per exposure.
void CheckNoise(const Instrument& inst, int seeds, double extra_charge_variance, double sigma_tolerance = 0.01) {
  const Model model = Model::Parse("lambert");
  const std::vector<double> p = ParseParams(model.Info(), "albedo=0.5");
  const double f_true = 0.5 / kPi;
  const Imperfections& m = inst.imperfections;
  const double t = inst.detector.exposure_time;
  ZStats z;
  for (int seed = 0; seed < seeds; ++seed) {
    const SynthResult r = Synthesize(inst, model, p, std::uint64_t(seed), GridPlan());
    for (std::size_t n = 0; n < r.samples.size(); ++n) {
      const SynthSample& s = r.samples[n];
      ASSERT_TRUE(s.valid);
      for (int c = 0; c < 3; ++c) {
        const double k = RatePerF(inst, c, r.plan.pairs[n]);
        const double mu = (k * f_true + m.dark_current) * t;
        const double var_charge = (m.shot_noise ? mu : 0.0) + m.read_noise * m.read_noise + extra_charge_variance;
        const double sigma_f = std::sqrt(var_charge) / t / k;
        z.Add((s.f[c] - f_true) / sigma_f, s.sigma[c] / sigma_f);
      }
    }
  }
  z.ExpectUnbiased();
  z.ExpectModelVariance();
  // The reported uncertainty (evaluated at the measured value) matches.
  EXPECT_NEAR(z.sigma_ratio / z.n, 1.0, sigma_tolerance);
}

TEST(Noise, ShotReadAndDarkAreUnbiasedWithModelVariance) {
  Instrument inst = NoisyInstrument();
  inst.imperfections.shot_noise = true;
  inst.imperfections.read_noise = 12;
  inst.imperfections.dark_current = 2e5;  // 200 electrons in 1 ms
  CheckNoise(inst, 300, 0.0);
}

TEST(Noise, AdcQuantisationAddsGainSquaredOverTwelve) {
  Instrument inst = NoisyInstrument();
  inst.imperfections.read_noise = 6;
  inst.imperfections.adc = true;
  inst.imperfections.adc_bits = 16;
  inst.imperfections.adc_gain = 9;  // coarse steps: gain^2/12 = 6.75 e^2 vs read^2 = 36 e^2
  CheckNoise(inst, 300, 81.0 / 12.0);
}

TEST(Noise, ShotNoiseAloneIsPoisson) {
  Instrument inst = NoisyInstrument();
  inst.detector.responsivity = Eigen::Array3d::Constant(1e11);  // about 10 to 30 electrons: Poisson, not Gaussian
  inst.imperfections.shot_noise = true;
  // sqrt(N) under-estimates sqrt(mu) by about 1/(8 mu) at low counts.
  CheckNoise(inst, 400, 0.0, 0.1);
}

TEST(Noise, HdrMergeRecoversSaturatedSignal) {
  Instrument inst = NoisyInstrument();
  Imperfections& m = inst.imperfections;
  m.shot_noise = true;
  m.read_noise = 5;
  m.saturation = true;
  m.full_well = 20000;
  m.hdr_exposures = {1e-4, 1e-3, 1e-2};
  const Model model = Model::Parse("lambert");
  const std::vector<double> p = ParseParams(model.Info(), "albedo=0.5");
  const double f_true = 0.5 / kPi;
  // One geometry, repeated: 1e-2 s collects ~50000 electrons (always over the
  // 20000 well), 1e-3 s ~5000 and 1e-4 s ~500 (never near it).
  ExpandedPlan plan;
  const PlannedPair pp{0.0, 0.0, 20 * kDeg, kPi};
  plan.pairs.assign(400, pp);
  inst.detector.responsivity = Eigen::Array3d::Constant(5e6 / RatePerF(NoisyInstrument(), 0, pp) * 3e13 / f_true);
  ZStats z;
  for (int seed = 0; seed < 15; ++seed) {
    const SynthResult r = Synthesize(inst, model, p, std::uint64_t(seed), plan);
    EXPECT_EQ(r.report.saturated, 0u);
    for (const SynthSample& s : r.samples) {
      const double k = RatePerF(inst, 0, pp);
      const double t_sum = 1e-4 + 1e-3;
      const double var = (k * f_true * t_sum + 2 * m.read_noise * m.read_noise) / (t_sum * t_sum);
      const double sigma_f = std::sqrt(var) / k;
      z.Add((s.f[0] - f_true) / sigma_f, s.sigma[0] / sigma_f);
    }
  }
  EXPECT_GT(RatePerF(inst, 0, pp) * f_true * 1e-2, 2 * m.full_well);
  z.ExpectUnbiased();
  z.ExpectModelVariance();
  EXPECT_NEAR(z.sigma_ratio / z.n, 1.0, 0.01);

  // Every exposure saturated: flagged, and the value is a lower bound.
  m.hdr_exposures = {1e-2};
  const SynthResult r = Synthesize(inst, model, p, 3, plan);
  EXPECT_EQ(r.report.saturated, plan.pairs.size());
  EXPECT_LT(r.samples[0].f[0], f_true);
}

TEST(Imperfections, SourceDriftScalesLinearlyInPlanOrder) {
  Instrument inst = NoisyInstrument();
  inst.imperfections.drift_per_sample = 1e-3;
  const Model model = Model::Parse("ggx");
  const std::vector<double> p = ParseParams(model.Info(), "alpha=0.3");
  const SynthResult drifted = Synthesize(inst, model, p, 0, GridPlan());
  inst.imperfections.drift_per_sample = 0;
  const SynthResult clean = Synthesize(inst, model, p, 0, GridPlan());
  for (std::size_t n = 0; n < clean.samples.size(); ++n)
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(drifted.samples[n].f[c], clean.samples[n].f[c] * (1 + 1e-3 * double(n)),
                  1e-13 * clean.samples[n].f[c]);
}

TEST(Imperfections, PointingJitterAveragesTheCosineOfTheOffset) {
  // Normal incidence, point apertures: a source offset by angle rho gives
  // f_hat = (rho_d / pi) cos(rho). rho is Rayleigh distributed with scale
  // sigma; its moments come from a fine trapezoid rule here.
  Instrument inst = NoisyInstrument();
  inst.detector.angular_radius = 0;
  const double sigma = 3 * kDeg;
  inst.imperfections.jitter_source = sigma;
  double m1 = 0, m2 = 0;
  const int steps = 200000;
  const double h = 12 * sigma / steps;
  for (int k = 1; k < steps; ++k) {
    const double r = k * h;
    const double pdf = r / (sigma * sigma) * std::exp(-r * r / (2 * sigma * sigma));
    m1 += h * pdf * std::cos(r);
    m2 += h * pdf * std::cos(r) * std::cos(r);
  }
  const double sd = std::sqrt(m2 - m1 * m1);
  const Model model = Model::Parse("lambert");
  const std::vector<double> p = ParseParams(model.Info(), "albedo=1");
  ExpandedPlan plan;
  plan.pairs.assign(20000, PlannedPair{0.0, 0.0, 25 * kDeg, kPi});
  const SynthResult r = Synthesize(inst, model, p, 42, plan);
  double sum = 0, sum2 = 0;
  for (const SynthSample& s : r.samples) {
    const double ratio = s.f[0] * kPi;
    sum += ratio;
    sum2 += ratio * ratio;
    EXPECT_LE(ratio, 1.0 + 1e-15);
  }
  const double n = double(plan.pairs.size());
  const double mean = sum / n, var = sum2 / n - mean * mean;
  EXPECT_LT(std::abs(mean - m1) / (sd / std::sqrt(n)), 4.5);
  EXPECT_NEAR(std::sqrt(var), sd, 0.05 * sd);
}

TEST(Imperfections, SameSeedSameDataDifferentSeedDifferentData) {
  Instrument inst = NoisyInstrument();
  inst.imperfections.shot_noise = true;
  inst.imperfections.jitter_detector = 0.1 * kDeg;
  const Model model = Model::Parse("ggx");
  const std::vector<double> p = ParseParams(model.Info(), "alpha=0.2");
  const SynthResult a = Synthesize(inst, model, p, 9, GridPlan());
  const SynthResult b = Synthesize(inst, model, p, 9, GridPlan());
  const SynthResult c = Synthesize(inst, model, p, 10, GridPlan());
  for (std::size_t n = 0; n < a.samples.size(); ++n) {
    EXPECT_EQ(a.samples[n].f[0], b.samples[n].f[0]);
    EXPECT_NE(a.samples[n].f[0], c.samples[n].f[0]);
  }
}

}  // namespace
}  // namespace brdfkit::synth
