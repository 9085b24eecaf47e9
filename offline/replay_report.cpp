#include "offline/replay_report.hpp"

#include <cmath>
#include <cstdio>
#include <optional>

#include "engine/io/atomic_file.hpp"
#include "engine/io/map_image.hpp"
#include "engine/io/params_json.hpp"
#include "engine/io/robot_json.hpp"
#include "engine/io/tum.hpp"
#include "engine/match_window.hpp"
#include "hw_link/status_json.hpp"
#include "sim/map_quality.hpp"

namespace slam::offline {
namespace {

using Json = nlohmann::json;

Json CountersJson(const offline::ExperimentCounters& c) {
  return {{"bad_lines", c.bad_lines},
          {"ignored_lines", c.ignored_lines},
          {"clock_jumps", c.clock_jumps},
          {"ground_truth_unplaced", c.ground_truth_unplaced},
          {"scans_out_of_order", c.scans_out_of_order},
          {"scans_without_odometry", c.scans_without_odometry},
          {"reassembly", hw::ReassemblyCountersToJson(c.reassembly)},
          {"decoder", hw::DecoderCountersToJson(c.decoder)},
          {"assembler", hw::AssemblerCountersToJson(c.assembler)}};
}

std::string BudgetLabel(const BudgetSettings& budget) {
  char text[64];
  if (budget.mode == QuotaMode::kCpuShare) {
    std::snprintf(text, sizeof(text), "%.3g of a core", budget.cpu_share);
  } else {
    std::snprintf(text, sizeof(text), "%lld rays/scan",
                  static_cast<long long>(budget.rays_per_scan));
  }
  return std::string(text) + (budget.policy == BudgetPolicy::kAdaptive ? ", adaptive" : "");
}

/// What the scheduler planned and the engine used, over the run.
Json SchedulerSummary(const ReplayResult& run) {
  int64_t over = 0, filling = 0, quota_total = 0, particles_max = 0;
  double used_share = 0.0, used_share_min = 1.0, particles_sum = 0.0, candidates_sum = 0.0;
  for (const PlanRecord& r : run.plans) {
    over += r.used_rays > r.quota ? 1 : 0;
    quota_total += r.quota;
    particles_sum += r.plan.particles;
    candidates_sum += r.plan.candidates;
    particles_max = std::max<int64_t>(particles_max, r.plan.particles);
    if (r.fills_quota && r.quota > 0) {
      const double share = static_cast<double>(r.used_rays) / static_cast<double>(r.quota);
      ++filling;
      used_share += share;
      used_share_min = std::min(used_share_min, share);
    }
  }
  const double n = std::max<double>(1.0, static_cast<double>(run.plans.size()));
  Json j;
  j["over_quota_scans"] = over;
  j["quota_mean"] = static_cast<double>(quota_total) / n;
  j["scans_filling_quota"] = filling;
  j["quota_used_mean"] =
      filling > 0 ? Json(used_share / static_cast<double>(filling)) : Json(nullptr);
  j["quota_used_min"] = filling > 0 ? Json(used_share_min) : Json(nullptr);
  j["particles_mean"] = particles_sum / n;
  j["particles_max"] = particles_max;
  j["candidates_mean"] = candidates_sum / n;
  return j;
}

std::string Centimetres(double metres) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.1f cm", 100.0 * metres);
  return text;
}

Json PoseJson(const Pose2& p) { return {{"x", p.x}, {"y", p.y}, {"theta_deg", RadToDeg(p.theta)}}; }

/// A pose of the run at time `t` (the scans' clock) against the ground truth there, in the
/// frame most of the trajectory agrees with (ReplayResult::map_alignment): error_m and
/// heading_error_deg into `j` (nothing without ground truth at t).
void AddErrorAgainstTruth(const offline::Experiment& experiment, const ReplayResult& run, double t,
                          const Pose2& pose, Json& j) {
  if (!run.map_alignment) return;
  const std::optional<Pose2> truth = PoseAt(experiment.ground_truth, t);
  if (!truth) return;
  const Pose2 seen = TransformTrajectory(run.map_alignment->Inverse(), {{t, *truth}}).front().pose;
  j["error_m"] = (seen.translation() - pose.translation()).norm();
  j["heading_error_deg"] = std::abs(RadToDeg(NormalizeAngle(seen.theta - pose.theta)));
}

/// Where the replay started and what it left out, and each relocalisation (against the ground
/// truth, aligned, when there is one).
void LocalizationSummary(const offline::Experiment& experiment, const ReplayResult& run,
                         const ReplayOptions& options, Json& j) {
  // Times relative to the first scan's start, as ReplayOptions::drop's.
  const double t_origin = experiment.scans.empty() ? 0.0 : experiment.scans.front().t_begin;
  j["localize"] = options.map.has_value();
  j["localize_only"] = options.localize_only;
  j["start_pose"] = options.map && options.start_pose ? PoseJson(*options.start_pose) : Json();
  Json drop = Json::array();
  // A cut of the recording's start or end has an open end: null.
  const auto end = [](double t) { return std::isfinite(t) ? Json(t) : Json(); };
  for (const TimeInterval& d : options.drop) {
    drop.push_back({{"from_s", end(d.t0_s)}, {"to_s", end(d.t1_s)}});
  }
  j["drop"] = drop;
  j["scans_dropped"] = run.scans_dropped;
  j["relocalize_after_drop"] = options.relocalize_after_drop;
  j["detect_loss"] = options.loss_detector.has_value();
  j["losses"] = run.losses;
  j["losses_s"] = run.loss_times_s;
  // How near the run came to a loss: the detector's largest window share, and when.
  j["loss_share_max"] = options.loss_detector ? Json{{"share", run.loss_share_max},
                                                     {"t_s", run.loss_share_max_t - t_origin}}
                                              : Json();
  Json answers = Json::array();
  for (const ReplayRelocalization& r : run.relocalizations) {
    Json a = {{"cause", ToString(r.cause)},
              {"started_t", r.started_t},
              {"started_s", r.started_t - t_origin},
              {"t", r.t},
              {"t_s", r.t - t_origin},
              {"took_s", r.t - r.started_t},
              {"scans", r.scans},
              {"pose", PoseJson(r.found.pose)},
              {"score", r.found.score},
              {"runner_up", r.found.runner_up_score},
              {"points", r.found.points},
              {"lookups", r.found.lookups},
              {"searches", r.found.searches},
              {"taken", r.taken}};
    AddErrorAgainstTruth(experiment, run, r.t, r.found.pose, a);
    answers.push_back(a);
  }
  j["relocalizations"] = answers;
  Json untracked = Json::array();
  for (const TimeInterval& u : run.untracked) {
    untracked.push_back({{"from_s", u.t0_s}, {"to_s", u.t1_s}});
  }
  j["untracked"] = untracked;
  j["lookups_total"] = run.lookups_total;
  j["searches_unsure"] = run.searches_unsure;
  if (run.best_unsure) {
    j["best_unsure"] = {{"t_s", run.best_unsure_t - t_origin},
                        {"pose", PoseJson(run.best_unsure->pose)},
                        {"score", run.best_unsure->score},
                        {"runner_up", run.best_unsure_runner_up}};
  } else {
    j["best_unsure"] = nullptr;
  }
  j["relocalizing_scans"] = run.relocalizing_scans;
  j["watch"] = options.watch && options.loss_detector ? Json{{"lookups", run.watch_lookups},
                                                             {"searches_unsure", run.watch_unsure},
                                                             {"confirmed", run.watch_confirmed}}
                                                      : Json();
  j["relocalizing_at_end"] = run.relocalizing_at_end;
  if (run.relocalizing_at_end) j["relocalizing_since_s"] = run.relocalizing_since_t - t_origin;
}

}  // namespace

