// One scan through the budget (BudgetedStep), as replay and slamd run it, on a short simulated run.

#include "scheduler/budgeted_step.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <limits>
#include <tuple>
#include <utility>

#include "engine/loss_detector.hpp"
#include "engine/quality.hpp"
#include "engine/relocalizer.hpp"
#include "sim/map_quality.hpp"
#include "sim/scenario.hpp"
#include "sim/world.hpp"
#include "test_support.hpp"

namespace slam {
namespace {

using testing::ShippedRobot;

std::vector<Scan> RoomScans(double duration_s) {
  sim::ScenarioConfig config;
  config.duration_s = duration_s;
  config.seed = 3;
  const sim::ScenarioOutput out =
      sim::RunScenario(*sim::BuiltinWorld("rooms"), ShippedRobot(), config);
  return sim::BuildScans(ShippedRobot(), out.odometry, out.scanner);
}

TEST(BudgetedStep, PlansEachScanWithinItsQuotaSwitchesSetsAndSkipsWhatTheEngineRefuses) {
  const std::vector<Scan> scans = RoomScans(30.0);
  ASSERT_GT(scans.size(), 40u);
  BudgetSettings settings;
  settings.rays_per_scan = 8125;
  RayBudgetScheduler scheduler(settings);
  const ParamsChoice choice;  // the infrared scanner's shipped sets
  const ParamsSet first = choice.For(8125);
  SlamConfig config;
  config.parallel = false;
  Slam engine(ShippedRobot(), first.params, config);
  BudgetedStep step(engine, scheduler, choice, first, CpuClock::kThread);

  size_t k = 0;
  for (; k < 20; ++k) {
    const BudgetedStep::Result r = step.Run(scans[k]);
    ASSERT_TRUE(r.record) << k;
    EXPECT_EQ(r.report.usable_measurements, r.prepared.summary.usable_measurements);
    EXPECT_EQ(r.record->used_rays, r.report.rays.total());
    EXPECT_EQ(r.record->planned_rays, r.record->used_rays) << k;  // the engine's own accounting
    EXPECT_LE(r.record->used_rays, 8125);
  }
  EXPECT_GT(scheduler.totals().rays_used, 20 * 8125 * 9 / 10);  // and fills it
  EXPECT_EQ(step.switches(), 0);

  // A larger budget calls for its own set from the next scan on.
  settings.rays_per_scan = 65000;
  scheduler.SetSettings(settings);
  const BudgetedStep::Result bigger = step.Run(scans[k++]);
  ASSERT_TRUE(bigger.record);
  EXPECT_EQ(step.switches(), 1);
  EXPECT_EQ(step.in_use(), choice.For(65000));
  EXPECT_NE(step.in_use(), first);
  EXPECT_EQ(engine.params().particles, choice.For(65000).params.particles);
  EXPECT_GT(bigger.record->used_rays, 8125);

  // A scan the engine refuses did nothing: the scheduler learns nothing from it.
  Scan broken = scans[k];
  broken.odom_end.x = std::numeric_limits<double>::quiet_NaN();
  const int64_t recorded = scheduler.totals().scans;
  const BudgetedStep::Result refused = step.Run(broken);
  EXPECT_FALSE(refused.record);
  EXPECT_EQ(refused.report.refused, ScanRefusal::kNotFinite);
  EXPECT_EQ(scheduler.totals().scans, recorded);
  EXPECT_EQ(engine.scans_refused(), 1);

  // Odometry-only mapping: nothing matched, every usable reading updates.
  const BudgetedStep::Result mapping = step.Run(scans[k], /*refine=*/false);
  ASSERT_TRUE(mapping.record);
  EXPECT_EQ(mapping.report.rays.matching, 0);
  EXPECT_EQ(mapping.report.update_rays, mapping.prepared.summary.usable_measurements);
  EXPECT_EQ(mapping.record->planned_rays, mapping.record->used_rays);
}

TEST(BudgetedStep,
     WhileRelocalisingScansGoToTheRelocaliserWithinTheQuotaAndItsAnswerMovesTheEngine) {
  const std::vector<Scan> scans = RoomScans(120.0);
  BudgetSettings settings;
  settings.rays_per_scan = 16250;
  RayBudgetScheduler scheduler(settings);
  const ParamsChoice choice;
  const ParamsSet set = choice.For(16250);
  SlamConfig config;
  config.parallel = false;
  config.history_samples = false;
  Slam engine(ShippedRobot(), set.params, config);
  BudgetedStep step(engine, scheduler, choice, set, CpuClock::kThread);
  Relocalizer relocalizer;
  step.SetRelocalizer(&relocalizer);  // inactive: scans go to the engine
  size_t k = 0;
  for (; k < scans.size() && scans[k].t_end < 60.0; ++k) {
    const BudgetedStep::Result r = step.Run(scans[k]);
    ASSERT_FALSE(r.relocalization) << k;
    ASSERT_TRUE(r.record) << k;
  }
  // The robot is then carried: the engine is told it is half a metre and a quarter turn
  // from where it is, and relocalises on its own map.
  Slam reference = engine;  // goes on tracking undisturbed, for comparison
  RayBudgetScheduler reference_scheduler(settings);
  BudgetedStep reference_step(reference, reference_scheduler, choice, set, CpuClock::kThread);
  const Pose2 where = engine.Best().pose;
  ASSERT_TRUE(engine.Relocate(Compose(where, Pose2{0.5, 0.0, kPi / 2})));
  relocalizer.Start(engine.Best().map);
  const uint64_t map_version = engine.Best().map.Version();
  const int64_t processed = engine.scans_processed();
  const int64_t recorded = scheduler.totals().scans;
  bool relocated = false;
  for (; k < scans.size() && !relocated; ++k) {
    reference_step.Run(scans[k]);
    const BudgetedStep::Result r = step.Run(scans[k]);
    ASSERT_TRUE(r.relocalization) << k;
    EXPECT_FALSE(r.record);
    EXPECT_LE(r.relocalization->lookups, 16250 * kLookupsPerRay + 4 * 400) << k;
    relocated = r.relocated;
    if (!relocated) {
      EXPECT_EQ(engine.Best().map.Version(), map_version) << "mapped while lost";
    }
  }
  ASSERT_TRUE(relocated) << "not relocalised in 60 s";
  EXPECT_EQ(engine.scans_processed(), processed);  // the engine saw none of those scans
  EXPECT_EQ(scheduler.totals().scans, recorded);
  EXPECT_FALSE(relocalizer.active());
  // Back on track: the next scans go to the engine again, which tracks on to where the
  // undisturbed engine is (the answer is a few centimetres and degrees off; tracking mends it).
  const size_t end = std::min(scans.size(), k + 15);
  for (; k < end; ++k) {
    reference_step.Run(scans[k]);
    const BudgetedStep::Result next = step.Run(scans[k]);
    EXPECT_FALSE(next.relocalization);
    EXPECT_TRUE(next.record);
  }
  const Pose2 there = reference.Best().pose, found = engine.Best().pose;
  EXPECT_LT((found.translation() - there.translation()).norm(), 0.05)
      << found.x << " " << found.y << " vs " << there.x << " " << there.y;
  EXPECT_LT(std::abs(NormalizeAngle(found.theta - there.theta)), DegToRad(3.0));
}

TEST(BudgetedStep, LocalisingOnlyTracksOnTheMapAndNeverChangesACell) {
  const std::vector<Scan> scans = RoomScans(60.0);
  BudgetSettings settings;
  settings.rays_per_scan = 16250;
  RayBudgetScheduler scheduler(settings);
  const ParamsChoice choice;
  const ParamsSet set = choice.For(16250);
  SlamConfig config;
  config.parallel = false;
  Slam engine(ShippedRobot(), set.params, config);
  BudgetedStep step(engine, scheduler, choice, set, CpuClock::kThread);
  size_t k = 0;
  for (; k < scans.size() && scans[k].t_end < 40.0; ++k) ASSERT_TRUE(step.Run(scans[k]).record);
  Slam reference = engine;  // maps on, for comparison
  RayBudgetScheduler reference_scheduler(settings);
  BudgetedStep reference_step(reference, reference_scheduler, choice, set, CpuClock::kThread);
  const OccupancyGrid before = engine.Best().map;
  std::vector<std::array<LogOdds, kTileCells>> cells;  // copied: tiles are shared
  for (const TileRef& t : before.Tiles()) cells.push_back(t.tile->cells);
  step.SetLocalizeOnly(true);
  int64_t matching = 0;
  for (; k < scans.size(); ++k) {
    reference_step.Run(scans[k]);
    const BudgetedStep::Result r = step.Run(scans[k]);
    ASSERT_TRUE(r.record) << k;
    EXPECT_EQ(r.report.rays.update, 0) << k;
    EXPECT_LE(r.record->used_rays, 16250) << k;
    matching += r.report.rays.matching;
  }
  EXPECT_GT(matching, 0);
  // Every particle's map holds exactly the cells it had.
  for (const Particle& p : engine.particles()) {
    ASSERT_EQ(p.map.TileCount(), before.TileCount());
    size_t i = 0;
    for (const TileRef& t : before.Tiles()) {
      ASSERT_NE(p.map.FindTile(t.index), nullptr);
      EXPECT_EQ(p.map.FindTile(t.index)->cells, cells[i++]);
    }
  }
  // And it tracks as well as mapping on would (the robot drives where it mapped before).
  const Pose2 there = reference.Best().pose, here = engine.Best().pose;
  EXPECT_LT((here.translation() - there.translation()).norm(), 0.03);
  EXPECT_LT(std::abs(NormalizeAngle(here.theta - there.theta)), DegToRad(2.0));
}

/// A run of the rooms world simulated with `config`, stepped through `budget` by a serial engine
/// with the loss detector and the relocaliser; the truth to compare with.
struct RoomsThroughTheBudget {
  RoomsThroughTheBudget(const sim::ScenarioConfig& config, int64_t budget_rays)
      : budget(budget_rays),
        world(*sim::BuiltinWorld("rooms")),
        out(sim::RunScenario(world, ShippedRobot(), config)),
        scans(sim::BuildScans(ShippedRobot(), out.odometry, out.scanner)),
        scheduler([&] {
          BudgetSettings settings;
          settings.rays_per_scan = budget;
          return settings;
        }()),
        engine(ShippedRobot(), choice.For(budget).params,
               [] {
                 SlamConfig c;
                 c.parallel = false;
                 c.history_samples = false;
                 return c;
               }()),
        step(engine, scheduler, choice, choice.For(budget), CpuClock::kThread) {
    step.SetRelocalizer(&relocalizer);
    step.SetLossDetector(&detector);
    const Pose2 origin = *PoseAt(out.ground_truth, scans.front().t_begin);
    map_to_world = {origin.theta, origin.translation()};
  }

