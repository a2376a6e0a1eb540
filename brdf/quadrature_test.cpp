#include "brdf/quadrature.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "brdf/core.h"

namespace brdfkit {
namespace {

QuadValue Grey(double v) { return {Eigen::Array3d::Constant(v), Eigen::Array3d::Zero()}; }

// A smooth integrand to the tolerance asked: int_0^pi sin = 2.
TEST(AdaptiveKronrod, SmoothIntegrandMeetsTheTolerance) {
  auto f = [](double x) { return Grey(std::sin(x)); };
  const QuadValue r = AdaptiveKronrod(f, 0.0, kPi, {}, 1e-13, 0.0, 100, [] { return false; });
  EXPECT_NEAR(r.value[0], 2.0, 1e-13);
  EXPECT_LE(r.error[0], 1e-13);
}

// A jump at a given break needs no bisection: two segments of 15 nodes,
// each integrating a constant exactly (int_0^1 [x > 0.3] = 0.7).
TEST(AdaptiveKronrod, JumpAtABreakIsExactWithoutBisection) {
  int calls = 0;
  auto f = [&](double x) {
    ++calls;
    return Grey(x > 0.3 ? 1.0 : 0.0);
  };
  const QuadValue r = AdaptiveKronrod(f, 0.0, 1.0, {0.3, 1.5, -2.0}, 1e-12, 0.0, 100, [] { return false; });
  EXPECT_NEAR(r.value[0], 0.7, 1e-15);
  EXPECT_EQ(calls, 30);
}

// A jump between two neighbouring doubles can never meet a zero tolerance:
// the segments shrink to one ulp, cannot be split in double precision, and
// become final; the driver stops there (not at max_splits) and reports the
// error it is left with. The value is still the integral to an ulp.
TEST(AdaptiveKronrod, StopsWhenOnlySegmentsTooShortToSplitAreLeft) {
  const double a = 1.0, ulp = std::nextafter(1.0, 2.0) - 1.0, b = a + 8 * ulp;
  const double jump = a + 3.5 * ulp;  // between the doubles a + 3 ulp and a + 4 ulp
  int calls = 0;
  auto f = [&](double x) {
    ++calls;
    return Grey(x > jump ? 1.0 : 0.0);
  };
  int rounds = 0;  // of the bisection loop, which asks stop() once per round
  const QuadValue r = AdaptiveKronrod(f, a, b, {}, 0.0, 0.0, 1000000, [&] {
    ++rounds;
    return false;
  });
  // Eight one-ulp leaves at most: 15 segments of 15 nodes, a round for each
  // split and for each leaf found final.
  EXPECT_LE(calls, 15 * 15);
  EXPECT_LE(rounds, 7 + 8 + 1);
  EXPECT_GT(r.error[0], 0.0);
  EXPECT_NEAR(r.value[0], b - jump, ulp);
}

}  // namespace
}  // namespace brdfkit
