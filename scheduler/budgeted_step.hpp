#pragma once
// One scan through the ray budget: the sequence every user of the engine runs (offline replay,
// slamd). The parameter set the scan's quota calls for, the scan prepared once, planned by the
// scheduler within its quota, processed by the engine, and the engine's report given back to the
// scheduler (what the rays cost, what the filter's belief looks like).

#include <cstdint>
#include <deque>
#include <optional>

#include "engine/loss_detector.hpp"
#include "engine/relocalizer.hpp"
#include "engine/scan.hpp"
#include "engine/slam.hpp"
#include "scheduler/params_catalog.hpp"
#include "scheduler/ray_budget_scheduler.hpp"

namespace slam {

/// How CPU time is counted: the whole process's (an engine with worker threads, run alone) or
/// the calling thread's (engines running side by side, each on its own thread).
enum class CpuClock { kProcess, kThread };
/// CPU seconds so far on `clock`.
double CpuSeconds(CpuClock clock);

/// The background check's options (BudgetedStep::EnableWatch).
struct WatchConfig {
  /// Of each scan's quota, spent on the watch's fields and searches.
  double share = 0.1;
  /// The watch's relocaliser: as the relocaliser's, but its window never widens (a widened
  /// window reaches back over a kidnap).
  RelocalizerConfig relocalizer = [] {
    RelocalizerConfig c;
    c.max_window_s = c.window_s;
    c.max_points = 250;
    c.search.min_score = 0.6;
    c.search.unique_ratio = 0.85;
    return c;
  }();
  /// An answer this far from the tracked pose on an axis, or turned this much, is elsewhere.
  double distinct_m = 0.3;
  double distinct_deg = 10.0;
  /// ... and taken only when the tracked pose explains the readings badly (its fine score at
  /// most this) and the answer far better (by at least `margin`): a multiscan may fit a
  /// symmetric twin of a room, or a place a few tens of centimetres off, nearly as well as the
  /// truth, and a false correction breaks a good track.
  double max_tracked_score = 0.5;
  double margin = 0.25;
  /// Searches in a row ending unsure after which the snapshot is renewed (the robot may be
  /// where the snapshot has not mapped yet).
  int refresh_after_unsure = 2;

  /// Out-of-range values as JSON pointers; empty when valid.
  ConfigErrors Validate() const;
};

class BudgetedStep {
 public:
  /// `engine` and `scheduler` must outlive the step. `choice` gives the set of each quota;
  /// `in_use` is the set the engine runs now.
  BudgetedStep(Slam& engine, RayBudgetScheduler& scheduler, ParamsChoice choice, ParamsSet in_use,
               CpuClock clock);

  /// The sets to choose from, from the next scan on.
  void SetChoice(ParamsChoice choice) { choice_ = std::move(choice); }
  /// The set the engine runs with.
  const ParamsSet& in_use() const { return in_use_; }
  /// How many times a scan's quota switched the engine to another set.
  int64_t switches() const { return switches_; }

  /// The relocalisation stage (may be null; must outlive its use here): while it is active
  /// (Relocalizer::Start), each scan goes to it instead of the engine, with the scan's whole
  /// quota as lookups (kLookupsPerRay), nothing matched and the map untouched; its answer
  /// moves the engine there (Slam::Relocate), and the engine maps again from the next scan.
  void SetRelocalizer(Relocalizer* relocalizer) { relocalizer_ = relocalizer; }
  /// Localisation only (true): scans are matched as planned, but no update ray is cast, so the
  /// map is never changed (a robot localising on a map it has, slamd --localize).
  void SetLocalizeOnly(bool localize_only) { localize_only_ = localize_only; }
  /// The loss detector (may be null; must outlive its use here): each scan the engine tracks is
  /// first checked against the map of some scans ago (LossDetectorConfig::history_scans; its
  /// cost reserved from the quota); when the detector says the tracker is lost, the map goes
  /// back to that one (what the lost tracker mapped is taken back), that scan and the next go to
  /// the relocaliser (Relocalizer::Start on that map), and Result::lost says so. Needs a
  /// relocaliser.
  void SetLossDetector(LossDetector* detector);
  bool localize_only() const { return localize_only_; }

