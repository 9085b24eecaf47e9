#include "server/slam_service.hpp"

#include <pthread.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <utility>

#include "engine/cell_encoding.hpp"
#include "engine/thread_safety.hpp"

namespace slam::server {
namespace {

constexpr double kTruthPeriodS = 0.1;   // ground truth kept at 10 Hz
constexpr double kTruthWindowS = 30.0;  // world-frame truth kept for alignment and errors

int64_t SteadyNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

std::vector<const TrajectoryChunk*> Chunks(const std::shared_ptr<const TrajectoryChunk>& last) {
  std::vector<const TrajectoryChunk*> chunks;
  for (const TrajectoryChunk* c = last.get(); c != nullptr; c = c->parent.get()) {
    chunks.push_back(c);
  }
  std::reverse(chunks.begin(), chunks.end());
  return chunks;
}

// At most this many ground-truth poses, evenly spread over the run, enter the live error: its
// cost per scan stays bounded however long slamd runs.
constexpr size_t kMaxErrorPoses = 2000;

struct TruthErrors {
  double ate_m = 0.0;         // RMS residual over the run so far
  double pose_error_m = 0.0;  // residual of the latest ground-truth pose the estimate spans
};

// The estimate against the ground truth as the ATE measures it: both aligned by the rigid
// transform that fits the whole run so far best. Aligning at the first pose only would charge
// the start's heading error to every later pose (several times the ATE of the same run).
// nullopt until two ground-truth poses fall within the estimate.
std::optional<TruthErrors> ErrorsAgainstTruth(const std::vector<TimedPose>& estimate,
                                              const std::vector<TimedPose>& truth) {
  if (estimate.size() < 2 || truth.empty()) return std::nullopt;
  const auto first = std::lower_bound(truth.begin(), truth.end(), estimate.front().t,
                                      [](const TimedPose& p, double t) { return p.t < t; });
  const auto end = std::upper_bound(truth.begin(), truth.end(), estimate.back().t,
                                    [](double t, const TimedPose& p) { return t < p.t; });
  if (end - first < 2) return std::nullopt;
  const size_t span = static_cast<size_t>(end - first);
  const size_t stride = (span + kMaxErrorPoses - 1) / kMaxErrorPoses;
  std::vector<TimedPose> sample;
  sample.reserve(span / stride + 2);
  for (size_t i = 0; i < span; i += stride) sample.push_back(*(first + static_cast<long>(i)));
  if (sample.back().t != std::prev(end)->t) sample.push_back(*std::prev(end));  // the latest
  const std::optional<TrajectoryQuality> quality = EvaluateTrajectory(estimate, sample);
  const std::optional<Pose2> latest = PoseAt(estimate, sample.back().t);
  if (!quality || !latest) return std::nullopt;
  TruthErrors errors;
  errors.ate_m = quality->ate_rmse_m;
  errors.pose_error_m =
      (quality->alignment.Apply(latest->translation()) - sample.back().pose.translation()).norm();
  return errors;
}

}  // namespace

const char* ToString(SlamState state) {
  switch (state) {
    case SlamState::kWaiting:
      return "waiting";
    case SlamState::kRunning:
      return "running";
    case SlamState::kRelocalizing:
      return "relocalizing";
  }
  return "unknown";
}

const std::vector<double>& LatencyBuckets() {
  static const std::vector<double> buckets{0.001, 0.002, 0.005, 0.01, 0.02, 0.05,
                                           0.1,   0.2,   0.5,   1.0,  2.0,  5.0};
  return buckets;
}

std::vector<TimedPose> ScanEndTrajectory(const SlamSnapshot& snapshot) {
  std::vector<TimedPose> out;
  if (snapshot.resumed) out = *snapshot.resumed;
  bool first = true;
  for (const TrajectoryChunk* chunk : Chunks(snapshot.history)) {
    if (chunk->poses.empty()) continue;
    if (first) {  // where this run started
      TimedPose start = chunk->poses.front();
      start.t += snapshot.time_offset_s;
      if (out.empty() || start.t > out.back().t) out.push_back(start);
      first = false;
    }
    TimedPose end = chunk->poses.back();
    end.t += snapshot.time_offset_s;
    if (out.empty() || end.t > out.back().t) out.push_back(end);
  }
  return out;
}

OccupancyGrid SnapshotGrid(const SlamSnapshot& snapshot, int encoded_logodds_limit) {
  OccupancyGrid grid(GridGeometry(snapshot.resolution_m), encoded_logodds_limit);
  grid.BeginWrite();
  for (const TileRef& ref : snapshot.tiles) {
    Tile& tile = grid.MutableTile(ref.index);
    tile.cells = ref.tile->cells;
    tile.version = ref.tile->version;
  }
  return grid;
}

SlamService::SlamService(hw::Link& link, sim::VirtualMarxbotSource* truth_source,
                         const ServiceOptions& options)
    : link_(link),
      truth_source_(truth_source),
      options_(options),
      scheduler_(options.budget, options.scheduler),
      assembler_(options.robot, options.assembler),
      relocalizer_(options.relocalizer),
      loss_detector_(options.loss_detector),
      params_(options.params.ForRobot(options.robot)) {
  options_.config.parallel = false;
  // slamd serves, saves and evaluates scan ends only (ScanEndTrajectory).
  options_.config.history_samples = false;
  {
    MutexLock lock(mutex_);
    revised_params_ = params_.For(scheduler_.Quota(last_period_s_));
  }
  counters_.latency_counts.assign(LatencyBuckets().size() + 1, 0);
  if (options_.resume) {
    version_base_ = options_.resume->version;
    resumed_ = std::make_shared<const std::vector<TimedPose>>(options_.resume->trajectory);
    if (!options_.resume->trajectory.empty()) {
      // This run's robot clock starts over: its times follow the resumed ones after a second.
      time_offset_s_ = options_.resume->trajectory.back().t + 1.0;
    }
  }
  BuildEngine();
  Publish(std::nullopt);
}

SlamService::~SlamService() { Stop(); }

void SlamService::Start() {
  thread_ = std::thread([this] {
    pthread_setname_np(pthread_self(), "slam");
    Run();
  });
}

void SlamService::Stop() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
}

