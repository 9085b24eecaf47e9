#pragma once
// What slam-replay and slam-evaluate (the reference table) report about one replay: the JSON
// summary (docs/design.md section 6 keys and more) and the files (trajectory.tum, map.pgm +
// map.yaml, map.png).

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "offline/experiment_reader.hpp"
#include "offline/replay.hpp"

namespace slam::offline {

/// The JSON summary of a replay: q, e, ate_rmse_m (null without ground truth), scans,
/// rays_total, rays_per_scan_max, budget, wall_s, realtime_factor, frames, frames_rejected, and
/// the odometry-only ATE, map quality against world.json (when present), the parameters and
/// every decoding counter; how it started and what it left out (localize, localize_only,
/// start_pose, drop, scans_dropped) and each relocalisation (relocalizations, with times as
/// `t` in the scans' clock and `t_s` after the first scan's start, and the pose's error against
/// the ground truth when there is one), lookups_total, relocalizing_scans, relocalizing_at_end.
nlohmann::json ReplaySummary(const offline::Experiment& experiment, const ReplayResult& run,
                             const ReplayOptions& options);

/// Every relocaliser search of the run (ReplayOptions::log_searches) as JSON Lines, one per
/// search in order: t (the scans' clock), t_s (after the first scan's start), outcome
/// ("unsure", "unconfirmed", "answer"), places (pose, score, and with ground truth error_m and
/// heading_error_deg, aligned as the relocalisations' errors), and an answer's points.
std::string SearchLog(const offline::Experiment& experiment, const ReplayResult& run);

struct ReplayOutputs {
  std::vector<std::string> errors;  // one per file that could not be written
};

/// Writes trajectory.tum, map.pgm, map.yaml, map.png and robot.json (the robot replayed) into
/// `dir` (atomically, each).
ReplayOutputs WriteReplayOutputs(const std::string& dir, const offline::Experiment& experiment,
                                 const ReplayResult& run, bool odometry_only,
                                 const BudgetSettings& budget);

}  // namespace slam::offline