  /// The background check, "where else?" (needs the loss detector; off until called). The
  /// detector only sees readings that contradict the map: a tracker carried by the odometry
  /// into a part of the map that holds nothing yet (a kidnap's usual aftermath) or onto a
  /// symmetric twin of the room is never contradicted. So while the engine tracks, a
  /// relocaliser of the step's own (the watch) searches the whole map for the last seconds'
  /// readings, anytime, from `config.share` of each scan's quota (reserved from the plan as the
  /// detector's check is). Its map is a snapshot, never newer than the detector's reference (the
  /// map some scans ago): readings are searched on a map they did not draw. The tracked pose
  /// is the search's rival (Relocalizer::SetRival). When its confirmed answer (the
  /// relocaliser's own checks: unique, confirmed seconds apart) is distinct from the tracked
  /// pose, and the tracked pose explains the readings badly and the answer far better
  /// (WatchConfig::max_tracked_score, margin), the tracker was lost: the map goes back to the
  /// snapshot (what the lost tracker drew since is taken back), the engine is moved to the
  /// answer, and the scan reports it (Result::watch_relocated). An answer at the tracked pose
  /// vouches for the map: the next search runs on a snapshot of then. A search that ends unsure
  /// keeps the snapshot (a kidnap in the middle of a multiscan muddles it; the next one is
  /// clean) until `config.refresh_after_unsure` did in a row. Experimental: off in slamd, and
  /// `slam-replay --watch` (docs/accuracy.md has what it finds and where it errs).
  /// Precondition: config.Validate() is empty.
  void EnableWatch(const WatchConfig& config);
  /// After the engine was moved or its map changed from outside (a pose set by hand): the
  /// watch starts over on the map of then, with readings from then on.
  void RestartWatch() {
    if (watch_) watch_->Cancel();
  }

  struct Result {
    PreparedScan prepared;  // the scan as the engine measured it (refers to the scan)
    ScanReport report;
    /// The scheduler's record of the scan; none when the engine refused it (the scheduler
    /// learns nothing from a scan that did nothing).
    std::optional<PlanRecord> record;
    double cpu_s = 0.0;  // the whole step's
    int64_t quota = 0;   // the scan's quota, rays
    /// Set when the scan went to the relocaliser (then `report` is empty and `record` none):
    /// what it spent and found.
    std::optional<RelocalizerStep> relocalization;
    /// The engine took the relocaliser's answer (false: it refused the pose, see
    /// Slam::AcceptsPose, and the relocaliser searches again).
    bool relocated = false;
    /// The loss detector's check of the scan, when it ran.
    std::optional<LossCheck> loss_check;
    /// The detector found the tracker lost at this scan: the relocaliser started.
    bool lost = false;
    /// The watch's step of this scan, when it ran.
    std::optional<RelocalizerStep> watch;
    /// The watch found the robot elsewhere than the tracked pose (`watch_from`, this scan's end
    /// as the engine predicted it): the engine took its answer. Then `relocalization` is that
    /// step and `relocated` true, as for the relocaliser's answers, and nothing was matched.
    bool watch_relocated = false;
    Pose2 watch_from;
  };
  /// Runs one scan; `refine` false maps on the odometry alone (phase B off, nothing matched).
  Result Run(const Scan& scan, bool refine = true);

 private:
  Slam& engine_;
  RayBudgetScheduler& scheduler_;
  ParamsChoice choice_;
  ParamsSet in_use_;
  CpuClock clock_;
  Relocalizer* relocalizer_ = nullptr;
  bool localize_only_ = false;
  LossDetector* detector_ = nullptr;
  /// The best particle's map before each of the detector's latest history_scans scans (tiles
  /// shared): the oldest is what scans are checked against, and what a loss goes back to.
  std::deque<OccupancyGrid> history_;
  int64_t switches_ = 0;
  /// Starts the watch on `map` (its snapshot).
  void StartWatch(const OccupancyGrid& map);
  WatchConfig watch_config_;
  std::optional<Relocalizer> watch_;
  std::optional<OccupancyGrid> watch_map_;  // the watch's snapshot
  int watch_unsure_ = 0;                    // its searches in a row that ended unsure
};

}  // namespace slam
