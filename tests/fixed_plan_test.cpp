#include "scheduler/fixed_plan.hpp"

#include <gtest/gtest.h>

#include "engine/random.hpp"

namespace slam {
namespace {

TEST(FixedPlan, CandidatesTakeWhatTheUpdatesLeave) {
  SlamParams params;  // one particle
  const ScanSummary summary{160, 120};
  const ScanPlan plan = FixedPlan(summary, 65000, params);
  EXPECT_EQ(plan.particles, 1);
  EXPECT_EQ(plan.update_rays, 160);
  EXPECT_EQ(plan.matching_measurements, 120);
  EXPECT_EQ(plan.candidates, (65000 - 160) / 120);
  EXPECT_LE(PlannedRays(plan, summary), 65000);
  EXPECT_GT(PlannedRays(plan, summary), 65000 - 120);
}

TEST(FixedPlan, ThinsMatchingWhenTwoCandidatesDoNotFit) {
  SlamParams params;
  const ScanSummary summary{160, 160};
  const ScanPlan plan = FixedPlan(summary, 300, params);
  EXPECT_EQ(plan.update_rays, 160);
  EXPECT_EQ(plan.candidates, 2);
  EXPECT_EQ(plan.matching_measurements, 70);
  EXPECT_EQ(PlannedRays(plan, summary), 300);
  // Not even the updates fit: they are capped, and nothing is matched.
  const ScanPlan tiny = FixedPlan(summary, 100, params);
  EXPECT_EQ(tiny.update_rays, 100);
  EXPECT_EQ(PlannedRays(tiny, summary), 100);
}

TEST(FixedPlan, NeverExceedsTheQuotaOnRandomScans) {
  Rng rng(5);
  for (int trial = 0; trial < 20000; ++trial) {
    SlamParams params;
    params.particles = 1 + static_cast<int>(rng.Uniform() * 8);
    const int usable = static_cast<int>(rng.Uniform() * 400);
    const ScanSummary summary{usable, static_cast<int>(rng.Uniform() * (usable + 1))};
    const int64_t quota = static_cast<int64_t>(rng.Uniform() * 70000);
    const ScanPlan plan = FixedPlan(summary, quota, params);
    const int64_t rays = PlannedRays(plan, summary);
    ASSERT_LE(rays, quota) << "trial " << trial;
    // Uses most of it when the scan offers enough: all but less than one candidate's worth.
    const int64_t per_candidate = int64_t{params.particles} * summary.matching_measurements;
    if (summary.matching_measurements > 0 &&
        quota >= params.particles * (usable + 2 * summary.matching_measurements)) {
      ASSERT_GT(rays, quota - per_candidate - params.particles) << "trial " << trial;
    }
  }
}

}  // namespace
}  // namespace slam