  /// Whether the scan spent more than its quota (rays, the loss check's lookups at its rate
  /// and the searches' at theirs); a search's last node may run past its share by one
  /// expansion (GlobalSearch::Continue).
  bool OverQuota(const BudgetedStep::Result& r) const {
    const int64_t rays = (r.record ? r.record->used_rays : 0) +
                         (r.loss_check ? LossDetector::RaysOf(r.loss_check->lookups) : 0);
    const int64_t lookups =
        r.relocalization ? r.relocalization->lookups : (r.watch ? r.watch->lookups : 0);
    return rays * kLookupsPerRay + lookups > (budget + 64) * kLookupsPerRay;
  }
  /// How far the engine's pose is from the truth at `t`: metres, degrees.
  std::pair<double, double> Error(double t) const {
    const Pose2 p = engine.Best().pose;
    const Pose2 truth = *PoseAt(out.ground_truth, t);
    return {(map_to_world.Apply(p.translation()) - truth.translation()).norm(),
            std::abs(RadToDeg(NormalizeAngle(p.theta + map_to_world.rotation_rad - truth.theta)))};
  }
  double Precision() const {
    return sim::EvaluateMap(engine.Best().map, map_to_world, world, out.ground_truth).precision;
  }

  const int64_t budget;
  const sim::World world;
  const sim::ScenarioOutput out;
  const std::vector<Scan> scans;
  RayBudgetScheduler scheduler;
  const ParamsChoice choice;
  Slam engine;
  BudgetedStep step;
  Relocalizer relocalizer;
  LossDetector detector;
  RigidTransform2 map_to_world;
};

/// A run of the rooms world with a tracked robot's odometry, kidnapped at `kidnap_s` (0: not)
/// to where it was at half that time, through the budget with the loss detector and the
/// relocaliser: what happened, against the ground truth.
struct KidnapRun {
  int losses = 0;
  double lost_t = -1.0, relocated_t = -1.0, reacquired_t = -1.0;  // -1: never
  int64_t over_quota_scans = 0;
  bool mapped_while_lost = false;
  double precision = 0.0;  // of the map at the end
};

KidnapRun RunKidnapped(double kidnap_s, uint64_t seed) {
  sim::ScenarioConfig config =
      sim::WithOdometryProfile(sim::ScenarioConfig{}, sim::OdometryProfile::kTracked);
  config.duration_s = 160.0;
  config.seed = seed;
  if (kidnap_s > 0.0) config.kidnap_t_s = kidnap_s;
  RoomsThroughTheBudget rig(config, 16250);
  KidnapRun run;
  uint64_t version = 0;
  for (const Scan& scan : rig.scans) {
    const BudgetedStep::Result r = rig.step.Run(scan);
    if (rig.OverQuota(r)) ++run.over_quota_scans;
    if (r.lost) {
      ++run.losses;
      if (run.lost_t < 0) run.lost_t = scan.t_end;
      version = rig.engine.Best().map.Version();
    }
    if (r.relocalization && !r.relocated && rig.engine.Best().map.Version() != version) {
      run.mapped_while_lost = true;
    }
    if (r.relocated && run.relocated_t < 0) run.relocated_t = scan.t_end;
    if (kidnap_s > 0 && scan.t_end > kidnap_s && run.reacquired_t < 0 && r.record &&
        PoseAt(rig.out.ground_truth, scan.t_end)) {
      const auto [error_m, error_deg] = rig.Error(scan.t_end);
      if (error_m < 0.05 && error_deg < 3.0) run.reacquired_t = scan.t_end;
    }
  }
  run.precision = rig.Precision();
  return run;
}

TEST(BudgetedStep, AKidnappedTrackerIsFoundLostStopsMappingAndIsReacquiredOnItsMap) {
  const KidnapRun calm = RunKidnapped(0.0, 2);
  EXPECT_EQ(calm.losses, 0) << "no loss where nothing happened";
  const KidnapRun run = RunKidnapped(100.0, 2);
  EXPECT_EQ(run.over_quota_scans, 0);
  EXPECT_EQ(run.losses, 1);
  EXPECT_GT(run.lost_t, 100.0);
  EXPECT_LT(run.lost_t, 110.0) << "found lost within seconds";
  EXPECT_FALSE(run.mapped_while_lost);
  EXPECT_GT(run.relocated_t, run.lost_t);
  EXPECT_GT(run.reacquired_t, 100.0) << "within 5 cm and 3 degrees of the truth";
  EXPECT_LT(run.reacquired_t, 120.0) << "within 20 s of driving";
  EXPECT_GT(run.precision, 0.8) << "one map";
  EXPECT_GT(run.precision, calm.precision - 0.05);
}

/// The rooms world with the shipped odometry, the loss detector and the watch, through the
/// budget; at `jump_s` (0: never) the engine's pose is moved 3 m away and turned, beyond the
/// rooms: where the map knows nothing, so the readings placed there contradict nothing and the
/// detector cannot tell (what a kidnap does when the odometry carries the tracker off the map).
struct WatchRun {
  int watch_relocations = 0, losses = 0, confirmed = 0;
  double relocated_t = -1.0;                            // the watch's first relocation
  double error_after_m = -1.0, error_after_deg = -1.0;  // the engine's, right after it
  int64_t over_quota_scans = 0;
  int64_t watch_lookups = 0;
};

WatchRun RunWatched(double jump_s) {
  sim::ScenarioConfig config;
  config.duration_s = 130.0;
  config.seed = 4;
  RoomsThroughTheBudget rig(config, 65000);
  rig.step.EnableWatch(WatchConfig{});
  WatchRun run;
  bool jumped = false;
  for (const Scan& scan : rig.scans) {
    if (jump_s > 0.0 && !jumped && scan.t_begin >= jump_s) {
      jumped = true;
      const Pose2 p = rig.engine.Best().pose;
      EXPECT_TRUE(rig.engine.Relocate(Pose2{p.x + 3.0, p.y - 3.0, p.theta + 1.5}));
      rig.step.RestartWatch();
    }
    const BudgetedStep::Result r = rig.step.Run(scan);
    if (rig.OverQuota(r)) ++run.over_quota_scans;
    if (r.watch) run.watch_lookups += r.watch->lookups;
    run.losses += r.lost ? 1 : 0;
    run.confirmed += r.watch && r.watch->found && !r.watch_relocated ? 1 : 0;
    if (r.watch_relocated) {
      EXPECT_TRUE(r.relocated);
      EXPECT_TRUE(r.relocalization && r.relocalization->found);
      if (run.watch_relocations++ == 0) {
        run.relocated_t = scan.t_end;
        std::tie(run.error_after_m, run.error_after_deg) = rig.Error(scan.t_end);
      }
    }
  }
  return run;
}

TEST(BudgetedStep, TheWatchFindsATrackerCarriedOffTheMapWhereTheDetectorSeesNothing) {
  const WatchRun calm = RunWatched(0.0);
  EXPECT_EQ(calm.watch_relocations, 0) << "no correction of a good track";
  EXPECT_GE(calm.confirmed, 1) << "the watch found the robot where the tracker had it";
  EXPECT_EQ(calm.over_quota_scans, 0);
  EXPECT_GT(calm.watch_lookups, 0);

  const WatchRun run = RunWatched(70.0);
  EXPECT_EQ(run.over_quota_scans, 0);
  EXPECT_EQ(run.losses, 0) << "the detector cannot see this one";
  ASSERT_GE(run.watch_relocations, 1);
  EXPECT_GT(run.relocated_t, 70.0);
  EXPECT_LT(run.relocated_t, 110.0) << "found within 40 s of driving";
  EXPECT_LT(run.error_after_m, 0.10);
  EXPECT_LT(run.error_after_deg, 5.0);
}

TEST(BudgetedStep, WatchConfigValidates) {
  EXPECT_TRUE(WatchConfig{}.Validate().empty());
  WatchConfig bad;
  bad.share = 0.0;
  bad.distinct_m = -1.0;
  bad.distinct_deg = 200.0;
  bad.max_tracked_score = 1.5;
  bad.margin = -0.1;
  bad.refresh_after_unsure = 0;
  const ConfigErrors errors = bad.Validate();
  ASSERT_EQ(errors.size(), 6u);
  EXPECT_EQ(errors.front().pointer, "/share");
}
}  // namespace
}  // namespace slam