int SlamService::encoded_logodds_limit() const {
  return EncodeLogOdds(options_.config.logodds_limit);
}

void SlamService::BuildEngine() {
  double period = 0.0;
  ParamsChoice choice;
  {
    MutexLock lock(mutex_);
    choice = params_;
    params_changed_ = false;
    period = last_period_s_;
  }
  const ParamsSet set = choice.For(scheduler_.Quota(period));
  engine_ = std::make_unique<Slam>(options_.robot, set.params, options_.config);
  step_ = std::make_unique<BudgetedStep>(*engine_, scheduler_, std::move(choice), set,
                                         CpuClock::kThread);
  engine_->set_interrupt(&stop_);  // a scan of a huge budget ends soon after Stop()
  step_->SetRelocalizer(&relocalizer_);
  step_->SetLocalizeOnly(options_.localize_only);
  if (options_.detect_loss) step_->SetLossDetector(&loss_detector_);
  relocalizer_.Cancel();
  relocalizing_.reset();
  if (options_.resume) {
    const SavedState& saved = *options_.resume;
    OccupancyGrid grid(GridGeometry(options_.config.resolution_m), encoded_logodds_limit());
    grid.BeginWrite();
    for (const SavedTile& tile : saved.tiles) {
      std::copy(tile.cells.begin(), tile.cells.end(), grid.MutableTile(tile.index).cells.begin());
    }
    // Where the robot is on the map is known only when given: it may have been carried while
    // slamd was off (the virtual marXbot starts over from its start pose), and mapping from a
    // wrong pose draws a second copy of the room over the first.
    const Pose2 pose = options_.resume_pose.value_or(Pose2{});
    // slamd validates a given pose; one beyond the map's bound got here anyway: relocalise.
    const bool given = options_.resume_pose && engine_->Restore(grid, pose);
    if (!given) {
      engine_->Restore(grid, Pose2{});
      if (grid.Tiles().empty()) return;  // nothing to find the robot in: map from the origin
      StartRelocalizing(RelocalizationCause::kResume);
    }
  }
}

