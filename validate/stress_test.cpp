#include "validate/stress.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>

#include "brdf/merl.h"
#include "brdf/model.h"

namespace brdfkit::validate {
namespace {

// The sweep over every registered model: no value is NaN, Inf or negative
// in any scalar type, derivatives are finite wherever values are, nothing
// is non-zero below the horizon, sampling stays finite, and every value one
// ulp past a bound (or NaN) is rejected.
TEST(Stress, EveryModelStaysFiniteAndNonNegative) {
  const std::vector<StressRow> rows = RunStress();
  std::map<std::string, int> types;
  for (const StressRow& r : rows) {
    SCOPED_TRACE(r.model + " / " + r.type + (r.first_failure.empty() ? "" : ": first failure " + r.first_failure));
    if (r.skipped) {
      // The models that need a file.
      EXPECT_TRUE(r.model == "merl" || r.model == "rgl" || r.model == "utia" || r.model == "astm") << r.skip_reason;
      continue;
    }
    ++types[r.model];
    EXPECT_GT(r.evaluations, 1000);
    EXPECT_EQ(r.nonfinite_count, 0);
    EXPECT_EQ(r.negative_count, 0);
    EXPECT_EQ(r.horizon_nonzero_count, 0);
    EXPECT_EQ(r.nonfinite_derivative_count, 0);
    EXPECT_EQ(r.sample_failures, 0);
    EXPECT_GT(r.bound_checks, 0);
    EXPECT_EQ(r.bound_failures, 0);
  }
  // Every registered model was swept in three types.
  for (const ModelInfo& info : RegisteredModelInfos())
    if (info.settings.empty() || info.settings.front() != "path") {
      EXPECT_EQ(types[info.name], 3) << info.name;
    }
}

// Mirror-like lobes at mu = 1e-6: both cubatures end finite, inside [0, 1]
// (F = 1 microfacet lobes conserve energy), and agree within their own
// error estimates.
TEST(Stress, StiffIntegralsAgreeBetweenIndependentRules) {
  const std::vector<StiffIntegral> rows = RunStiffIntegrals();
  ASSERT_GE(rows.size(), 2u);
  for (const StiffIntegral& r : rows) {
    SCOPED_TRACE(r.model + " " + r.params);
    EXPECT_TRUE(r.finite);
    EXPECT_GE(r.value, 0.0);
    EXPECT_LE(r.value, 1.0 + r.error);
    EXPECT_TRUE(r.agree) << r.value << " +- " << r.error << " vs " << r.reference << " +- " << r.reference_error;
  }
}

}  // namespace
}  // namespace brdfkit::validate
