// slam-replay: runs the SLAM on a recorded experiment (docs/design.md sections 5-6) through the
// same decoding as live data, prints a JSON summary on stdout and writes trajectory.tum, map.pgm +
// map.yaml (ROS map_server), map.png (the map with the trajectories, like the paper's Fig. 9) and
// robot.json (the robot replayed). With --localize it localises on a map it is given (slamd's
// saved state or a map.yaml) instead of mapping; --drop leaves stretches out (a kidnap).

#include <tbb/global_control.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "engine/cell_encoding.hpp"
#include "engine/io/atomic_file.hpp"
#include "engine/io/map_yaml.hpp"
#include "engine/io/params_json.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/relations.hpp"
#include "offline/replay.hpp"
#include "offline/replay_report.hpp"
#include "scheduler/ray_budget_scheduler.hpp"
#include "server/state_store.hpp"
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

/// A bad option value: said on stderr, exit status 2.
int Usage(const std::string& message) {
  std::cerr << "slam-replay: " << message << "\n";
  return 2;
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
  // Localisation and stretches left out, as typed (checked by LocalizationOptions).
  std::string localize_path, pose_text;
  std::vector<std::string> drop_texts;
  double from_s = 0.0, until_s = 0.0;
  bool no_relocalize = false;
  bool detect_loss = false;
  bool watch = false;
  bool log_searches = false;
};

constexpr char kTimeBase[] =
    "seconds after the first scan of the recording began (the JSON's *_s times count from there "
    "too; trajectory.tum and the JSON's \"t\" keep the recording's own clock)";

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
  app.add_option("--localize", c.localize_path,
                 "localise on this map instead of mapping: a slamd state directory (--state-dir: "
                 "its saved log odds, at its own cell size unless --resolution), a ROS map_server "
                 "map.yaml (its PGM or PNG image, resampled to the replay's cells), or a folder "
                 "holding a map.yaml (slam-replay's --out). The map is never changed: map.pgm, "
                 "map.yaml and map.png written are the map localised on. Without --pose the "
                 "replay first relocalises on the whole map (nothing is tracked until it answers)");
  app.add_option("--pose", c.pose_text,
                 "with --localize: the robot's pose on that map at the start of the first scan "
                 "replayed, X,Y,THETA_DEG (metres, degrees, the map's frame)");
  app.add_option("--drop", c.drop_texts,
                 std::string("T0:T1, repeatable: leave out the scans that begin in [T0, T1), ") +
                     kTimeBase +
                     ". The robot moves on while the SLAM's pose does not (an artificial kidnap); "
                     "after the stretch the replay relocalises on the map (--localize's, or the "
                     "one mapped so far) unless --no-relocalize")
      ->allow_extra_args(false);  // one stretch per --drop: EXP_DIR may follow it
  app.add_flag("--no-relocalize", c.no_relocalize,
               "after a --drop stretch, track on from where the SLAM was instead of relocalising "
               "(the kidnap unannounced: found only by --detect-loss)");
  app.add_flag("--detect-loss", c.detect_loss,
               "check each scan tracked against the map (engine/loss_detector.hpp, as slamd "
               "does): a loss takes back what the lost tracker mapped and relocalises");
  app.add_flag("--watch", c.watch,
               "with --detect-loss, also search the whole map for the last seconds' readings in "
               "the background from a tenth of each scan's rays (experimental, off in slamd): "
               "an answer that explains them far better than the tracked pose moves the SLAM "
               "there");
  app.add_flag("--log-searches", c.log_searches,
               "write every relocaliser search's outcome to searches.jsonl in the output "
               "directory (one JSON object a line: t_s, outcome unsure/unconfirmed/answer, the "
               "places it scored, and their errors against the ground truth when there is one)");
  app.add_option(
         "--from", c.from_s,
         std::string("replay only the scans that begin at or after this time, ") + kTimeBase)
      ->check(CLI::Range(0.0, 1e9));
  app.add_option("--until", c.until_s,
                 std::string("replay only the scans that begin before this time, ") + kTimeBase)
      ->check(CLI::Range(0.0, 1e9));
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