nlohmann::json ReplaySummary(const offline::Experiment& experiment, const ReplayResult& run,
                             const ReplayOptions& options) {
  Json j;
  j["experiment"] = experiment.meta.name;
  j["dir"] = experiment.dir;
  // budget: rays per scan in that mode (the contract of docs/design.md section 6), null under a CPU
  // share.
  const BudgetSettings& budget = options.budget;
  j["budget"] = budget.mode == QuotaMode::kRaysPerScan ? Json(budget.rays_per_scan) : Json(nullptr);
  j["quota_mode"] = std::string(ToString(budget.mode));
  if (budget.mode == QuotaMode::kCpuShare) j["cpu_share"] = budget.cpu_share;
  j["policy"] = std::string(ToString(budget.policy));
  if (budget.policy == BudgetPolicy::kAdaptive) j["max_particles"] = budget.max_particles;
  j["refine"] = options.refine;
  j["params_set"] = run.params_set.name;
  if (options.params.follows_quota()) j["params_switches"] = run.params_switches;
  j["seed"] = options.config.seed;
  j["resolution_m"] = run.map.geometry().resolution();
  if (run.quality) {
    j["q"] = run.quality->q_cm2;
    j["e"] = run.quality->e;
    j["ate_rmse_m"] = run.quality->ate_rmse_m;
    j["matched_poses"] = run.quality->matched;
  } else {
    j["q"] = j["e"] = j["ate_rmse_m"] = nullptr;
  }
  const auto odometry =
      EvaluateTrajectory(DeadReckoning(experiment.scans), experiment.ground_truth);
  j["odometry_ate_rmse_m"] = odometry ? Json(odometry->ate_rmse_m) : Json(nullptr);
  j["scans"] = run.scans;
  j["rays_total"] = run.rays_total;
  j["rays_per_scan_max"] = run.rays_per_scan_max;
  j["rays_per_scan_mean"] =
      run.scans > 0 ? static_cast<double>(run.rays_total) / static_cast<double>(run.scans) : 0.0;
  j["resamplings"] = run.resamplings;
  j["scheduler"] = SchedulerSummary(run);
  j["duration_s"] = experiment.duration_s();
  j["wall_s"] = run.wall_s;
  j["cpu_s"] = run.cpu_s;
  j["ray_kernel"] = BestWindowKernelName();  // the timings depend on it, the answers do not
  j["ns_per_ray"] =
      run.rays_total > 0 ? 1e9 * run.cpu_s / static_cast<double>(run.rays_total) : 0.0;
  j["cpu_ms_per_scan"] = run.scans > 0 ? 1000.0 * run.cpu_s / static_cast<double>(run.scans) : 0.0;
  j["realtime_factor"] = run.wall_s > 0.0 ? experiment.duration_s() / run.wall_s : 0.0;
  j["frames"] = experiment.counters.frames;
  j["frames_rejected"] = experiment.counters.FramesRejected();
  if (experiment.world && run.quality && run.map_alignment) {
    // The map scored in the frame, of two, that it fits better: the ATE's (least squares over
    // the whole trajectory: a drifting track has no frame of its own) or the majority's (a
    // track off for a stretch, then re-found, drew the map in the frame of the rest).
    const RigidTransform2& ate = run.quality->alignment;
    const RigidTransform2& most = *run.map_alignment;
    const sim::MapQuality by_ate =
        sim::EvaluateMap(run.map, ate, *experiment.world, experiment.ground_truth);
    // A track that every pose agrees with leaves the least-squares fit as it was: one score.
    const bool same = most.rotation_rad == ate.rotation_rad && most.translation == ate.translation;
    const std::optional<sim::MapQuality> by_majority =
        same ? std::nullopt
             : std::optional(
                   sim::EvaluateMap(run.map, most, *experiment.world, experiment.ground_truth));
    const bool majority = by_majority && by_majority->precision > by_ate.precision;
    const sim::MapQuality& m = majority ? *by_majority : by_ate;
    const auto as_pose = [](const RigidTransform2& a) {
      return Pose2{a.translation.x(), a.translation.y(), a.rotation_rad};
    };
    const Pose2 between = Between(as_pose(ate), as_pose(most));
    j["map_quality"] = {{"frame", majority ? "majority" : "trajectory"},
                        {"frame_shift_m", between.translation().norm()},
                        {"frame_rotation_deg", std::abs(RadToDeg(between.theta))},
                        {"precision", m.precision},
                        {"recall", m.recall},
                        {"f1", m.f1},
                        {"tolerance_m", m.tolerance_m},
                        {"occupied_cells", m.occupied_cells},
                        {"true_occupied_cells", m.true_occupied_cells},
                        {"surface_points", m.surface_points},
                        {"surface_points_found", m.surface_points_found}};
  } else {
    j["map_quality"] = nullptr;
  }
  j["params"] = io::ParamsToJson(run.params_set.params);
  j["counters"] = CountersJson(experiment.counters);
  LocalizationSummary(experiment, run, options, j);
  return j;
}

