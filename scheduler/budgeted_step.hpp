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
};

}  // namespace slam
