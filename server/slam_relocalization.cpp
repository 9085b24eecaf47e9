// The service's relocalisation bookkeeping: starting and ending searches (a loss, a hint, a
// pose, a request), the scans that go to the relocaliser, and what they leave for the status
// (the last answer, the places the robot may be).
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "engine/thread_safety.hpp"
#include "server/slam_service.hpp"

namespace slam::server {

const char* ToString(RelocalizationCause cause) {
  switch (cause) {
    case RelocalizationCause::kResume:
      return "resume";
    case RelocalizationCause::kRequest:
      return "request";
    case RelocalizationCause::kHint:
      return "hint";
    case RelocalizationCause::kLost:
      return "lost";
  }
  return "unknown";
}

ConfigErrors ValidatePoseRequest(const PoseRequest& request, double resolution_m) {
  ConfigErrors errors;
  const Pose2& p = request.pose;
  if (!std::isfinite(p.x)) errors.push_back({"/x", "must be a finite number of metres"});
  if (!std::isfinite(p.y)) errors.push_back({"/y", "must be a finite number of metres"});
  if (!std::isfinite(p.theta)) errors.push_back({"/theta_deg", "must be a finite number"});
  if (errors.empty() && !GridGeometry(resolution_m).InMapBound(p.translation())) {
    errors.push_back({"", "the position is beyond the map's bound"});
  }
  if (request.sigma_m && !(*request.sigma_m > 0.0 && *request.sigma_m <= 50.0)) {
    errors.push_back({"/sigma_m", "must be above 0 and at most 50 (metres)"});
  }
  if (request.sigma_deg && !(*request.sigma_deg > 0.0 && *request.sigma_deg <= 180.0)) {
    errors.push_back({"/sigma_deg", "must be above 0 and at most 180 (degrees)"});
  }
  return errors;
}

void SlamService::BeginSearch(RelocalizationCause cause) {
  relocalizing_ = cause;
  places_.clear();
  relocalizing_since_t_ = -1.0;
  relocalizing_scans_ = 0;
}

void SlamService::NoteLoss(const LossCheck& check) {
  BeginSearch(RelocalizationCause::kLost);  // the step has started the relocaliser
  {
    MutexLock lock(mutex_);
    ++counters_.losses;
  }
  std::fprintf(stderr,
               "slamd: the tracker is lost (%.0f %% of the readings checked over the last scans "
               "land where the map is free): what it mapped meanwhile is taken back, and it "
               "relocalises\n",
               100.0 * check.window_share);
}

void SlamService::StartRelocalizing(RelocalizationCause cause, const GlobalRegion& region) {
  relocalizer_.Start(engine_->Best().map, region, last_odom_);
  BeginSearch(cause);
  MutexLock lock(mutex_);
  counters_.state = SlamState::kRelocalizing;
}

void SlamService::ApplyPose(const PoseRequest& request) {
  // A hint on a map with nothing in it has nothing to be searched for: the pose is taken as is.
  const bool mapped = !engine_->Best().map.Tiles().empty();
  if (mapped && (request.sigma_m || request.sigma_deg)) {
    GlobalRegion region;
    region.whole_map = false;
    region.center = request.pose.translation();
    region.half_width_m = 3.0 * request.sigma_m.value_or(PoseRequest::kDefaultHintSigmaM);
    region.heading = request.pose.theta;
    region.half_angle_rad = std::min(
        kPi, DegToRad(3.0 * request.sigma_deg.value_or(PoseRequest::kDefaultHintSigmaDeg)));
    StartRelocalizing(RelocalizationCause::kHint, region);
    std::fprintf(stderr,
                 "slamd: relocalising around the pose given (%.3f, %.3f, %.1f deg), within "
                 "%.2f m and %.0f deg\n",
                 request.pose.x, request.pose.y, RadToDeg(request.pose.theta), region.half_width_m,
                 RadToDeg(region.half_angle_rad));
    return;
  }
  relocalizer_.Cancel();
  relocalizing_.reset();
  const bool taken = engine_->Relocate(request.pose);  // validated: always taken
  MutexLock lock(mutex_);
  if (taken) ++counters_.poses_set;
  if (counters_.state == SlamState::kRelocalizing) {
    counters_.state = counters_.scans > 0 ? SlamState::kRunning : SlamState::kWaiting;
  }
}

void SlamService::RequestPose(const PoseRequest& request) {
  MutexLock lock(mutex_);
  pose_requested_ = request;
  relocalize_requested_ = false;  // the latest request wins
}

bool SlamService::RequestRelocalize() {
  MutexLock lock(mutex_);
  if (snapshot_->tiles.empty()) return false;
  relocalize_requested_ = true;
  pose_requested_.reset();
  return true;
}

Result<Pose2> SlamService::KidnapSimulatedRobot(const std::optional<Pose2>& target) {
  if (truth_source_ == nullptr) return Error("the source is not the virtual marXbot");
  return truth_source_->Kidnap(target);
}

void SlamService::ProcessRelocalizingScan(const BudgetedStep::Result& step, const Scan& scan,
                                          double period, int64_t wall_start, int64_t receive_ns) {
  const RelocalizerStep& r = *step.relocalization;
  if (options_.scan_points) {
    scan_points_ = std::make_shared<const std::vector<Vec2>>(engine_->ReadingPoints(step.prepared));
  }
  ScanMetrics m;
  m.scan = engine_->scans_processed();
  m.quota = step.quota;
  m.relocalizing = true;
  m.lookups = r.lookups;
  m.particles = static_cast<int>(engine_->particles().size());
  Time(m, step, period, wall_start, receive_ns);
  if (relocalizing_since_t_ < 0.0) relocalizing_since_t_ = scan.t_begin;
  ++relocalizing_scans_;
  const RelocalizationCause cause = relocalizing_.value_or(RelocalizationCause::kRequest);
  if (r.rejected_best) {
    places_ = r.rejected_candidates;
    places_odom_ = scan.odom_end;
  }
  if (r.found && step.relocated) {
    RelocalizationRecord record;
    record.cause = cause;
    record.t = scan.t_end + time_offset_s_;
    record.pose = r.found->pose;
    record.score = r.found->score;
    record.runner_up_score = r.found->runner_up_score;
    record.points = r.found->points;
    record.searches = r.found->searches;
    record.lookups = r.found->lookups;
    record.scans = relocalizing_scans_;
    record.search_s = scan.t_end - relocalizing_since_t_;
    last_relocalization_ = record;
    relocalizing_.reset();
    std::fprintf(stderr,
                 "slamd: relocalised (%s) at (%.3f, %.3f, %.1f deg), score %.2f, %d readings, "
                 "%d searches, %.1f M lookups over %d scans (%.1f s)\n",
                 ToString(cause), record.pose.x, record.pose.y, RadToDeg(record.pose.theta),
                 record.score, record.points, record.searches,
                 static_cast<double>(record.lookups) * 1e-6, record.scans, record.search_s);
  }
  {
    MutexLock lock(mutex_);
    ServiceCounters& c = counters_;
    CountCommon(c, m, period);
    ++c.relocalizing_scans;
    c.relocalization_lookups += r.lookups;
    c.relocalization_searches_unsure += r.rejected_best ? 1 : 0;
    if (r.found) ++(step.relocated ? c.relocalizations : c.relocalizations_refused);
    c.state = relocalizer_.active() ? SlamState::kRelocalizing : SlamState::kRunning;
    c.assembler = assembler_.counters();
  }
  Publish(m);
}

}  // namespace slam::server
