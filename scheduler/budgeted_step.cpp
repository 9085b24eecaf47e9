#include "scheduler/budgeted_step.hpp"

#include <time.h>

#include <cmath>
#include <optional>
#include <utility>
#include <vector>

namespace slam {

BudgetedStep::BudgetedStep(Slam& engine, RayBudgetScheduler& scheduler, ParamsChoice choice,
                           ParamsSet in_use, CpuClock clock)
    : engine_(engine),
      scheduler_(scheduler),
      choice_(std::move(choice)),
      in_use_(std::move(in_use)),
      clock_(clock) {}

void BudgetedStep::SetLossDetector(LossDetector* detector) {
  detector_ = detector;
  history_.clear();
  if (detector_ != nullptr) detector_->Reset();
}

ConfigErrors WatchConfig::Validate() const {
  ConfigErrors errors;
  if (!(share > 0.0 && share <= 0.5)) errors.push_back({"/share", "must be in (0, 0.5]"});
  if (!(distinct_m > 0.0 && std::isfinite(distinct_m))) {
    errors.push_back({"/distinct_m", "must be a positive number of metres"});
  }
  if (!(distinct_deg > 0.0 && distinct_deg <= 180.0)) {
    errors.push_back({"/distinct_deg", "must be in (0, 180] degrees"});
  }
  if (!(max_tracked_score >= 0.0 && max_tracked_score <= 1.0)) {
    errors.push_back({"/max_tracked_score", "must be in [0, 1]"});
  }
  if (!(margin >= 0.0 && margin <= 1.0)) errors.push_back({"/margin", "must be in [0, 1]"});
  if (refresh_after_unsure < 1) {
    errors.push_back({"/refresh_after_unsure", "must be at least 1"});
  }
  return errors;
}

void BudgetedStep::EnableWatch(const WatchConfig& config) {
  watch_config_ = config;
  watch_.emplace(config.relocalizer);
  watch_unsure_ = 0;
}

void BudgetedStep::StartWatch(const OccupancyGrid& map) {
  watch_map_ = map;
  watch_->Start(*watch_map_);
  watch_unsure_ = 0;
}

double CpuSeconds(CpuClock clock) {
  timespec now{};
  ::clock_gettime(clock == CpuClock::kProcess ? CLOCK_PROCESS_CPUTIME_ID : CLOCK_THREAD_CPUTIME_ID,
                  &now);
  return static_cast<double>(now.tv_sec) + 1e-9 * static_cast<double>(now.tv_nsec);
}

BudgetedStep::Result BudgetedStep::Run(const Scan& scan, bool refine) {
  Result result;
  const double cpu_start = CpuSeconds(clock_);
  const double period = scan.t_end - scan.t_begin;
  // A CPU share's quota moves with the measured cost per ray, and may call for another set.
  const int64_t quota = scheduler_.Quota(period);
  result.quota = quota;
  const ParamsSet& set = choice_.For(quota);
  if (set != in_use_) {
    engine_.SetParams(set.params);
    in_use_ = set;
    ++switches_;
  }
  result.prepared = engine_.Prepare(scan);
  int64_t reserved = 0;
  // The scan's readings in the robot's frame, for the detector and the relocaliser: computed
  // once, when one of them wants them.
  std::optional<std::vector<Vec2>> points;
  const auto readings = [&]() -> const std::vector<Vec2>& {
    if (!points) points = engine_.ReadingPoints(result.prepared);
    return *points;
  };
  if (detector_ != nullptr && relocalizer_ != nullptr && !relocalizer_->active() && refine) {
    const Pose2 predicted = Compose(engine_.Best().pose, Between(scan.odom_begin, scan.odom_end));
    // Checked against the map as it was some scans ago: a lost tracker maps what it sees where
    // it wrongly thinks it is, and its next scans would agree with that.
    const OccupancyGrid& reference = history_.empty() ? engine_.Best().map : history_.front();
    result.loss_check = detector_->Check(reference, predicted, readings());
    // What it spent is taken from the plan's rays (as the watch's below): a check costs from a
    // few cells a reading (one next to a wall) to a ray's traversal (one seen through a wall).
    reserved = LossDetector::RaysOf(result.loss_check->lookups);
    history_.push_back(engine_.Best().map);
    while (history_.size() > static_cast<size_t>(detector_->config().history_scans)) {
      history_.pop_front();
    }
    if (result.loss_check->lost) {
      const OccupancyGrid before = history_.front();
      engine_.ReplaceMap(before);
      relocalizer_->Start(before);
      history_.clear();
      detector_->Reset();
      result.lost = true;
      if (watch_) watch_->Cancel();
    } else if (watch_) {
      // Never on a map newer than the detector's reference: the oldest one kept.
      if (!watch_->active() && history_.front().HasTiles()) StartWatch(history_.front());
      if (watch_->active()) {
        const auto share = static_cast<int64_t>(watch_config_.share * static_cast<double>(quota));
        // The multiscan is placed by the odometry, as the relocaliser's: a lost tracker's own
        // poses smear it (placed by them, it fitted the truth worse after a kidnap and a
        // symmetric twin better before one: docs/accuracy.md). The tracked pose is its rival.
        watch_->SetRival(predicted, scan.odom_end);
        RelocalizerStep w =
            watch_->Add(readings(), scan.odom_end, scan.t_end, share * kLookupsPerRay);
        // What it spent is taken from the plan's rays (it may have spent nothing, gathering).
        reserved += (w.lookups + kLookupsPerRay - 1) / kLookupsPerRay;
        if (w.rejected_best && ++watch_unsure_ >= watch_config_.refresh_after_unsure) {
          StartWatch(history_.front());
        }
        if (w.found) {
          const Pose2 d = Between(predicted, w.found->pose);
          const bool elsewhere = d.translation().norm() >= watch_config_.distinct_m ||
                                 std::abs(d.theta) >= DegToRad(watch_config_.distinct_deg);
          const bool better = w.found->rival_score <= watch_config_.max_tracked_score &&
                              w.found->score >= w.found->rival_score + watch_config_.margin;
          if (elsewhere && better && engine_.AcceptsPose(w.found->pose)) {
            engine_.ReplaceMap(*watch_map_);
            result.relocated = engine_.Relocate(w.found->pose);
            result.watch_relocated = result.relocated;
            result.watch_from = predicted;
            history_.clear();
            detector_->Reset();
            result.watch = w;
            result.relocalization = std::move(w);
            result.cpu_s = CpuSeconds(clock_) - cpu_start;
            return result;
          }
          // Found where the tracker is: the next search runs on a newer snapshot.
        }
        result.watch = std::move(w);
      }
    }
  }
  if (relocalizer_ != nullptr && relocalizer_->active()) {
    if (watch_) watch_->Cancel();  // the map it watched may not be the engine's afterwards
    // The detector's check of a scan found lost came out of the same quota.
    const int64_t checked =
        result.loss_check ? LossDetector::RaysOf(result.loss_check->lookups) : 0;
    RelocalizerStep step = relocalizer_->Add(readings(), scan.odom_end, scan.t_end,
                                             (quota - checked) * kLookupsPerRay);
    if (step.found) {
      result.relocated = engine_.Relocate(step.found->pose);
      if (!result.relocated) relocalizer_->Start(engine_.Best().map);
    }
    if (result.relocated && detector_ != nullptr) {  // a new start: the window begins again
      detector_->Reset();
      history_.clear();
    }
    result.relocalization = std::move(step);
    result.cpu_s = CpuSeconds(clock_) - cpu_start;
    return result;
  }
  ScanSummary summary = result.prepared.summary;
  if (!refine) {  // phase B off: nothing to match
    summary.matching_measurements = 0;
    summary.matching_available = 0;
  }
  ScanPlan plan = scheduler_.Plan(summary, period, engine_.params(), reserved);
  plan.refine = refine;
  if (localize_only_) plan.update_rays = 0;
  result.report = engine_.ProcessScan(result.prepared, plan);
  result.cpu_s = CpuSeconds(clock_) - cpu_start;
  if (result.report.refused == ScanRefusal::kNone)
    result.record = scheduler_.Record(result.report, result.cpu_s);
  return result;
}

}  // namespace slam
