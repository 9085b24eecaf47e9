#pragma once
// Runs the engine over the scans of a recorded experiment at a ray budget, as slam-replay, the
// reference table and the tuner's fitness do. Deterministic in rays-per-scan mode: the same
// inputs and seed give the same trajectory and map, with the engine's parallel path or without
// (CPU-share mode depends on measured time by design).

#include <atomic>
#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "engine/occupancy_grid.hpp"
#include "engine/params.hpp"
#include "engine/pose.hpp"
#include "engine/quality.hpp"
#include "engine/robot.hpp"
#include "engine/scan.hpp"
#include "engine/slam.hpp"
#include "scheduler/params_catalog.hpp"
#include "scheduler/ray_budget_scheduler.hpp"

namespace slam::offline {

/// The engine's defaults, but resolution_m 0: the robot's cell size (DefaultResolution).
inline SlamConfig RobotResolutionConfig() {
  SlamConfig config;
  config.resolution_m = 0.0;
  return config;
}

struct ReplayOptions {
  /// The parameters: one set (here the paper's untuned Table II defaults), or the shipped sets
  /// chosen by each scan's quota (ParamsChoice{}: what the tools do without --params).
  ParamsChoice params{"table-ii", SlamParams{}};
  /// Seed and parallel among others. Its resolution_m of 0 (the default here) means the robot's
  /// cell size (DefaultResolution: 1 cm for the marXbot's scanner, 5 cm for a laser).
  SlamConfig config = RobotResolutionConfig();
  BudgetSettings budget;  // rays per scan or CPU share, fixed or adaptive policy
  SchedulerConfig scheduler;
  bool refine = true;  // false: phase B off, odometry-only mapping
  /// Called after every scan with (scans done, scans in all); may be empty.
  std::function<void(size_t, size_t)> progress;
  /// When it becomes true, the scan in progress skips its remaining refinement candidates and
  /// the replay stops after it (a cancelled tuning job at a large budget must not finish a
  /// whole experiment, nor a scan of seconds, first): the result covers the scans done and
  /// says `cancelled`. May be null.
  const std::atomic<bool>* cancel = nullptr;
  /// With ground truth: the replay stops once no later scan can bring its e (eq. 9) down to
  /// this, that is once ErrorLowerBound over every particle's history exceeds it (checked every
  /// few scans, never after the last): a tuner's candidate that can no longer enter the elite.
  /// The result then says `stopped_early` and holds the bound. Infinity: never.
  double stop_above_e = std::numeric_limits<double>::infinity();
};

struct ReplayResult {
  std::vector<TimedPose> trajectory;         // best particle's, from the first scan's start
  OccupancyGrid map;                         // best particle's
  std::optional<TrajectoryQuality> quality;  // against the ground truth, when there is one
  int64_t scans = 0;                         // scans replayed (fewer than given when cancelled)
  bool cancelled = false;
  /// Stopped by `stop_above_e`; every e the full replay could score is at least `e_lower_bound`.
  bool stopped_early = false;
  double e_lower_bound = 0.0;
  int64_t rays_total = 0;
  int64_t rays_per_scan_max = 0;
  int64_t resamplings = 0;
  /// Scans the engine refused (Slam::ProcessScan: odometry not finite, faster than the robot
  /// drives, or beyond the map's bound): the pose held across them.
  int64_t scans_refused = 0;
  ParamsSet params_set;           // the parameter set of the last scan
  int64_t params_switches = 0;    // scans whose set differed from the previous scan's
  std::vector<PlanRecord> plans;  // one per scan: the scheduler's plan and what it used
  double wall_s = 0.0;
  double cpu_s =
      0.0;  // CPU time of the run: this thread's with a serial engine, else the process's

  explicit ReplayResult(OccupancyGrid final_map) : map(std::move(final_map)) {}
};

/// The command-line help of slam-replay's and slam-evaluate's --heading-sweep-turn
/// (SlamConfig::heading_sweep_turn_deg).
inline constexpr char kHeadingSweepTurnHelp[] =
    "a range scanner's heading sweep: when the odometry turned by more than this many degrees "
    "over a scan, phase B also tries headings over +-60 % of the turn (0: never; docs/laser.md)";

/// The odometry-only trajectory of `scans`, as the engine with phase B off builds it: from the
/// origin at the first scan's start, every sample's pose and each scan's end pose, scans chained
/// end to end.
std::vector<TimedPose> DeadReckoning(const std::vector<Scan>& scans);

/// Replays `scans` through the engine under the ray-budget scheduler. In CPU-share mode the cost
/// per ray is measured on this thread's CPU time with a serial engine, else on the process's.
/// Preconditions: robot, params and config valid.
ReplayResult Replay(const RobotDescription& robot, const std::vector<Scan>& scans,
                    const std::vector<TimedPose>& ground_truth, const ReplayOptions& options);

}  // namespace slam::offline
