#include "offline/replay.hpp"

#include <algorithm>
#include <chrono>
#include <limits>

#include "scheduler/budgeted_step.hpp"

namespace slam::offline {
namespace {

constexpr double kNoStop = std::numeric_limits<double>::infinity();

}  // namespace

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
    const BudgetedStep::Result step = stepper.Run(scans[k], options.refine);
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
  if (!ground_truth.empty()) result.quality = EvaluateTrajectory(result.trajectory, ground_truth);
  result.scans = static_cast<int64_t>(done);
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
