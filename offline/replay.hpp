#pragma once
// Runs the engine over the scans of a recorded experiment at a ray budget, as slam-replay, the
// reference table and the tuner's fitness do: mapping from nothing, or localising on a map it is
// given (from a pose, or relocalising first), with stretches of the recording left out (an
// artificial kidnap). Deterministic in rays-per-scan mode: the same inputs and seed give the
// same trajectory and map, with the engine's parallel path or without (CPU-share mode depends
// on measured time by design).

#include <atomic>
#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "engine/loss_detector.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/params.hpp"
#include "engine/pose.hpp"
#include "engine/quality.hpp"
#include "engine/relocalizer.hpp"
#include "engine/robot.hpp"
#include "engine/scan.hpp"
#include "engine/slam.hpp"
#include "scheduler/budgeted_step.hpp"
#include "scheduler/params_catalog.hpp"
#include "scheduler/ray_budget_scheduler.hpp"

namespace slam::offline {

/// The engine's defaults, but resolution_m 0: the robot's cell size (DefaultResolution).
inline SlamConfig RobotResolutionConfig() {
  SlamConfig config;
  config.resolution_m = 0.0;
  return config;
}

/// A stretch of a recording: from t0_s (included) to t1_s (excluded), in seconds after the
/// first scan's start (Scan::t_begin of the first scan given to the replay).
struct TimeInterval {
  double t0_s = 0.0;
  double t1_s = 0.0;
  bool Contains(double t_s) const { return t_s >= t0_s && t_s < t1_s; }
};

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

  /// A map to start from (Slam::Restore: every particle on it), of the config's resolution once
  /// resolved (DefaultResolution when 0); none: mapping from nothing at the origin.
  std::optional<OccupancyGrid> map;
  /// Where the robot is on `map` at the start of the first scan replayed; none (or a pose the
  /// engine refuses, Slam::AcceptsPose): the replay starts by relocalising on the whole map (a
  /// Relocalizer paid from the scans' quotas; nothing is matched or mapped until it answers).
  std::optional<Pose2> start_pose;
  /// No update ray is cast: the map is never changed (BudgetedStep::SetLocalizeOnly).
  bool localize_only = false;
  /// Scans that begin in one of these stretches are left out. The engine's motion model takes
  /// each scan's odometry from its own start to its end, so the robot moves on while the
  /// engine's pose stays: a kidnap. Stretches before the first scan replayed only cut the
  /// recording's start.
  std::vector<TimeInterval> drop;
  /// After a stretch left out (once a scan was replayed), the replay relocalises on the best
  /// particle's map (`map`, or what was mapped so far), as slamd does when told the robot was
  /// moved (POST /api/v1/relocalize): the kidnap announced. False: the engine tracks on from
  /// where it was, unaware, unless the loss detector finds it lost.
  bool relocalize_after_drop = true;
  RelocalizerConfig relocalizer;
  /// With it, each scan tracked is first checked against the map (BudgetedStep::
  /// SetLossDetector): a loss takes back what the lost tracker mapped and relocalises. None (the
  /// default, as the tuner and the reference table replay): no check.
  std::optional<LossDetectorConfig> loss_detector;
  /// With it and the loss detector, the background check as well (BudgetedStep::EnableWatch):
  /// a confirmed answer away from the tracked pose moves the engine there.
  std::optional<WatchConfig> watch;
  /// Keep every relocaliser search's outcome in ReplayResult::searches (slam-replay
  /// --log-searches): what a relocalisation saw before it answered, or why it never did.
  bool log_searches = false;
};

/// Why a replay relocalised.
enum class RelocalizationStart {
  kStart,  // on `map` without a start pose
  kDrop,   // after a stretch left out
  kLost,   // the loss detector found the tracker lost
  kWatch,  // the background check found the robot elsewhere (the tracker was lost)
};
/// "start", "drop", "lost", "watch".
const char* ToString(RelocalizationStart start);

/// One answer of the relocaliser during a replay.
struct ReplayRelocalization {
  RelocalizationStart cause = RelocalizationStart::kStart;
  double started_t = 0.0;  // start of the first scan it was given (the scans' clock)
  double t = 0.0;          // end of the scan that completed it: the time of `pose`
  Relocalization found;    // its pose, score, runner-up, points, lookups and searches
  int64_t scans = 0;       // scans it was given, that one included
  bool taken = true;       // false: the engine refused the pose and the search started over
};

