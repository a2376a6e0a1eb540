// Two-dimensional Sobol' sequence (Sobol' 1967) with the direction numbers
// of Joe & Kuo 2008 ("Constructing Sobol sequences with better
// two-dimensional projections", file new-joe-kuo-6.21201), and Owen's nested
// uniform scrambling (Owen 1995) realised with a hash per tree node, so each
// seed gives an independent randomisation that keeps the (0, m, 2)-net
// structure and makes every point uniform on the unit square.
#pragma once

#include <array>
#include <cstdint>

namespace brdfkit::validate {

class Sobol2D {
 public:
  Sobol2D();
  // Unscrambled point i as 32-bit integers (divide by 2^32 for [0, 1)).
  std::array<std::uint32_t, 2> Raw(std::uint32_t index) const;
  // Owen-scrambled point i of the randomisation `seed`, strictly inside (0, 1)^2.
  std::array<double, 2> Point(std::uint32_t index, std::uint64_t seed) const;

 private:
  std::array<std::array<std::uint32_t, 32>, 2> v_{};
};

// Owen (nested uniform) scrambling of a 32-bit fixed-point coordinate: every
// digit is flipped by a coin that depends on the seed and on all preceding
// original digits.
std::uint32_t OwenScramble(std::uint32_t x, std::uint64_t seed);

// SplitMix64 finaliser (Steele et al. 2014), the hash behind the scrambling
// and the seeds of independent streams.
inline std::uint64_t Mix64(std::uint64_t z) {
  z += 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

}  // namespace brdfkit::validate
