// slam-replay: runs the SLAM on a recorded experiment (docs/design.md sections 5-6) through the
// same decoding as live data, prints a JSON summary on stdout and writes trajectory.tum, map.pgm +
// map.yaml (ROS map_server), map.png (the map with the trajectories, like the paper's Fig. 9) and
// robot.json (the robot replayed).

#include <tbb/global_control.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "engine/io/atomic_file.hpp"
#include "engine/io/params_json.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/relations.hpp"
#include "offline/replay.hpp"
#include "offline/replay_report.hpp"
#include "scheduler/ray_budget_scheduler.hpp"
#include "tools/command_line.hpp"

namespace {

using Json = nlohmann::json;

/// Progress on stderr: rewritten in place on a terminal, one line per tenth otherwise.
class ProgressLine {
 public:
  explicit ProgressLine(std::string label)
      : label_(std::move(label)),
        interactive_(::isatty(STDERR_FILENO) != 0),
        start_(std::chrono::steady_clock::now()) {}

  void Update(size_t done, size_t total) {
    const auto now = std::chrono::steady_clock::now();
    const double elapsed = std::chrono::duration<double>(now - start_).count();
    const size_t tenth = std::max<size_t>(1, total / 10);
    const bool last = done == total;
    if (interactive_) {
      if (!last && now - last_print_ < std::chrono::milliseconds(200)) return;
    } else if (!last && done % tenth != 0) {
      return;
    }
    last_print_ = now;
    const double eta =
        done > 0 ? elapsed * static_cast<double>(total - done) / static_cast<double>(done) : 0.0;
    std::fprintf(stderr, "%s%s: scan %zu/%zu (%3.0f%%), %.1f s elapsed, ETA %.1f s%s",
                 interactive_ ? "\r" : "", label_.c_str(), done, total,
                 total > 0 ? 100.0 * static_cast<double>(done) / static_cast<double>(total) : 100.0,
                 elapsed, eta, interactive_ ? (last ? "\n" : "") : "\n");
    std::fflush(stderr);
  }