ParamsSet SlamService::Params() const {
  MutexLock lock(mutex_);
  return params_.For(scheduler_.Quota(last_period_s_));
}

ParamsSet SlamService::ShippedParamsNow() const {
  MutexLock lock(mutex_);
  return ShippedParamsFor(scheduler_.Quota(last_period_s_), FamilyOf(options_.robot));
}

bool SlamService::ParamsFollowQuota() const {
  MutexLock lock(mutex_);
  return params_.follows_quota();
}

uint64_t SlamService::ParamsRevision() const {
  MutexLock lock(mutex_);
  return params_revision_;
}

void SlamService::SetParams(const std::string& name, const SlamParams& params) {
  MutexLock lock(mutex_);
  params_ = ParamsChoice(name, params);
  params_changed_ = true;
  ReviseParams();
}

SlamService::RevisedParams SlamService::ParamsRevised() const {
  MutexLock lock(mutex_);
  return {params_.For(scheduler_.Quota(last_period_s_)), params_revision_};
}

SlamService::RevisedParams SlamService::ResetParams() {
  MutexLock change_lock(params_change_mutex_);
  UseShippedParams();
  return ParamsRevised();
}

SlamService::ParamsChange SlamService::ChangeParams(
    const std::function<bool(uint64_t revision)>& precondition,
    const std::function<Result<SlamParams>(const SlamParams&, const SlamParams&)>& change) {
  MutexLock change_lock(params_change_mutex_);
  ParamsChange out;
  out.revision = ParamsRevision();
  if (!precondition(out.revision)) {
    out.precondition_failed = true;
    return out;
  }
  const ParamsSet current = Params();
  const ParamsSet shipped = ShippedParamsNow();
  const Result<SlamParams> changed = change(current.params, shipped.params);
  if (!changed.ok()) {
    out.errors = changed.errors();
    return out;
  }
  out.params = changed.value();
  if (!(out.params == current.params)) {
    if (out.params == shipped.params) {
      // Every change undone (null resets to the shipped set): the sets follow the budget again.
      UseShippedParams();
    } else {
      // Named after the set it was patched from; it stays in use whatever the budget.
      constexpr std::string_view kPatched = ", patched";
      const bool patched = current.name.ends_with(kPatched);
      SetParams(patched ? current.name : current.name + std::string(kPatched), out.params);
    }
  }
  out.revision = ParamsRevision();
  return out;
}

void SlamService::UseShippedParams() {
  MutexLock lock(mutex_);
  params_ = ParamsChoice(FamilyOf(options_.robot));
  params_changed_ = true;
  ReviseParams();
}

SlamService::RevisedBudget SlamService::BudgetRevised() const {
  MutexLock lock(budget_mutex_);
  return {scheduler_.settings(), budget_revision_};
}

SlamService::BudgetChange SlamService::ChangeBudget(
    const std::function<bool(uint64_t revision)>& precondition,
    const std::function<Result<BudgetSettings>(const BudgetSettings&)>& change) {
  MutexLock budget_lock(budget_mutex_);
  BudgetChange out;
  out.budget = scheduler_.settings();
  out.revision = budget_revision_;
  if (!precondition(budget_revision_)) {
    out.precondition_failed = true;
    return out;
  }
  const Result<BudgetSettings> changed = change(out.budget);
  if (!changed.ok()) {
    out.errors = changed.errors();
    return out;
  }
  if (!(changed.value() == out.budget)) {
    scheduler_.SetSettings(changed.value());
    out.budget = changed.value();
    out.revision = ++budget_revision_;
    MutexLock lock(mutex_);
    ReviseParams();  // another quota may call for another shipped set
  }
  return out;
}

void SlamService::SetBudget(const BudgetSettings& settings) {
  ChangeBudget([](uint64_t) { return true; },
               [&](const BudgetSettings&) -> Result<BudgetSettings> { return settings; });
}