/// --pose, --drop, --from and --until into `options`; an exit status when one is bad.
std::optional<int> StretchOptions(const ReplayConfig& c, const CLI::App& app,
                                  slam::offline::ReplayOptions& options) {
  if (!c.pose_text.empty()) {
    if (c.localize_path.empty()) return Usage("--pose needs --localize MAP");
    options.start_pose = slam::cli::PoseArgument(c.pose_text);
    if (!options.start_pose) {
      return Usage("--pose " + c.pose_text +
                   ": expected X,Y,THETA_DEG (three finite numbers: metres, metres, degrees)");
    }
  }
  const bool from = app.count("--from") > 0, until = app.count("--until") > 0;
  if (from && until && !(c.from_s < c.until_s)) {
    return Usage("--from " + std::to_string(c.from_s) + " is not before --until " +
                 std::to_string(c.until_s));
  }
  constexpr double kForever = std::numeric_limits<double>::infinity();
  if (from) options.drop.push_back({-kForever, c.from_s});
  if (until) options.drop.push_back({c.until_s, kForever});
  for (const std::string& text : c.drop_texts) {
    const auto v = slam::cli::FiniteNumbers(text, ':', 2);
    if (!v || !((*v)[0] >= 0.0 && (*v)[0] < (*v)[1])) {
      return Usage("--drop " + text + ": expected T0:T1 with 0 <= T0 < T1 (" + kTimeBase + ")");
    }
    options.drop.push_back({(*v)[0], (*v)[1]});
  }
  options.relocalize_after_drop = !c.no_relocalize;
  if (c.watch && !c.detect_loss) return Usage("--watch needs --detect-loss");
  if (c.detect_loss) options.loss_detector = slam::LossDetectorConfig{};
  if (c.watch) options.watch = slam::WatchConfig{};
  options.log_searches = c.log_searches;
  return std::nullopt;
}

/// The map of --localize, and what it was.
struct LocalizeMap {
  slam::OccupancyGrid grid;
  std::string kind;  // "slamd-state" or "map.yaml"
};

/// slamd's saved state in `dir` as a grid, cells within the clamp `limit`; `resolution_m` (0:
/// the state's own) must be the state's.
slam::Result<LocalizeMap> LoadStateMap(const std::string& dir, double resolution_m, int limit) {
  const auto loaded = slam::server::LoadState(dir);
  if (!loaded.ok()) return slam::Error(dir + ": " + loaded.Message());
  if (!loaded.value()) return slam::Error(dir + ": no saved state (state.json) in it");
  const slam::server::SavedState& saved = *loaded.value();
  if (resolution_m > 0.0 && std::abs(resolution_m - saved.resolution_m) > 1e-12) {
    return slam::Error(dir + ": the saved map's cells are " + std::to_string(saved.resolution_m) +
                       " m, not --resolution's " + std::to_string(resolution_m) + " m");
  }
  slam::OccupancyGrid grid(slam::GridGeometry(saved.resolution_m), limit);
  grid.BeginWrite();
  for (const slam::server::SavedTile& tile : saved.tiles) {
    slam::Tile& cells = grid.MutableTile(tile.index);
    for (size_t i = 0; i < cells.cells.size() && i < tile.cells.size(); ++i) {
      cells.cells[i] = static_cast<slam::LogOdds>(std::clamp<int>(tile.cells[i], -limit, limit));
    }
  }
  grid.RefreshSummaries();
  return LocalizeMap{std::move(grid), "slamd-state"};
}

/// The map of --localize (a state directory, a map.yaml, or a folder holding one) for a replay
/// at `resolution_m` (0: a state's own, a map.yaml's `default_resolution_m`).
slam::Result<LocalizeMap> LoadLocalizeMap(const std::string& path, double resolution_m,
                                          double default_resolution_m, int limit) {
  namespace fs = std::filesystem;
  std::error_code ec;
  std::string yaml = path;
  if (fs::is_directory(path, ec)) {
    if (fs::exists(fs::path(path) / "state.json", ec)) {
      return LoadStateMap(path, resolution_m, limit);
    }
    yaml = (fs::path(path) / "map.yaml").string();
    if (!fs::exists(yaml, ec)) {
      return slam::Error(path +
                         ": neither a slamd state directory (state.json) nor a folder holding a "
                         "map.yaml");
    }
  }
  const double resolution = resolution_m > 0.0 ? resolution_m : default_resolution_m;
  auto grid = slam::io::LoadMapYaml(yaml, slam::GridGeometry(resolution), limit);
  if (!grid.ok()) return {grid.errors(), grid.error_context()};
  return LocalizeMap{std::move(grid).value(), "map.yaml"};
}