std::string SearchLog(const offline::Experiment& experiment, const ReplayResult& run) {
  const double t_origin = experiment.scans.empty() ? 0.0 : experiment.scans.front().t_begin;
  std::string lines;
  for (const ReplaySearch& search : run.searches) {
    Json places = Json::array();
    for (const GlobalMatch& place : search.places) {
      Json p = {{"pose", PoseJson(place.pose)}, {"score", place.score}};
      AddErrorAgainstTruth(experiment, run, search.t, place.pose, p);
      places.push_back(p);
    }
    Json line = {{"t", search.t},
                 {"t_s", search.t - t_origin},
                 {"outcome", ToString(search.outcome)},
                 {"lookups", search.lookups},
                 {"scans", search.scans},
                 {"places", places}};
    if (search.outcome == SearchOutcome::kAnswer) line["points"] = search.points;
    lines += line.dump() + "\n";
  }
  return lines;
}

ReplayOutputs WriteReplayOutputs(const std::string& dir, const offline::Experiment& experiment,
                                 const ReplayResult& run, bool odometry_only,
                                 const BudgetSettings& budget) {
  ReplayOutputs outputs;
  const auto check = [&](const Result<void>& written) {
    if (!written.ok()) outputs.errors.push_back(written.Message());
  };
  const std::string base = dir + "/";
  const io::GridImage grid = io::MakeGridImage(run.map);
  check(io::WritePgm(base + "map.pgm", grid));
  check(io::WriteMapYaml(base + "map.yaml", "map.pgm", grid));
  check(io::WriteFileAtomic(base + "trajectory.tum", io::FormatTum(run.trajectory)));
  // The robot replayed: for a bare CARMEN log the one derived from it, to edit and give back as
  // robot.json beside the log.
  check(io::WriteFileAtomic(base + "robot.json", io::RobotToJson(experiment.robot).dump(2) + "\n"));

  // The picture: odometry for comparison, the aligned ground truth, then the estimate on top.
  std::vector<io::TrajectoryLayer> layers;
  if (!odometry_only) {
    // Drawn, clipped, but not fitted: a real log's dead reckoning wanders far off the building.
    layers.push_back(
        {"odometry only", DeadReckoning(experiment.scans), {150, 150, 150}, /*fit=*/false});
  }
  if (run.quality) {
    layers.push_back(
        {"ground truth, aligned (ATE " + Centimetres(run.quality->ate_rmse_m) + ")",
         TransformTrajectory(run.quality->alignment.Inverse(), experiment.ground_truth),
         {0, 90, 255}});
  }
  layers.push_back({odometry_only ? "odometry only (phase B off)" : "SLAM, " + BudgetLabel(budget),
                    run.trajectory,
                    {230, 0, 0}});
  check(io::WritePng(base + "map.png", io::RenderMapPicture(run.map, layers, 3)));
  return outputs;
}

}  // namespace slam::offline