void SlamService::ReviseParams() {
  const ParamsSet& now = params_.For(scheduler_.Quota(last_period_s_));
  if (now == revised_params_) return;  // every scan: compared in place, copied on change only
  revised_params_ = now;
  ++params_revision_;
}

void SlamService::FollowPeriod(double scan_period_s) {
  MutexLock lock(mutex_);
  last_period_s_ = scan_period_s;
  ReviseParams();  // a CPU share's quota moves with the measured cost per ray
}

void SlamService::RequestReset() {
  MutexLock lock(mutex_);
  reset_requested_ = true;
}

std::shared_ptr<const SlamSnapshot> SlamService::Snapshot() const {
  MutexLock lock(mutex_);
  return snapshot_;
}

std::shared_ptr<const SlamSnapshot> SlamService::WaitNewer(
    uint64_t sequence, std::chrono::milliseconds timeout) const {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  MutexLock lock(mutex_);
  while (snapshot_->sequence <= sequence && !stop_) {
    if (lock.WaitUntil(published_, deadline) == std::cv_status::timeout) break;
  }
  return snapshot_;
}

ServiceCounters SlamService::Counters() const {
  MutexLock lock(mutex_);
  return counters_;
}

std::vector<TimedPose> SlamService::GroundTruth() const {
  MutexLock lock(mutex_);
  return truth_map_;
}

void SlamService::ApplyCommands() {
  bool reset = false;
  bool relocalize = false;
  std::optional<PoseRequest> pose;
  std::optional<ParamsChoice> params;
  {
    MutexLock lock(mutex_);
    std::swap(reset, reset_requested_);
    std::swap(relocalize, relocalize_requested_);
    std::swap(pose, pose_requested_);
    if (params_changed_) params = params_;
    params_changed_ = false;
    if (reset) {
      truth_map_.clear();
      ++counters_.resets;
      version_base_ = snapshot_->map_version + 1;  // versions keep growing across a reset
    }
  }
  if (reset) {
    ++epoch_;
    options_.resume.reset();
    resumed_.reset();
    scan_points_.reset();
    world_to_map_.reset();
    BuildEngine();
    Publish(std::nullopt);
  } else if (params) {
    step_->SetChoice(*params);  // the next scan takes the set of its quota
  }
  // A reset forgets the map: a pose on it or a search in it means nothing any more.
  if (pose && !reset) {
    ApplyPose(*pose);
    Publish(std::nullopt);
  } else if (relocalize && !reset) {
    StartRelocalizing(RelocalizationCause::kRequest);
    std::fprintf(stderr, "slamd: relocalising on the map, as requested\n");
    Publish(std::nullopt);
  }
}

void SlamService::Run() {
  std::vector<Scan> scans;
  while (!stop_) {
    ApplyCommands();
    hw::LinkEvent event;
    if (!link_.PopWait(event, std::chrono::milliseconds(100))) {
      // Idle: publish the assembler's counters (ProcessScan does it after every scan).
      MutexLock lock(mutex_);
      counters_.assembler = assembler_.counters();
      continue;
    }
    scans.clear();
    assembler_.Add(event.event, scans);
    for (const Scan& scan : scans) {
      ApplyCommands();
      ProcessScan(scan, event.receive_ns);
    }
  }
  {
    MutexLock lock(mutex_);
    published_.notify_all();
  }
}

void SlamService::UpdateGroundTruth() {
  if (!truth_source_) return;
  std::vector<TimedPose> fresh;
  truth_read_ = truth_source_->GroundTruthSince(truth_read_, fresh);
  for (const TimedPose& p : fresh) {
    if (truth_world_.empty() || p.t - truth_world_.back().t >= kTruthPeriodS) {
      truth_world_.push_back(p);
    }
  }
  // The world-frame truth is only needed near the present (alignment and pose errors).
  if (!truth_world_.empty()) {
    const double keep_from = truth_world_.back().t - kTruthWindowS;
    const auto first = std::find_if(truth_world_.begin(), truth_world_.end(),
                                    [&](const TimedPose& p) { return p.t >= keep_from; });
    truth_world_.erase(truth_world_.begin(), first);
  }
}

