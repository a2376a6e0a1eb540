// Spectra to linear sRGB: the CIE 1931 2-degree observer and the sRGB
// primaries (IEC 61966-2-1), for measured files that store spectra.
//
// The colour matching functions are the multi-lobe piecewise-Gaussian fit of
// Wyman, Sloan & Shirley 2013 ("Simple Analytic Approximations to the CIE XYZ
// Color Matching Functions", JCGT 2(2), eq. 2): three lobes for x-bar, two
// each for y-bar and z-bar. Its integrals over 360-830 nm are within 0.5 % of
// the tabulated observer's (tested against the CIE's 106.857 for y-bar).
//
// A spectrum s(lambda), linear between its wavelength nodes and zero outside
// them, goes to XYZ under the equal-energy illuminant, then to linear sRGB
// by the standard matrix, each channel divided by its value for a flat
// spectrum: a flat spectrum of value v is (v, v, v), so a grey measurement
// stays grey (a von Kries white balance from illuminant E to sRGB white).
#pragma once

#include <array>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

namespace brdfkit {

namespace cie {

inline double Lobe(double lambda, double mu, double s1, double s2) {
  const double t = (lambda - mu) / (lambda < mu ? s1 : s2);
  return std::exp(-0.5 * t * t);
}

// x-bar, y-bar, z-bar at wavelength lambda in nm.
inline std::array<double, 3> Xyz(double lambda) {
  return {1.056 * Lobe(lambda, 599.8, 37.9, 31.0) + 0.362 * Lobe(lambda, 442.0, 16.0, 26.7) -
              0.065 * Lobe(lambda, 501.1, 20.4, 26.2),
          0.821 * Lobe(lambda, 568.8, 46.9, 40.5) + 0.286 * Lobe(lambda, 530.9, 16.3, 31.1),
          1.217 * Lobe(lambda, 437.0, 11.8, 36.0) + 0.681 * Lobe(lambda, 459.0, 26.0, 13.8)};
}

// Linear sRGB from XYZ (D65 primaries of IEC 61966-2-1).
inline std::array<double, 3> XyzToLinearSrgb(const std::array<double, 3>& v) {
  return {3.2404542 * v[0] - 1.5371385 * v[1] - 0.4985314 * v[2],
          -0.9692660 * v[0] + 1.8760108 * v[1] + 0.0415560 * v[2],
          0.0556434 * v[0] - 0.2040259 * v[1] + 1.0572252 * v[2]};
}

// Weights w[c][k] such that channel c = sum_k w[c][k] s_k for a spectrum
// given at the (strictly increasing) wavelengths lambda_k in nm, linear in
// between; sum_k w[c][k] = 1 for each channel. The integral runs on a 0.1 nm
// grid. A single wavelength is read as a flat spectrum. Wavelengths lie in
// [1, 1e5] nm (the grid then has at most 1e6 steps; beyond, a step count
// would not fit an int).
inline std::vector<std::array<double, 3>> RgbWeights(const std::vector<double>& lambda) {
  const std::size_t n = lambda.size();
  if (n == 0) throw std::invalid_argument("no wavelengths");
  for (std::size_t k = 0; k < n; ++k)
    if (!(lambda[k] >= 1 && lambda[k] <= 1e5))
      throw std::invalid_argument("wavelength " + std::to_string(k) + " is " + std::to_string(lambda[k]) +
                                  " nm, outside 1 to 1e5 nm");
  for (std::size_t k = 0; k + 1 < n; ++k)
    if (!(lambda[k + 1] > lambda[k]))
      throw std::invalid_argument("wavelengths must increase strictly (node " + std::to_string(k + 1) + ")");
  std::vector<std::array<double, 3>> w(n, {0.0, 0.0, 0.0});
  if (n == 1) {
    w[0] = {1.0, 1.0, 1.0};
    return w;
  }
  std::vector<std::array<double, 3>> xyz(n, {0.0, 0.0, 0.0});
  constexpr double kStep = 0.1;
  for (std::size_t k = 0; k + 1 < n; ++k) {
    const double a = lambda[k], b = lambda[k + 1];
    const int steps = std::max(1, static_cast<int>(std::ceil((b - a) / kStep)));
    const double h = (b - a) / steps;
    for (int s = 0; s < steps; ++s) {
      const double l = a + (s + 0.5) * h, t = (l - a) / (b - a);  // midpoint rule
      const std::array<double, 3> m = Xyz(l);
      for (int c = 0; c < 3; ++c) {
        xyz[k][c] += (1 - t) * m[c] * h;
        xyz[k + 1][c] += t * m[c] * h;
      }
    }
  }
  std::array<double, 3> white = {0, 0, 0};
  for (std::size_t k = 0; k < n; ++k) {
    w[k] = XyzToLinearSrgb(xyz[k]);
    for (int c = 0; c < 3; ++c) white[c] += w[k][c];
  }
  for (int c = 0; c < 3; ++c)
    if (!(std::abs(white[c]) > 1e-9))  // the range misses the visible band
      throw std::invalid_argument("the wavelengths (" + std::to_string(lambda.front()) + " to " +
                                  std::to_string(lambda.back()) + " nm) do not cover the visible range");
  for (auto& v : w)
    for (int c = 0; c < 3; ++c) v[c] /= white[c];
  return w;
}

}  // namespace cie

}  // namespace brdfkit
