#include "scheduler/fixed_plan.hpp"

#include <gtest/gtest.h>

#include <algorithm>

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
    ScanSummary summary{usable, static_cast<int>(rng.Uniform() * (usable + 1))};
    // Half the scans from a range scanner whose narrowed search keeps more readings.
    if (rng.Uniform() < 0.5) {
      summary.matching_available =
          summary.matching_measurements +
          static_cast<int>(rng.Uniform() * (usable - summary.matching_measurements + 1));
    }
    const int64_t quota = static_cast<int64_t>(rng.Uniform() * 70000);
    const ScanPlan plan = FixedPlan(summary, quota, params);
    const int64_t rays = PlannedRays(plan, summary);
    ASSERT_LE(rays, quota) << "trial " << trial;
    // Uses most of it when the scan offers enough: all but less than one candidate's worth.
    const int64_t per_candidate =
        int64_t{params.particles} *
        std::max(summary.matching_measurements, summary.matching_available);
    if (summary.matching_measurements > 0 &&
        quota >= params.particles * (usable + 2 * summary.matching_measurements)) {
      ASSERT_GT(rays, quota - per_candidate - params.particles) << "trial " << trial;
    }
  }
}

TEST(FixedPlan, ANarrowedSearchTradesCandidatesForReadingsDownToThePeakFitsNeed) {
  // A laser's 180 readings thinned to 45 by the set, 175 by its narrowed search: the set's 236
  // candidates per particle of 45 readings become 60 of 175, about as many rays.
  const ScanSummary summary{180, 45, 175};
  const ScanPlan plan = SplitQuota(summary, 32500, 3);
  EXPECT_EQ(plan.update_rays, 180);
  EXPECT_EQ(plan.matching_measurements, 175);
  EXPECT_EQ(plan.candidates, (32500 / 3 - 180) / 175);
  EXPECT_LE(PlannedRays(plan, summary), 32500);
  EXPECT_GT(PlannedRays(plan, summary), 32500 - 3 * 175 - 3);
  // Never below the candidates the peak fit needs: 40 of 45 readings would become 10 of 175; it
  // keeps 20 of as many readings as they afford.
  const ScanSummary few{180, 45, 175};
  const ScanPlan fit = SplitQuota(few, 180 + 40 * 45, 1);
  EXPECT_EQ(fit.candidates, kPeakFitMinCandidates);
  EXPECT_EQ(fit.matching_measurements, 40 * 45 / kPeakFitMinCandidates);
  // At or below the peak fit's need already, the set's thinning stays.
  const ScanPlan kept = SplitQuota(few, 180 + 17 * 45, 1);
  EXPECT_EQ(kept.candidates, 17);
  EXPECT_EQ(kept.matching_measurements, 45);
  // Without a narrowed search nothing changes.
  const ScanPlan set = SplitQuota({180, 45, 45}, 32500, 3);
  EXPECT_EQ(set.matching_measurements, 45);
  EXPECT_EQ(set.candidates, (32500 / 3 - 180) / 45);
}

}  // namespace
}  // namespace slam