void SlamService::ProcessScan(const Scan& scan, int64_t receive_ns) {
  const int64_t wall_start = SteadyNs();
  const double period = scan.t_end - scan.t_begin;
  FollowPeriod(period);
  const BudgetedStep::Result step = step_->Run(scan);
  last_odom_ = scan.odom_end;
  last_t_end_ = scan.t_end;
  if (step.lost) NoteLoss(*step.loss_check);
  if (step.relocalization) {
    ProcessRelocalizingScan(step, scan, period, wall_start, receive_ns);
    return;
  }
  if (!step.record) {  // refused by the engine
    MutexLock lock(mutex_);
    ++counters_.refused_scans;
    return;
  }
  // For viewers (Foxglove's /scan): a few hundred points, outside the scan's CPU account.
  if (options_.scan_points) {
    scan_points_ = std::make_shared<const std::vector<Vec2>>(engine_->ReadingPoints(step.prepared));
  }
  ScanMetrics m = MetricsOf(step, period, wall_start, receive_ns);
  UpdateGroundTruth();
  CountScan(m, period, NewlyMappedTruth());
  MeasureAgainstTruth(m);
  Publish(m);
}

void SlamService::Time(ScanMetrics& m, const BudgetedStep::Result& step, double period,
                       int64_t wall_start, int64_t receive_ns) {
  const int64_t now = SteadyNs();
  m.scan_period_s = period;
  m.busy_s = static_cast<double>(now - wall_start) * 1e-9;
  m.latency_s = static_cast<double>(now - receive_ns) * 1e-9;
  m.cpu_s = step.cpu_s;
  m.cpu_share = period > 0.0 ? step.cpu_s / period : 0.0;
  m.realtime_ratio = m.busy_s > 0.0 ? period / m.busy_s : 0.0;
  m.late = period > 0.0 && m.latency_s > period;
}

ScanMetrics SlamService::MetricsOf(const BudgetedStep::Result& step, double period,
                                   int64_t wall_start, int64_t receive_ns) const {
  const ScanReport& report = step.report;
  const PlanRecord& record = *step.record;
  ScanMetrics m;
  m.scan = engine_->scans_processed();
  m.quota = step.quota;  // the whole quota (the plan's share of it is record.quota)
  m.rays_planned = record.planned_rays;
  m.rays_used = record.used_rays;
  m.particles = report.particles;
  m.candidates = report.candidates;
  m.ess = report.effective_sample_size;
  Time(m, step, period, wall_start, receive_ns);
  m.lookups = step.loss_check ? step.loss_check->lookups : 0;  // the loss detector's check
  return m;
}

std::vector<TimedPose> SlamService::NewlyMappedTruth() {
  // Ground truth (virtual marXbot): the map frame is the engine's, whose origin is the robot's
  // pose at the first scan's start; align the world frame to it once, at that moment.
  std::vector<TimedPose> newly_mapped;
  if (!truth_source_) return newly_mapped;
  const auto history = engine_->Best().history;
  if (!world_to_map_ && history) {
    const TrajectoryChunk* first = Chunks(history).front();
    if (!first->poses.empty()) {
      const TimedPose& start = first->poses.front();
      if (const auto truth = PoseAt(truth_world_, start.t)) {
        const Pose2 t = Compose(start.pose, Inverse(*truth));
        world_to_map_ = RigidTransform2{t.theta, {t.x, t.y}};
        for (const TimedPose& p : truth_world_) {
          if (p.t >= start.t) newly_mapped.push_back(p);
        }
      }
    }
  } else if (world_to_map_) {
    // Poses newer than the last mapped one.
    double last_t = -1e300;
    {
      MutexLock lock(mutex_);
      if (!truth_map_.empty()) last_t = truth_map_.back().t - time_offset_s_;
    }
    for (const TimedPose& p : truth_world_) {
      if (p.t > last_t) newly_mapped.push_back(p);
    }
  }
  if (world_to_map_) {
    newly_mapped = TransformTrajectory(*world_to_map_, newly_mapped);
    for (TimedPose& p : newly_mapped) p.t += time_offset_s_;
  }
  return newly_mapped;
}