/// What the relocaliser found, on stderr.
void ReportRelocalizations(const slam::offline::ReplayResult& run, double t_origin) {
  for (const slam::offline::ReplayRelocalization& r : run.relocalizations) {
    std::fprintf(stderr,
                 "relocalised (%s) at %.1f s after %.1f s and %lld scans: (%.3f, %.3f, %.1f deg), "
                 "score %.3f, runner-up %.3f, %lld lookups%s\n",
                 slam::offline::ToString(r.cause), r.t - t_origin, r.t - r.started_t,
                 static_cast<long long>(r.scans), r.found.pose.x, r.found.pose.y,
                 slam::RadToDeg(r.found.pose.theta), r.found.score, r.found.runner_up_score,
                 static_cast<long long>(r.found.lookups),
                 r.taken ? "" : " (refused by the SLAM: searching again)");
  }
  if (run.relocalizing_at_end) {
    std::fprintf(stderr,
                 "note: still relocalising at the end (since %.1f s, %lld scans in all given to "
                 "the relocaliser): the robot was not found\n",
                 run.relocalizing_since_t - t_origin,
                 static_cast<long long>(run.relocalizing_scans));
  }
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
  slam::offline::ReplayOptions options = ReplayOptionsOf(config, params);
  if (const std::optional<int> exit_code = StretchOptions(config, app, options)) return *exit_code;
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

  const double t_origin = experiment.scans.empty() ? 0.0 : experiment.scans.front().t_begin;
  if (std::none_of(experiment.scans.begin(), experiment.scans.end(), [&](const slam::Scan& scan) {
        return std::none_of(options.drop.begin(), options.drop.end(),
                            [&](const slam::offline::TimeInterval& d) {
                              return d.Contains(scan.t_begin - t_origin);
                            });
      })) {
    char span[96];
    std::snprintf(span, sizeof(span), "(its scans begin from 0 to %.1f s)",
                  experiment.scans.back().t_begin - t_origin);
    return Usage("--from, --until and --drop leave no scan of " + config.experiment_dir +
                 " to replay " + span);
  }
  std::optional<LocalizeMap> localize;
  if (!config.localize_path.empty()) {
    auto loaded = LoadLocalizeMap(config.localize_path, config.resolution,
                                  slam::DefaultResolution(experiment.robot),
                                  slam::EncodeLogOdds(options.config.logodds_limit));
    if (!loaded.ok()) return Usage("--localize: " + loaded.Message());
    localize.emplace(std::move(loaded).value());
    const slam::GridGeometry& geometry = localize->grid.geometry();
    if (!localize->grid.HasTiles()) {
      return Usage("--localize " + config.localize_path + ": the map is empty (nothing known)");
    }
    if (options.start_pose && !geometry.InMapBound(options.start_pose->translation())) {
      return Usage("--pose " + config.pose_text + ": outside the map's bound");
    }
    options.config.resolution_m = geometry.resolution();
    options.map = localize->grid;
    options.localize_only = true;
  }

  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  if (ec) return Fail("cannot create " + out_dir + ": " + ec.message());

  ProgressLine progress(experiment.meta.name + (config.no_refine ? " (odometry only)" : "") +
                        (localize ? " (localising)" : ""));
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
  if (!config.quiet) ReportRelocalizations(run, t_origin);
  slam::offline::ReplayOutputs outputs =
      slam::offline::WriteReplayOutputs(out_dir, experiment, run, config.no_refine, options.budget);
  Json summary = slam::offline::ReplaySummary(experiment, run, options);
  summary["out"] = out_dir;
  summary["from_s"] = app.count("--from") > 0 ? Json(config.from_s) : Json();
  summary["until_s"] = app.count("--until") > 0 ? Json(config.until_s) : Json();
  if (localize) {
    summary["localize_map"] = {{"path", config.localize_path},
                               {"kind", localize->kind},
                               {"tiles", localize->grid.TileCount()}};
  }
  if (config.log_searches) {
    const std::string path = (std::filesystem::path(out_dir) / "searches.jsonl").string();
    const auto written = slam::io::WriteFileAtomic(path, slam::offline::SearchLog(experiment, run));
    if (written.ok()) {
      summary["searches_file"] = path;
    } else {
      outputs.errors.push_back(written.Message());
    }
  }
  if (!config.relations_path.empty()) {
    summary["relations"] = ScoreRelations(config, relations, experiment, run, outputs.errors);
  }
  std::cout << summary.dump(2) << "\n";
  for (const std::string& e : outputs.errors) std::cerr << "slam-replay: " << e << "\n";
  return outputs.errors.empty() ? 0 : 1;
}
