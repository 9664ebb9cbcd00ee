// DurationHistogram (include/vcsim/core.h): the per-step stage times of `vcsim run --profile`.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "vcsim/core.h"

namespace vcsim {
namespace {

// 1000 durations 1, 2, ..., 1000 us: the mean exact, the median and the 99th percentile within
// half a bin (2.5 %) of the sample's, never above the largest.
TEST(DurationHistogram, QuantilesWithinHalfABinAndAnExactMean) {
  DurationHistogram h;
  for (int k = 1; k <= 1000; ++k) h.add(k);
  EXPECT_EQ(h.count(), 1000);
  EXPECT_DOUBLE_EQ(h.mean(), 500.5);
  EXPECT_EQ(h.max(), 1000.0);
  EXPECT_NEAR(h.quantile(0.5), 500.0, 0.025 * 500.0);
  EXPECT_NEAR(h.quantile(0.99), 990.0, 0.025 * 990.0);
  EXPECT_LE(h.quantile(1.0), 1000.0);
  EXPECT_NEAR(h.quantile(0.0), 1.0, 0.025);
}

// Out of range, zero, negative and NaN durations are counted at the ends, never out of bounds.
TEST(DurationHistogram, AnyValueIsCountedInRange) {
  DurationHistogram h;
  EXPECT_EQ(h.quantile(0.5), 0.0) << "empty";
  h.add(0.0);
  h.add(-3.0);
  h.add(std::numeric_limits<double>::quiet_NaN());
  h.add(1e12);  // beyond 10 s: the last bin
  EXPECT_EQ(h.count(), 4);
  EXPECT_TRUE(std::isfinite(h.mean()));
  EXPECT_LE(h.quantile(0.5), 0.05);
  EXPECT_GT(h.quantile(1.0), 1e6);
}

}  // namespace
}  // namespace vcsim
