// Sensor noise model of the virtual detector (EMVA Standard 1288, release
// 4.0, sec. 2: linear photon-transfer model).
//
// One exposure of length t with mean photo-electron rate rho gives
//   mu   = (rho + dark) t                         mean charge (electrons)
//   N    = Poisson(mu)                            photon shot noise and dark shot noise
//   N    = min(N, full_well)                      saturation of the pixel well
//   N   += Normal(0, read^2)                      read noise
//   DN   = clamp(round(N / gain), 0, 2^bits - 1)  ADC quantisation (EMVA 1288 eq. 5)
// with variance  sigma^2 = mu + read^2 + gain^2 / 12  (EMVA 1288 eq. 7) while
// nothing saturates. The reduction subtracts the known mean dark charge (a
// dark frame) and merges bracketed exposures into a rate estimate
//   rho_hat = sum_k (N_k - dark t_k) / sum_k t_k   over unsaturated exposures k,
// the inverse-variance combination when shot noise dominates (var N_k is
// proportional to t_k), and unbiased under the Poisson and Gaussian terms.
// An exposure counts as saturated when its reading is within 4 read-noise
// deviations of the full well or at the ADC maximum; if all are, the
// shortest one is used and the sample is flagged (its value is then a lower
// bound).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

#include "data_synth/instrument.h"

namespace brdfkit::synth {

// Counter-based generator (SplitMix64, Steele et al. 2014): the stream of
// sample n under seed s depends on (s, n) only, so results do not depend on
// threading. Satisfies UniformRandomBitGenerator.
class SampleRng {
 public:
  using result_type = std::uint64_t;
  SampleRng(std::uint64_t seed, std::uint64_t stream) : state_(Mix(seed ^ Mix(stream + 0x632BE59BD9B4E019ull))) {}
  static constexpr result_type min() { return 0; }
  static constexpr result_type max() { return std::numeric_limits<result_type>::max(); }
  result_type operator()() { return Mix(state_ += 0x9E3779B97F4A7C15ull); }
  double Uniform() { return double((*this)() >> 11) * 0x1.0p-53; }

 private:
  static std::uint64_t Mix(std::uint64_t z) {
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  std::uint64_t state_;
};

struct RateEstimate {
  double rate = 0;      // electrons per second from the signal (dark removed)
  double variance = 0;  // model variance of `rate`, evaluated at the estimate
  bool saturated = false;
};

class SensorModel {
 public:
  SensorModel(const Imperfections& m, double exposure_time) : m_(m) {
    exposures_ = m.saturation && !m.hdr_exposures.empty() ? m.hdr_exposures : std::vector<double>{exposure_time};
    std::sort(exposures_.begin(), exposures_.end());
  }

  const std::vector<double>& Exposures() const { return exposures_; }

  // Variance of one exposure's charge for a mean charge mu (unsaturated).
  double ChargeVariance(double mu) const {
    double v = m_.shot_noise ? std::max(mu, 0.0) : 0.0;
    v += m_.read_noise * m_.read_noise;
    if (m_.adc) v += m_.adc_gain * m_.adc_gain / 12.0;
    return v;
  }

  // Model variance of the merged rate when the exposures `used` are kept.
  double RateVariance(double rate, const std::vector<bool>& used) const {
    double v = 0, t = 0;
    for (std::size_t k = 0; k < exposures_.size(); ++k) {
      if (!used[k]) continue;
      v += ChargeVariance((rate + m_.dark_current) * exposures_[k]);
      t += exposures_[k];
    }
    return t > 0 ? v / (t * t) : 0.0;
  }

  // One exposure's raw reading: DN with the ADC on, electrons without.
  template <class Rng>
  double Raw(double rate, double t, Rng& rng) const {
    const double mu = (rate + m_.dark_current) * t;
    double n = m_.shot_noise ? Poisson(mu, rng) : mu;
    if (m_.saturation) n = std::min(n, m_.full_well);
    if (m_.read_noise > 0) n += m_.read_noise * Normal(rng);
    if (!m_.adc) return n;
    return std::clamp(std::nearbyint(n / m_.adc_gain), 0.0, DnMax());
  }

  double DnMax() const { return std::ldexp(1.0, m_.adc_bits) - 1; }
  double RawToCharge(double raw) const { return m_.adc ? raw * m_.adc_gain : raw; }

  // Saturation as seen in the data: the ADC at its maximum, or a charge
  // within 4 read-noise deviations of the full well (a clipped well reads
  // full_well plus read noise).
  bool RawSaturated(double raw) const {
    if (m_.adc && raw >= DnMax()) return true;
    return m_.saturation && RawToCharge(raw) >= m_.full_well - 4 * m_.read_noise;
  }

  // Merges one raw reading per exposure (in Exposures() order).
  RateEstimate Merge(const double* raw) const {
    std::vector<bool> used(exposures_.size(), false);
    bool any = false;
    for (std::size_t k = 0; k < exposures_.size(); ++k) {
      used[k] = !RawSaturated(raw[k]);
      any = any || used[k];
    }
    RateEstimate e;
    if (!any) {
      used[0] = true;  // all saturated: the shortest exposure gives a lower bound
      e.saturated = true;
    }
    double sum_n = 0, sum_t = 0;
    for (std::size_t k = 0; k < exposures_.size(); ++k) {
      if (!used[k]) continue;
      sum_n += RawToCharge(raw[k]) - m_.dark_current * exposures_[k];
      sum_t += exposures_[k];
    }
    e.rate = sum_n / sum_t;
    e.variance = RateVariance(std::max(e.rate, 0.0), used);
    return e;
  }

  template <class Rng>
  RateEstimate Measure(double rate, Rng& rng) const {
    std::vector<double> raw(exposures_.size());
    for (std::size_t k = 0; k < exposures_.size(); ++k) raw[k] = Raw(rate, exposures_[k], rng);
    return Merge(raw.data());
  }

  // Standard normal deviate (Marsaglia polar method).
  template <class Rng>
  static double Normal(Rng& rng) {
    for (;;) {
      const double u = 2 * rng.Uniform() - 1, v = 2 * rng.Uniform() - 1;
      const double s = u * u + v * v;
      if (s > 0 && s < 1) return u * std::sqrt(-2 * std::log(s) / s);
    }
  }

  template <class Rng>
  static double Poisson(double mu, Rng& rng) {
    if (!(mu > 0)) return 0;
    // Beyond 1e12 electrons the Poisson law is Gaussian to a relative
    // skewness of 1e-6, and integer draws would approach overflow.
    if (mu > 1e12) return std::max(0.0, mu + std::sqrt(mu) * Normal(rng));
    std::poisson_distribution<long long> d(mu);
    return static_cast<double>(d(rng));
  }

 private:
  Imperfections m_;
  std::vector<double> exposures_;
};

}  // namespace brdfkit::synth
