#include "validate/sobol.h"

namespace brdfkit::validate {

namespace {

// Joe & Kuo 2008, new-joe-kuo-6.21201, dimension 2: degree s = 1, a = 0,
// m_1 = 1 (primitive polynomial x + 1). Dimension 1 is van der Corput.
constexpr unsigned kDegree = 1;
constexpr std::uint32_t kA = 0;
constexpr std::uint32_t kM[kDegree] = {1};

}  // namespace

Sobol2D::Sobol2D() {
  for (unsigned k = 0; k < 32; ++k) v_[0][k] = 1u << (31 - k);
  // Bratley & Fox 1988 recurrence on the scaled direction numbers
  // v_k = m_k 2^(32 - k): v_k = v_{k-s} ^ (v_{k-s} >> s) ^ sum_j a_j v_{k-j}.
  std::array<std::uint32_t, 32>& v = v_[1];
  for (unsigned k = 0; k < kDegree; ++k) v[k] = kM[k] << (31 - k);
  for (unsigned k = kDegree; k < 32; ++k) {
    std::uint32_t x = v[k - kDegree] ^ (v[k - kDegree] >> kDegree);
    for (unsigned j = 1; j < kDegree; ++j)
      if ((kA >> (kDegree - 1 - j)) & 1u) x ^= v[k - j];
    v[k] = x;
  }
}

std::array<std::uint32_t, 2> Sobol2D::Raw(std::uint32_t index) const {
  std::array<std::uint32_t, 2> out{0, 0};
  for (unsigned k = 0; index != 0; ++k, index >>= 1) {
    if (index & 1u) {
      out[0] ^= v_[0][k];
      out[1] ^= v_[1][k];
    }
  }
  return out;
}

namespace {

// Coin for one node of the digit tree: two multiply-xorshift rounds of
// (node, seed), top bit. Cheaper than Mix64 and ample for a random flip.
inline std::uint32_t NodeCoin(std::uint64_t node, std::uint64_t seed) {
  std::uint64_t h = (node ^ seed) * 0x9e3779b97f4a7c15ULL;
  h ^= h >> 29;
  h *= 0xbf58476d1ce4e5b9ULL;
  h ^= h >> 32;
  return std::uint32_t(h >> 63);
}

}  // namespace

std::uint32_t OwenScramble(std::uint32_t x, std::uint64_t seed) {
  std::uint32_t out = x;
  for (int depth = 0; depth < 32; ++depth) {
    const int bit = 31 - depth;
    // Node of the digit tree: the original leading digits with a leading 1
    // marking the depth, so nodes of different depths never collide.
    const std::uint64_t prefix = depth == 0 ? 0 : std::uint64_t(x >> (bit + 1));
    const std::uint64_t node = (std::uint64_t(1) << depth) | prefix;
    out ^= NodeCoin(node, seed) << bit;
  }
  return out;
}

std::array<double, 2> Sobol2D::Point(std::uint32_t index, std::uint64_t seed) const {
  const std::array<std::uint32_t, 2> r = Raw(index);
  const std::uint64_t s0 = Mix64(seed * 2 + 1), s1 = Mix64(seed * 2 + 2);
  // Centre of the 2^-32 cell: strictly inside (0, 1).
  const double scale = 1.0 / 4294967296.0;
  return {(double(OwenScramble(r[0], s0)) + 0.5) * scale, (double(OwenScramble(r[1], s1)) + 0.5) * scale};
}

}  // namespace brdfkit::validate
