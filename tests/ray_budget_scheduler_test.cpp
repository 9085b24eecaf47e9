// The online scheduler on synthetic scans: the quota invariant over randomised scan sizes,
// quotas and policies; the CPU-share conversion and its feedback; the adaptive rule; settings
// changed from another thread.

#include "scheduler/ray_budget_scheduler.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <thread>

#include "engine/random.hpp"
#include "scheduler/fixed_plan.hpp"

namespace slam {
namespace {

/// What the engine reports for a plan on a scan (its own accounting, as PlannedRays).
ScanReport Executed(const ScanPlan& plan, const ScanSummary& summary, int64_t scan) {
  ScanReport report;
  report.scan = scan;
  report.particles = plan.particles;
  const int64_t total = PlannedRays(plan, summary);
  report.rays.update =
      int64_t{plan.particles} * std::min(plan.update_rays, summary.usable_measurements);
  report.rays.matching = total - report.rays.update;
  report.effective_sample_size = plan.particles;
  return report;
}

TEST(RayBudgetScheduler, PlansNeverExceedTheQuotaAndFillIt) {
  Rng rng(11);
  for (int trial = 0; trial < 40000; ++trial) {
    BudgetSettings settings;
    settings.rays_per_scan = 1 + static_cast<int64_t>(rng.Uniform() * 200000);
    settings.policy = rng.Uniform() < 0.5 ? BudgetPolicy::kFixed : BudgetPolicy::kAdaptive;
    settings.max_particles = 1 + static_cast<int>(rng.Uniform() * 32);
    RayBudgetScheduler scheduler(settings);
    SlamParams params;
    params.particles = 1 + static_cast<int>(rng.Uniform() * 12);
    // A few scans in a row, so that the adaptive state moves.
    for (int k = 0; k < 4; ++k) {
      const int usable = static_cast<int>(rng.Uniform() * 600);
      const ScanSummary summary{usable, static_cast<int>(rng.Uniform() * (usable + 1))};
      const ScanPlan plan = scheduler.Plan(summary, 0.66, params);
      ScanReport report = Executed(plan, summary, k);
      report.refinement_ambiguity = rng.Uniform();
      report.effective_sample_size = rng.Uniform() * plan.particles;
      const PlanRecord record = scheduler.Record(report, 1e-3);
      ASSERT_LE(record.used_rays, settings.rays_per_scan) << "trial " << trial;
      ASSERT_EQ(record.quota, settings.rays_per_scan);
      ASSERT_EQ(record.planned_rays, record.used_rays);
      if (record.fills_quota) {
        ASSERT_GE(record.used_rays, 0.9 * static_cast<double>(settings.rays_per_scan))
            << "trial " << trial << " usable " << summary.usable_measurements << " matching "
            << summary.matching_measurements << " particles " << plan.particles;
      }
      if (settings.policy == BudgetPolicy::kFixed) {
        ASSERT_EQ(plan.particles, params.particles);
      } else {
        ASSERT_LE(plan.particles, settings.max_particles);
      }
    }
    ASSERT_EQ(scheduler.totals().over_quota_scans, 0);
  }
}

TEST(RayBudgetScheduler, FixedPolicyIsThePapersPlan) {
  RayBudgetScheduler scheduler(BudgetSettings{.rays_per_scan = 8125});
  SlamParams params;
  params.particles = 3;
  const ScanSummary summary{160, 120};
  const ScanPlan plan = scheduler.Plan(summary, 0.66, params);
  EXPECT_EQ(plan.particles, 3);
  EXPECT_EQ(plan.update_rays, 160);
  // 8125 / 3 = 2708 per particle: 160 updates, 2548 left = 21 candidates of 120 (2520).
  EXPECT_EQ(plan.candidates, 21);
  EXPECT_EQ(plan.matching_measurements, 120);
  EXPECT_EQ(PlannedRays(plan, summary), 3 * (160 + 21 * 120));
}

TEST(SplitQuota, ThinsMatchingRatherThanLeaveMoreThanAFifthOfACandidate) {
  // 1 particle, 500 left after the updates, 200 matching: 2 whole candidates would leave 100
  // (20 %), so 3 candidates of 166 measurements fill 498.
  const ScanSummary summary{100, 200};
  const ScanPlan plan = SplitQuota(summary, 600, 1);
  EXPECT_EQ(plan.candidates, 3);
  EXPECT_EQ(plan.matching_measurements, 166);
  EXPECT_EQ(PlannedRays(plan, summary), 598);
  // 5 % or less unused: whole candidates, every measurement.
  const ScanPlan close = SplitQuota(summary, 100 + 2 * 200 + 20, 1);
  EXPECT_EQ(close.candidates, 2);
  EXPECT_EQ(close.matching_measurements, 200);
}

TEST(RayBudgetScheduler, CpuShareQuotaFollowsTheMeasuredCostPerRay) {
  SchedulerConfig config;
  config.initial_ns_per_ray = 500.0;
  config.cost_smoothing = 0.5;
  RayBudgetScheduler scheduler(BudgetSettings{.mode = QuotaMode::kCpuShare, .cpu_share = 0.5},
                               config);
  const ScanSummary summary{200, 150};
  const SlamParams params;
  // 0.5 of a core over a 0.6 s scan at 500 ns per ray: 600000 rays.
  ScanPlan plan = scheduler.Plan(summary, 0.6, params);
  EXPECT_EQ(scheduler.totals().scans, 0);
  PlanRecord record = scheduler.Record(Executed(plan, summary, 0), 0.0);
  EXPECT_EQ(record.quota, 600000);
  // The scan cost 250 ns per ray: the smoothed estimate moves half way, to 375 ns.
  plan = scheduler.Plan(summary, 0.6, params);
  const int64_t rays = PlannedRays(plan, summary);
  record = scheduler.Record(Executed(plan, summary, 1), 250e-9 * static_cast<double>(rays));
  EXPECT_NEAR(record.ns_per_ray, 375.0, 1e-9);
  plan = scheduler.Plan(summary, 0.6, params);
  record = scheduler.Record(Executed(plan, summary, 2), 0.0);
  EXPECT_EQ(record.quota, static_cast<int64_t>(0.5 * 0.6 * 1e9 / 375.0));
}

TEST(RayBudgetScheduler, CpuShareSettlesOnItsTargetWithAFixedCostPerScan) {
  // Synthetic cost: 200 ns per ray plus 2 ms per scan; the smoothed cost per ray absorbs the
  // fixed part, so the achieved share converges on the target.
  RayBudgetScheduler scheduler(BudgetSettings{.mode = QuotaMode::kCpuShare, .cpu_share = 0.25});
  const ScanSummary summary{180, 140};
  const SlamParams params;
  double cpu = 0.0, period = 0.0;
  for (int k = 0; k < 60; ++k) {
    const ScanPlan plan = scheduler.Plan(summary, 0.66, params);
    const double cost = 200e-9 * static_cast<double>(PlannedRays(plan, summary)) + 2e-3;
    scheduler.Record(Executed(plan, summary, k), cost);
    if (k >= 30) {
      cpu += cost;
      period += 0.66;
    }
  }
  EXPECT_NEAR(cpu / period, 0.25, 0.25 * 0.02);
}

TEST(AdaptiveParticles, GrowsOnAmbiguityShrinksWhenSharpAndAgreeing) {
  const SchedulerConfig config;
  FilterState state{
      .particles = 4, .effective_sample_size = 3.5, .refinement_ambiguity = 0.8, .refined = true};
  EXPECT_EQ(AdaptiveParticles(state, 1, 16, config), 8);
  EXPECT_EQ(AdaptiveParticles(state, 1, 6, config), 6);  // the budget caps it
  state.refinement_ambiguity = 0.1;
  EXPECT_EQ(AdaptiveParticles(state, 1, 16, config), 3);
  EXPECT_EQ(AdaptiveParticles(state, 4, 16, config), 4);  // never below the tuned count
  state.effective_sample_size = 1.2;  // particles disagree: resampling's job, keep the count
  EXPECT_EQ(AdaptiveParticles(state, 1, 16, config), 4);
  state.refinement_ambiguity = 0.35;  // between the thresholds
  state.effective_sample_size = 4.0;
  EXPECT_EQ(AdaptiveParticles(state, 1, 16, config), 4);
  state.refined = false;  // nothing was matched: no evidence either way
  state.refinement_ambiguity = 0.9;
  EXPECT_EQ(AdaptiveParticles(state, 1, 16, config), 4);
  EXPECT_EQ(AdaptiveParticles(state, 8, 2, config), 2);  // the budget wins over the floor
}

TEST(RayBudgetScheduler, AdaptiveLeavesEveryParticleItsMinimumCandidates) {
  RayBudgetScheduler scheduler(
      BudgetSettings{.rays_per_scan = 20000, .policy = BudgetPolicy::kAdaptive});
  const ScanSummary summary{200, 150};
  const SlamParams params;
  for (int k = 0; k < 10; ++k) {
    const ScanPlan plan = scheduler.Plan(summary, 0.66, params);
    EXPECT_GE(plan.candidates, SchedulerConfig{}.adaptive_min_candidates);
    ScanReport report = Executed(plan, summary, k);
    report.refinement_ambiguity = 0.9;  // always ambiguous: grows to the budget's cap
    scheduler.Record(report, 1e-3);
  }
  // 20000 / (200 + 8 * 150) = 14 particles at most.
  EXPECT_EQ(scheduler.totals().last->plan.particles, 14);
}

TEST(RayBudgetScheduler, SettingsChangedFromAnotherThreadApplyFromTheNextScan) {
  RayBudgetScheduler scheduler(BudgetSettings{.rays_per_scan = 8125});
  const ScanSummary summary{160, 120};
  const SlamParams params;
  std::atomic<bool> stop{false};
  std::thread writer([&] {
    Rng rng(3);
    while (!stop.load()) {
      scheduler.SetSettings(BudgetSettings{
          .rays_per_scan = 8125 * (1 + static_cast<int64_t>(rng.Uniform() * 8)),
          .policy = rng.Uniform() < 0.5 ? BudgetPolicy::kFixed : BudgetPolicy::kAdaptive});
    }
  });
  for (int k = 0; k < 5000; ++k) {
    const ScanPlan plan = scheduler.Plan(summary, 0.66, params);
    const PlanRecord record = scheduler.Record(Executed(plan, summary, k), 1e-4);
    // The plan was made for one consistent snapshot of the settings.
    ASSERT_EQ(record.quota % 8125, 0);
    ASSERT_LE(record.used_rays, record.quota);
  }
  stop = true;
  writer.join();
  scheduler.SetSettings(BudgetSettings{.rays_per_scan = 1000});
  EXPECT_EQ(scheduler.settings().rays_per_scan, 1000);
  const ScanPlan plan = scheduler.Plan(summary, 0.66, params);
  EXPECT_LE(scheduler.Record(Executed(plan, summary, 0), 1e-4).used_rays, 1000);
  EXPECT_EQ(scheduler.totals().over_quota_scans, 0);
}

TEST(BudgetSettings, ValidationNamesTheKey) {
  EXPECT_TRUE(Validate(BudgetSettings{}).empty());
  BudgetSettings bad;
  bad.rays_per_scan = 0;
  bad.cpu_share = 1.5;
  bad.max_particles = 0;
  const ConfigErrors errors = Validate(bad);
  ASSERT_EQ(errors.size(), 3u);
  EXPECT_EQ(errors[0].pointer, "/rays_per_scan");
  EXPECT_EQ(errors[1].pointer, "/cpu_share");
  EXPECT_EQ(errors[2].pointer, "/max_particles");
  bad = BudgetSettings{};
  bad.cpu_share = std::nan("");
  EXPECT_EQ(Validate(bad).size(), 1u);
  EXPECT_EQ(ParseBudgetPolicy("adaptive"), BudgetPolicy::kAdaptive);
  EXPECT_EQ(ParseQuotaMode("cpu_share"), QuotaMode::kCpuShare);
  EXPECT_FALSE(ParseBudgetPolicy("greedy").has_value());
}

}  // namespace
}  // namespace slam