/// How a relocaliser search ended (ReplayOptions::log_searches).
enum class SearchOutcome {
  kUnsure,       // no unique place scoring accept_score: the robot gathers readings, searches again
  kUnconfirmed,  // an answer that its confirmation from farther on did not score
  kAnswer,       // the relocaliser's answer
};
/// "unsure", "unconfirmed", "answer".
const char* ToString(SearchOutcome outcome);

/// One relocaliser search that ended.
struct ReplaySearch {
  double t = 0.0;  // end of the scan it ended at (the scans' clock): the time of the poses
  SearchOutcome outcome = SearchOutcome::kUnsure;
  /// Unsure: every distinct place its checks scored, best first; unconfirmed: the
  /// confirmation's best; an answer: the answer. Poses carried to `t`.
  std::vector<GlobalMatch> places;
  int points = 0;  // an answer's multiscan readings (0 otherwise)
  /// What it cost: the relocaliser's lookups (fields' builds included) and the scans it took,
  /// since the search logged before it (or since the relocaliser started).
  int64_t lookups = 0;
  int64_t scans = 0;
};

struct ReplayResult {
  std::vector<TimedPose> trajectory;  // best particle's, from the first scan's start
  OccupancyGrid map;                  // best particle's
  /// Against the ground truth, when there is one (without its poses in `untracked`).
  std::optional<TrajectoryQuality> quality;
  /// ... and the frame most of the trajectory agrees with (AlignOnMajority: a stretch tracked
  /// off, then re-found, left out): the relocalisations' errors are judged in it, and the map's
  /// quality in it or the ATE's alignment, whichever the map fits better.
  std::optional<RigidTransform2> map_alignment;
  int64_t scans = 0;  // scans replayed (fewer than given when cancelled)
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
  int64_t scans_dropped = 0;  // left out by ReplayOptions::drop
  /// Every relocaliser answer, in order; the lookups every search cost (taken or not), the
  /// scans given to the relocaliser, and whether it was still searching at the end (since
  /// `relocalizing_since_t`, the scans' clock).
  std::vector<ReplayRelocalization> relocalizations;
  /// Where the engine had no pose of its own (between the last scan it processed and the next
  /// one, across scans left out or given to the relocaliser), in seconds after the first scan's
  /// start. The quality leaves the ground truth there out: the trajectory's line across such a
  /// stretch is no estimate.
  std::vector<TimeInterval> untracked;
  int64_t lookups_total = 0;
  /// Scans at which the loss detector found the tracker lost (each started a relocalisation).
  int64_t losses = 0;
  std::vector<double> loss_times_s;  // their scans' starts, seconds after the first scan's
  /// The loss detector's largest contradicting share over its window, and the end of the scan
  /// it was drawn at (the scans' clock): how near the run came to a loss (0 without a detector).
  double loss_share_max = 0.0;
  double loss_share_max_t = 0.0;
  /// Relocaliser searches that ended unsure (no unique answer scoring accept_score: the robot
  /// gathers readings and searches again), and the best of them (its fine check, or the coarse
  /// best), its distinct runner-up's score and the end time of its scan: what was seen when the
  /// robot is not found.
  int64_t searches_unsure = 0;
  std::optional<GlobalMatch> best_unsure;
  double best_unsure_runner_up = 0.0;
  double best_unsure_t = 0.0;
  int64_t relocalizing_scans = 0;
  std::vector<ReplaySearch> searches;  // with ReplayOptions::log_searches, in order
  /// The background check's (ReplayOptions::watch): lookups spent, searches that ended unsure,
  /// answers at the tracked pose.
  int64_t watch_lookups = 0, watch_unsure = 0, watch_confirmed = 0;
  bool relocalizing_at_end = false;
  double relocalizing_since_t = 0.0;
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
/// Preconditions: robot, params and config valid; a `map` of the resolved resolution.
ReplayResult Replay(const RobotDescription& robot, const std::vector<Scan>& scans,
                    const std::vector<TimedPose>& ground_truth, const ReplayOptions& options);

}  // namespace slam::offline