 private:
  std::string label_;
  bool interactive_;
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_print_{};
};

int Fail(const std::string& message) {
  std::cerr << "slam-replay: " << message << "\n";
  return 1;
}

/// slam-replay's command line, as parsed.
struct ReplayConfig {
  std::string experiment_dir, params_path, out_dir, relations_path;
  int64_t budget = 65000;
  double cpu_share = 0.0;
  std::string policy_name = "fixed";
  int max_particles = slam::BudgetSettings{}.max_particles;
  bool no_refine = false;
  uint64_t seed = 1;
  int threads = 0;
  bool quiet = false;
  double resolution = 0.0;  // the robot's
  double range_sigma_min_cells = slam::SlamConfig{}.range_sigma_min_cells;
  double heading_sweep_turn_deg = slam::SlamConfig{}.heading_sweep_turn_deg;
};

void AddOptions(CLI::App& app, ReplayConfig& c) {
  app.add_option("EXP_DIR", c.experiment_dir, "recorded experiment directory, or a CARMEN log")
      ->required();
  app.add_option("--resolution", c.resolution,
                 "grid cell size in metres [the robot's: 0.01 for the marXbot's infrared "
                 "scanner, 0.05 for a laser]")
      ->check(CLI::Range(0.002, 1.0));
  app.add_option("--heading-sweep-turn", c.heading_sweep_turn_deg,
                 slam::offline::kHeadingSweepTurnHelp)
      ->check(CLI::Range(0.0, 360.0))
      ->capture_default_str();
  app.add_option("--range-sigma-cells", c.range_sigma_min_cells,
                 "a range scanner's readings are matched with a deviation of at least this many "
                 "cells (0: the sensor's own noise)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 10.0));
  app.add_option("--params", c.params_path,
                 "SLAM parameters (JSON, Table II keys) [the shipped set of the budget, "
                 "config/params/]");
  app.add_option("--budget", c.budget, "rays per scan (paper: 8125, 16250, 32500, 65000)")
      ->capture_default_str()
      ->check(CLI::Range(int64_t{1}, slam::kMaxRaysPerScan));  // slamd's bound
  app.add_option("--cpu-share", c.cpu_share,
                 "quota as a share of one core instead of rays per scan (0.125 ... 1.0), through "
                 "the measured cost per ray; the engine then runs serially on one thread")
      ->check(CLI::Range(0.0, 1.0))
      ->excludes("--budget");
  app.add_option("--policy", c.policy_name, "fixed (the paper's) or adaptive particle count")
      ->capture_default_str()
      ->check(CLI::IsMember({"fixed", "adaptive"}));
  app.add_option("--max-particles", c.max_particles, "adaptive policy: most particles")
      ->capture_default_str()
      ->check(CLI::Range(1, slam::kMaxParticlesCap));
  app.add_flag("--no-refine", c.no_refine,
               "phase B off: odometry-only mapping (the paper's Fig. 9 bottom)");
  app.add_option("--seed", c.seed, "seed of the particle filter")->capture_default_str();
  app.add_option("--out", c.out_dir, "output directory, created if needed [replay-<EXP_DIR name>]");
  app.add_option("--threads", c.threads,
                 "worker threads (0: every core; results do not depend on it)")
      ->capture_default_str()
      ->check(CLI::Range(0, 256));
  app.add_option("--relations", c.relations_path,
                 "benchmark relations (Freiburg format: t1 t2 x y z roll pitch yaw per line): adds "
                 "a \"relations\" object to the summary with the trajectory's relation errors, and "
                 "odometry's beside them; writes each relation's errors to relations.tsv in the "
                 "output directory");
  app.add_flag("--quiet", c.quiet, "no progress line on stderr");
  app.set_version_flag("--version", std::string("slam-replay ") + SLAM_VERSION);
}

/// replay-<the experiment's name>.
std::string DefaultOutDir(const std::string& experiment_dir) {
  const std::filesystem::path dir = std::filesystem::path(experiment_dir).lexically_normal();
  const std::string name = (dir.has_filename() ? dir : dir.parent_path()).filename().string();
  return "replay-" + (name.empty() || name == "." ? std::string("out") : name);
}

/// Says what was decoded: scans, frames, what was skipped and noted.
void ReportLoad(const slam::offline::Experiment& experiment, double load_s) {
  std::fprintf(stderr, "%s: %zu scans from %llu frames (%llu rejected) in %.2f s\n",
               experiment.meta.name.c_str(), experiment.scans.size(),
               static_cast<unsigned long long>(experiment.counters.frames),
               static_cast<unsigned long long>(experiment.counters.FramesRejected()), load_s);
  for (const std::string& problem : experiment.problems) {
    std::fprintf(stderr, "skipped: %s\n", problem.c_str());
  }
  for (const std::string& note : experiment.notes) {
    std::fprintf(stderr, "note: %s\n", note.c_str());
  }
}

slam::offline::ReplayOptions ReplayOptionsOf(const ReplayConfig& c,
                                             const slam::ParamsChoice& params) {
  slam::offline::ReplayOptions options;
  options.params = params;
  options.config.seed = c.seed;
  options.config.resolution_m = c.resolution;
  options.config.range_sigma_min_cells = c.range_sigma_min_cells;
  options.config.heading_sweep_turn_deg = c.heading_sweep_turn_deg;
  options.budget.rays_per_scan = c.budget;
  options.budget.policy = *slam::ParseBudgetPolicy(c.policy_name);
  options.budget.max_particles = c.max_particles;
  if (c.cpu_share > 0.0) {
    options.budget.mode = slam::QuotaMode::kCpuShare;
    options.budget.cpu_share = c.cpu_share;
    options.config.parallel = false;  // one core's share is measured on this thread
  }
  options.refine = !c.no_refine;
  return options;
}

/// The trajectory's relation errors and dead reckoning's, for the summary; each relation's
/// errors into relations.tsv (an error to report when it cannot be written).
Json ScoreRelations(const ReplayConfig& c, const std::vector<slam::offline::Relation>& relations,
                    const slam::offline::Experiment& experiment,
                    const slam::offline::ReplayResult& run, std::vector<std::string>& errors) {
  const slam::offline::RelationsScore slam_score =
      slam::offline::ScoreRelations(run.trajectory, relations);
  const slam::offline::RelationsScore odometry_score =
      slam::offline::ScoreRelations(slam::offline::DeadReckoning(experiment.scans), relations);
  Json scored = slam::offline::RelationsToJson(slam_score);
  scored["file"] = c.relations_path;
  scored["odometry"] = slam::offline::RelationsToJson(odometry_score);
  // Each relation's errors, to see which relations a score comes from (docs/laser.md).
  const std::string errors_path = (std::filesystem::path(c.out_dir) / "relations.tsv").string();
  const auto written = slam::io::WriteFileAtomic(
      errors_path, slam::offline::RelationErrorsText(relations, slam_score, odometry_score));
  if (written.ok()) {
    scored["errors_file"] = errors_path;
  } else {
    errors.push_back(written.Message());
  }
  return scored;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Replays a recorded experiment (a directory with robot.json, can.log, meta.json, optional "
      "groundtruth.tum and world.json; or a CARMEN text log) through the SLAM. Prints a JSON "
      "summary on stdout; writes trajectory.tum, map.pgm, map.yaml, map.png and robot.json (the "
      "robot replayed, derived for a CARMEN log) into the output directory."};
  ReplayConfig config;
  AddOptions(app, config);
  if (const std::optional<int> exit_code = slam::cli::Parse(app, argc, argv)) return *exit_code;

  slam::ParamsChoice params;  // the shipped set of the quota
  if (!config.params_path.empty()) {
    const auto loaded = slam::io::LoadParams(config.params_path);
    if (!loaded.ok()) return Fail(loaded.Message());
    params = slam::ParamsChoice(config.params_path, loaded.value());
  }
  std::unique_ptr<tbb::global_control> thread_limit;
  std::vector<slam::offline::Relation> relations;
  if (!config.relations_path.empty()) {  // read first: a bad file should not cost a replay
    auto loaded = slam::offline::LoadRelations(config.relations_path);
    if (!loaded.ok()) return Fail(loaded.Message());
    relations = std::move(loaded).value();
  }
  if (config.threads > 0) {
    thread_limit = std::make_unique<tbb::global_control>(
        tbb::global_control::max_allowed_parallelism, static_cast<size_t>(config.threads));
  }
  if (config.out_dir.empty()) config.out_dir = DefaultOutDir(config.experiment_dir);
  const std::string& out_dir = config.out_dir;

  const auto load_start = std::chrono::steady_clock::now();
  slam::Result<slam::offline::Experiment> load =
      slam::offline::LoadExperiment(config.experiment_dir);
  if (!load.ok()) return Fail("cannot replay " + config.experiment_dir + ":\n" + load.Message());
  const slam::offline::Experiment& experiment = load.value();
  const double load_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - load_start).count();
  if (!config.quiet) ReportLoad(experiment, load_s);

  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  if (ec) return Fail("cannot create " + out_dir + ": " + ec.message());

  slam::offline::ReplayOptions options = ReplayOptionsOf(config, params);
  ProgressLine progress(experiment.meta.name + (config.no_refine ? " (odometry only)" : ""));
  if (!config.quiet)
    options.progress = [&](size_t done, size_t total) { progress.Update(done, total); };
  const slam::offline::ReplayResult run =
      slam::offline::Replay(experiment.robot, experiment.scans, experiment.ground_truth, options);

  if (run.scans_refused > 0) {
    std::fprintf(stderr,
                 "note: %lld scans refused by the SLAM (odometry not finite, faster than the "
                 "robot drives, or beyond the map's bound): the pose held across them\n",
                 static_cast<long long>(run.scans_refused));
  }
  slam::offline::ReplayOutputs outputs =
      slam::offline::WriteReplayOutputs(out_dir, experiment, run, config.no_refine, options.budget);
  Json summary = slam::offline::ReplaySummary(experiment, run, options);
  summary["out"] = out_dir;
  if (!config.relations_path.empty()) {
    summary["relations"] = ScoreRelations(config, relations, experiment, run, outputs.errors);
  }
  std::cout << summary.dump(2) << "\n";
  for (const std::string& e : outputs.errors) std::cerr << "slam-replay: " << e << "\n";
  return outputs.errors.empty() ? 0 : 1;
}
