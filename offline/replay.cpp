#include "offline/replay.hpp"

#include <algorithm>
#include <chrono>
#include <limits>
#include <optional>

#include "scheduler/budgeted_step.hpp"

namespace slam::offline {
namespace {

constexpr double kNoStop = std::numeric_limits<double>::infinity();

bool Dropped(const std::vector<TimeInterval>& drop, double t_s) {
  return std::any_of(drop.begin(), drop.end(),
                     [&](const TimeInterval& d) { return d.Contains(t_s); });
}

/// The replay's account of each relocalisation and of where the engine had no pose of its own.
class LocalizationLog {
 public:
  LocalizationLog(double t_origin, bool log_searches)
      : t_origin_(t_origin), log_searches_(log_searches) {}

  /// A relocalisation starts (the relocaliser was just started) before the scan beginning at t.
  void Start(RelocalizationStart cause, double t) {
    relocalizing_ = true;
    if (cause == RelocalizationStart::kLost || cause == RelocalizationStart::kWatch) {
      ++losses_;
      loss_times_.push_back(t - t_origin_);
    }
    cause_ = cause;
    since_t_ = t;
    scans_ = 0;
    search_lookups_ = search_scans_ = 0;
  }
  /// A scan was left out.
  void Dropped() { untracked_since_ = tracked_; }
  /// What the step did with `scan`.
  void Step(const Scan& scan, const BudgetedStep::Result& step) {
    last_given_end_ = scan.t_end;
    if (step.watch) {
      watch_lookups_ += step.watch->lookups;
      watch_unsure_ += step.watch->rejected_best ? 1 : 0;
      watch_confirmed_ += step.watch->found && !step.watch_relocated ? 1 : 0;
    }
    if (step.loss_check && step.loss_check->window_share > share_max_) {
      share_max_ = step.loss_check->window_share;
      share_max_t_ = scan.t_end;
    }
    if (!step.relocalization) {
      if (step.report.refused != ScanRefusal::kNone) return;  // the pose held
      if (untracked_since_ && tracked_) {
        result_untracked_.push_back({tracked_until_ - t_origin_, scan.t_begin - t_origin_});
      }
      untracked_since_ = false;
      tracked_ = true;
      tracked_until_ = scan.t_end;
      return;
    }
    const RelocalizerStep& r = *step.relocalization;
    untracked_since_ = tracked_;
    ++scans_;
    ++scans_total_;
    if (!step.watch_relocated) lookups_ += r.lookups;  // the watch's are counted above
    search_lookups_ += r.lookups;
    ++search_scans_;
    const bool search_ended = r.rejected_best || r.found;
    if (log_searches_ && search_ended) {
      ReplaySearch search;
      search.t = scan.t_end;
      search.lookups = search_lookups_;
      search.scans = search_scans_;
      if (r.found) {
        search.outcome = SearchOutcome::kAnswer;
        search.places.push_back({r.found->pose, 0, r.found->score});
        search.points = r.found->points;
      } else {
        search.outcome =
            r.rejected_confirmation ? SearchOutcome::kUnconfirmed : SearchOutcome::kUnsure;
        search.places = r.rejected_candidates;
        if (search.places.empty()) search.places.push_back(*r.rejected_best);
      }
      searches_.push_back(std::move(search));
    }
    if (search_ended) search_lookups_ = search_scans_ = 0;
    if (r.rejected_best) {
      ++unsure_;
      if (!best_unsure_ || r.rejected_best->score > best_unsure_->score) {
        best_unsure_ = r.rejected_best;
        best_unsure_runner_up_ = r.rejected_runner_up;
        best_unsure_t_ = scan.t_end;
      }
    }
    if (!r.found || !relocalizing_) return;
    ReplayRelocalization answer;
    answer.cause = cause_;
    answer.started_t = since_t_;
    answer.t = scan.t_end;
    answer.found = *r.found;
    answer.scans = scans_;
    answer.taken = step.relocated;
    answers_.push_back(answer);
    if (step.relocated) {
      relocalizing_ = false;
    } else {  // the step started the search over
      since_t_ = scan.t_end;
      scans_ = 0;
    }
  }
  /// Into `result`; `still_searching`: the relocaliser is active at the end.
  void Finish(bool still_searching, ReplayResult& result) {
    if (still_searching && tracked_) {  // lost to the end
      result_untracked_.push_back({tracked_until_ - t_origin_, last_given_end_ - t_origin_});
    }
    result.untracked = std::move(result_untracked_);
    result.relocalizations = std::move(answers_);
    result.lookups_total = lookups_;
    result.losses = losses_;
    result.loss_times_s = std::move(loss_times_);
    result.loss_share_max = share_max_;
    result.loss_share_max_t = share_max_t_;
    result.searches_unsure = unsure_;
    result.best_unsure = best_unsure_;
    result.best_unsure_runner_up = best_unsure_runner_up_;
    result.best_unsure_t = best_unsure_t_;
    result.relocalizing_scans = scans_total_;
    result.searches = std::move(searches_);
    result.watch_lookups = watch_lookups_;
    result.watch_unsure = watch_unsure_;
    result.watch_confirmed = watch_confirmed_;
    result.relocalizing_at_end = still_searching;
    result.relocalizing_since_t = still_searching ? since_t_ : 0.0;
  }