void SlamService::CountCommon(ServiceCounters& c, const ScanMetrics& m, double period) {
  ++c.scans;
  c.late_scans += m.late ? 1 : 0;
  c.busy_s += m.busy_s;
  c.cpu_s += m.cpu_s;
  c.robot_s += period;
  const auto& bounds = LatencyBuckets();
  const size_t bucket = static_cast<size_t>(
      std::lower_bound(bounds.begin(), bounds.end(), m.latency_s) - bounds.begin());
  ++c.latency_counts[bucket];
  c.latency_sum_s += m.latency_s;
}

void SlamService::CountScan(const ScanMetrics& m, double period,
                            const std::vector<TimedPose>& newly_mapped) {
  MutexLock lock(mutex_);
  ServiceCounters& c = counters_;
  c.state = SlamState::kRunning;
  CountCommon(c, m, period);
  c.rays_planned += m.rays_planned;
  c.rays_used += m.rays_used;
  c.assembler = assembler_.counters();
  truth_map_.insert(truth_map_.end(), newly_mapped.begin(), newly_mapped.end());
}

void SlamService::MeasureAgainstTruth(ScanMetrics& m) {
  if (!world_to_map_) return;
  std::vector<TimedPose> estimate;  // this run's scan ends, in the ground truth's time
  for (const TrajectoryChunk* chunk : Chunks(engine_->Best().history)) {
    if (chunk->poses.empty()) continue;
    TimedPose end = chunk->poses.back();
    end.t += time_offset_s_;
    if (estimate.empty() || end.t > estimate.back().t) estimate.push_back(end);
  }
  std::optional<TruthErrors> errors;
  {
    MutexLock lock(mutex_);  // truth_map_ is written on this thread only; readers copy it
    errors = ErrorsAgainstTruth(estimate, truth_map_);
  }
  if (errors) {
    m.ate_m = errors->ate_m;
    m.pose_error_m = errors->pose_error_m;
  }
}

void SlamService::Publish(const std::optional<ScanMetrics>& metrics) {
  auto s = std::make_shared<SlamSnapshot>();
  s->sequence = ++sequence_;
  s->epoch = epoch_;
  s->version_base = version_base_;
  s->resolution_m = options_.config.resolution_m;
  const Particle& best = engine_->Best();
  s->tiles = best.map.Tiles();
  s->map_version = version_base_ + best.map.Version();
  s->history = best.history;
  s->resumed = resumed_;
  s->scan_points = scan_points_;
  s->time_offset_s = time_offset_s_;
  if (best.history && !best.history->poses.empty()) {
    s->has_pose = true;
    s->pose = best.history->poses.back();
    s->pose.t += time_offset_s_;
  } else if (resumed_ && !resumed_->empty()) {
    s->has_pose = true;
    s->pose = resumed_->back();
  }
  s->last = metrics;
  s->relocalizing = relocalizing_;
  s->last_relocalization = last_relocalization_;
  if (relocalizing_ && !places_.empty()) {  // a new search clears them (StartRelocalizing, a loss)
    for (GlobalMatch place : places_) {
      if (last_odom_) place.pose = Compose(place.pose, Between(places_odom_, *last_odom_));
      s->relocalization_places.push_back(place);
    }
    s->relocalization_places_t = last_t_end_ + time_offset_s_;
  }
  if (world_to_map_ && s->has_pose) {
    if (const auto truth = PoseAt(truth_world_, s->pose.t - time_offset_s_)) {
      const Vec2 p = world_to_map_->Apply(truth->translation());
      s->truth = Pose2{p.x(), p.y(), NormalizeAngle(truth->theta + world_to_map_->rotation_rad)};
    }
  }
  {
    MutexLock lock(mutex_);
    snapshot_ = std::move(s);
  }
  published_.notify_all();
}

}  // namespace slam::server