 private:
  double t_origin_;
  bool log_searches_;
  std::vector<ReplaySearch> searches_;
  bool relocalizing_ = false;
  RelocalizationStart cause_ = RelocalizationStart::kStart;
  double since_t_ = 0.0;
  int64_t scans_ = 0, scans_total_ = 0, lookups_ = 0, unsure_ = 0, losses_ = 0;
  int64_t watch_lookups_ = 0, watch_unsure_ = 0, watch_confirmed_ = 0;
  int64_t search_lookups_ = 0, search_scans_ = 0;  // since the last search ended
  std::optional<GlobalMatch> best_unsure_;
  double best_unsure_runner_up_ = 0.0, best_unsure_t_ = 0.0;
  double share_max_ = 0.0, share_max_t_ = 0.0;
  std::vector<double> loss_times_;
  std::vector<ReplayRelocalization> answers_;
  // Whether the engine processed a scan, the end of the last one, whether scans went elsewhere
  // since, and the end of the last scan given to the step.
  bool tracked_ = false;
  double tracked_until_ = 0.0;
  bool untracked_since_ = false;
  double last_given_end_ = 0.0;
  std::vector<TimeInterval> result_untracked_;
};

}  // namespace

const char* ToString(RelocalizationStart start) {
  switch (start) {
    case RelocalizationStart::kStart:
      return "start";
    case RelocalizationStart::kDrop:
      return "drop";
    case RelocalizationStart::kLost:
      return "lost";
    case RelocalizationStart::kWatch:
      return "watch";
  }
  return "?";
}

const char* ToString(SearchOutcome outcome) {
  switch (outcome) {
    case SearchOutcome::kUnsure:
      return "unsure";
    case SearchOutcome::kUnconfirmed:
      return "unconfirmed";
    case SearchOutcome::kAnswer:
      return "answer";
  }
  return "?";
}

std::vector<TimedPose> DeadReckoning(const std::vector<Scan>& scans) {
  std::vector<TimedPose> trajectory;
  if (scans.empty()) return trajectory;
  Pose2 start;
  trajectory.push_back({scans.front().t_begin, start});
  for (const Scan& scan : scans) {
    // As the engine's history: a sample at the scan's start is the previous end pose, samples
    // that share a time give one pose, and the end pose is added unless the last sample is at
    // the scan's end.
    const size_t first = trajectory.size();
    for (const ScanSample& sample : scan.samples) {
      if (sample.t <= scan.t_begin ||
          (trajectory.size() > first && sample.t <= trajectory.back().t))
        continue;
      trajectory.push_back({sample.t, Compose(start, Between(scan.odom_begin, sample.odom))});
    }
    start = Compose(start, Between(scan.odom_begin, scan.odom_end));
    if (trajectory.size() == first || trajectory.back().t < scan.t_end) {
      trajectory.push_back({scan.t_end, start});
    }
  }
  return trajectory;
}

ReplayResult Replay(const RobotDescription& robot, const std::vector<Scan>& scans,
                    const std::vector<TimedPose>& ground_truth, const ReplayOptions& options) {
  RayBudgetScheduler scheduler(options.budget, options.scheduler);
  // The set of the first scan's quota builds the engine; later scans switch sets when their quota
  // (a CPU share's) calls for another one.
  const ParamsChoice params = options.params.ForRobot(robot);  // a laser's shipped family
  const ParamsSet& first = params.For(
      scheduler.Quota(scans.empty() ? 0.0 : scans.front().t_end - scans.front().t_begin));
  SlamConfig config = options.config;
  if (config.resolution_m == 0.0) config.resolution_m = DefaultResolution(robot);
  Slam engine(robot, first.params, config);
  engine.set_interrupt(options.cancel);  // a scan of a huge budget ends soon after a cancel
  // The whole process's CPU time when the engine may use worker threads, else this thread's (so
  // that replays running side by side each measure their own).
  const CpuClock clock = options.config.parallel ? CpuClock::kProcess : CpuClock::kThread;
  BudgetedStep stepper(engine, scheduler, params, first, clock);
  stepper.SetLocalizeOnly(options.localize_only);
  Relocalizer relocalizer(options.relocalizer);
  stepper.SetRelocalizer(&relocalizer);
  std::optional<LossDetector> detector;
  if (options.loss_detector) {
    detector.emplace(*options.loss_detector);
    stepper.SetLossDetector(&*detector);
    if (options.watch) stepper.EnableWatch(*options.watch);
  }
  const double t_origin = scans.empty() ? 0.0 : scans.front().t_begin;
  LocalizationLog log(t_origin, options.log_searches);
  bool relocalize_first = false;  // on `map`, from the first scan replayed
  if (options.map) {
    const bool placed = options.start_pose && engine.Restore(*options.map, *options.start_pose);
    if (!placed) {
      engine.Restore(*options.map, Pose2{});
      relocalize_first = options.map->HasTiles();  // else nothing to find the robot in
    }
  }
  bool replayed_any = false, left_out = false;
  int64_t dropped = 0;
  int64_t rays_total = 0, rays_max = 0, resamplings = 0;
  std::vector<PlanRecord> plans;
  plans.reserve(scans.size());
  const auto wall_start = std::chrono::steady_clock::now();
  const double cpu_start = CpuSeconds(clock);
  size_t done = 0;
  bool cancelled = false, stopped_early = false;
  double e_lower_bound = 0.0;
  // The early stop's bound costs a pass over the histories: checked about 32 times a replay.
  const bool bound_checks = !ground_truth.empty() && options.stop_above_e < kNoStop;
  const size_t check_every = std::max<size_t>(1, scans.size() / 32);
  for (size_t k = 0; k < scans.size(); ++k) {
    if (options.cancel != nullptr && options.cancel->load(std::memory_order_relaxed)) {
      cancelled = true;
      break;
    }
    const Scan& scan = scans[k];
    if (Dropped(options.drop, scan.t_begin - t_origin)) {
      ++dropped;
      left_out = true;
      log.Dropped();
      done = k + 1;
      if (options.progress) options.progress(k + 1, scans.size());
      continue;
    }
    const bool kidnapped =
        replayed_any && left_out && options.relocalize_after_drop && engine.Best().map.HasTiles();
    if ((!replayed_any && relocalize_first) || kidnapped) {
      relocalizer.Start(engine.Best().map);
      log.Start(kidnapped ? RelocalizationStart::kDrop : RelocalizationStart::kStart, scan.t_begin);
    }
    replayed_any = true;
    left_out = false;
    const BudgetedStep::Result step = stepper.Run(scan, options.refine);
    if (step.lost) log.Start(RelocalizationStart::kLost, scan.t_begin);  // this scan went to it
    if (step.watch_relocated) log.Start(RelocalizationStart::kWatch, scan.t_begin);
    log.Step(scan, step);
    if (step.record) plans.push_back(*step.record);
    rays_total += step.report.rays.total();
    rays_max = std::max(rays_max, step.report.rays.total());
    resamplings += step.report.resampled ? 1 : 0;
    done = k + 1;
    if (options.progress) options.progress(k + 1, scans.size());
    if (bound_checks && done < scans.size() && done % check_every == 0) {
      // The final trajectory is the history of a particle descending from one of today's.
      double bound = kNoStop;
      for (const Particle& particle : engine.particles()) {
        bound = std::min(bound, ErrorLowerBound(History(particle), ground_truth));
      }
      if (bound > options.stop_above_e) {
        stopped_early = true;
        e_lower_bound = bound;
        break;
      }
    }
  }
  const double cpu_s = CpuSeconds(clock) - cpu_start;
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();

  ReplayResult result(engine.Best().map);
  result.trajectory = engine.Trajectory();
  log.Finish(relocalizer.active(), result);
  if (!ground_truth.empty()) {
    std::vector<TimedPose> scored;
    for (const TimedPose& p : ground_truth) {
      if (!Dropped(result.untracked, p.t - t_origin)) scored.push_back(p);
    }
    result.quality = EvaluateTrajectory(result.trajectory, scored);
    result.map_alignment = AlignOnMajority(result.trajectory, scored);
  }
  result.scans = static_cast<int64_t>(done) - dropped;
  result.scans_dropped = dropped;
  result.cancelled = cancelled;
  result.stopped_early = stopped_early;
  result.e_lower_bound = e_lower_bound;
  result.rays_total = rays_total;
  result.rays_per_scan_max = rays_max;
  result.resamplings = resamplings;
  result.scans_refused = engine.scans_refused();
  result.params_set = stepper.in_use();
  result.params_switches = stepper.switches();
  result.plans = std::move(plans);
  result.wall_s = wall_s;
  result.cpu_s = cpu_s;
  return result;
}

}  // namespace slam::offline
