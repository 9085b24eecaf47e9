// slam-sim: writes recorded experiments of the virtual marXbot (docs/design.md section 6).
//   slam-sim --world NAME|FILE --duration S --seed N --out DIR    one experiment
//     [--kidnap T [--kidnap-to X,Y,THETA_DEG]]                     the robot lifted at T
//   slam-sim dataset [--set NAME] --out DIR                        a set of experiments
//   slam-sim dataset --set all --out DIR                           training, validation, reference
// The same arguments always write the same files.

#include <tbb/parallel_for.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "engine/io/atomic_file.hpp"
#include "engine/io/robot_json.hpp"
#include "engine/io/shipped_path.hpp"
#include "sim/dataset.hpp"
#include "sim/experiment_writer.hpp"
#include "sim/scenario.hpp"
#include "sim/world.hpp"
#include "tools/command_line.hpp"

namespace {

struct Job {
  std::string world_name;  // built-in name or the file's stem
  slam::sim::World world;
  uint64_t seed = 1;
  std::string dir;
  slam::sim::ScenarioConfig config;
};

/// The world of --world, and the name it goes by in meta.json.
bool ResolveWorld(const std::string& spec, slam::sim::World& world, std::string& name) {
  auto loaded = slam::sim::ResolveWorld(spec);
  if (!loaded.ok()) {
    for (const slam::ConfigError& e : loaded.errors())
      std::cerr << "slam-sim: " << e.detail << "\n";
    return false;
  }
  world = loaded.value();
  name = slam::sim::BuiltinWorld(spec) ? spec : std::filesystem::path(spec).stem().string();
  return true;
}

/// slam-sim's command line, as parsed.
struct SimConfig {
  std::string world_spec, out_dir;
  std::string robot_path = slam::io::ShippedPath("config/marxbot.robot.json");
  double duration_s = 300.0;
  uint64_t seed = 1;
  double scans_per_s = 1.5;
  double speed_m_s = slam::sim::ScenarioConfig{}.speed_m_s;
  double turn_rate_rad_s = slam::sim::ScenarioConfig{}.turn_rate_rad_s;
  std::string odometry = "tracked";
  int people = 0;
  std::string kidnap, kidnap_to;  // as typed; checked by KidnapOptions
  bool kidnap_given = false, kidnap_to_given = false;
  // slam-sim dataset
  std::string dataset_out, set_name = "reference";
  int runs = 0;
};

/// The options, and the dataset subcommand (returned).
CLI::App* AddOptions(CLI::App& app, SimConfig& c) {
  app.add_option("--world", c.world_spec,
                 "built-in world (" + slam::sim::BuiltinWorldList() + ") or a world.json file");
  app.add_option("--duration", c.duration_s, "simulated seconds")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 86400.0));
  app.add_option("--seed", c.seed, "seed of the simulation")->capture_default_str();
  app.add_option("--out", c.out_dir, "output directory (created if needed)");
  app.add_option("--robot", c.robot_path, "robot description")->capture_default_str();
  app.add_option("--scans-per-s", c.scans_per_s, "half turns of the scanner per second")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 5.0));
  app.add_option("--speed", c.speed_m_s,
                 "cruising speed in m/s (the marXbot's 0.12; a Pioneer "
                 "with a laser, 0.3 to 0.5)")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 2.0));
  app.add_option("--turn-rate", c.turn_rate_rad_s, "turning rate in place, rad/s")
      ->capture_default_str()
      ->check(CLI::Range(0.05, 5.0));
  app.add_option("--people", c.people,
                 "people walking about at 1 m/s, their legs seen by the sensors and in no map "
                 "(a lab's staff; 0 for an empty building)")
      ->capture_default_str()
      ->check(CLI::Range(0, 50));
  app.add_option("--odometry", c.odometry,
                 "how the odometry errs: tracked (a tracked robot with a MEMS gyro: dead "
                 "reckoning drifts decimetres to metres in 300 s) or gentle (the original "
                 "reference set's small zero-mean slip)")
      ->capture_default_str()
      ->check(CLI::IsMember({"tracked", "gentle"}));
  app.add_option("--kidnap", c.kidnap,
                 "kidnap the robot at this simulated time T in seconds (0 < T < --duration): it "
                 "is lifted and set down at the pose it had at T/2, or at --kidnap-to; its "
                 "odometry does not see it, the ground truth does (meta.json's \"kidnap\"). One "
                 "experiment only")
      ->type_name("T");
  app.add_option("--kidnap-to", c.kidnap_to,
                 "where --kidnap sets the robot down: X,Y,THETA_DEG in the world frame (metres, "
                 "degrees), a place where the robot fits")
      ->type_name("X,Y,THETA_DEG");

  CLI::App* dataset = app.add_subcommand(
      "dataset",
      "a set of experiments, DIR/<world>-<seed>/ each, with DIR/index.json: training (tuning "
      "only), validation (choosing between designs), reference (reporting only; the default), "
      "arenas (the original reference set: 3 arenas x 5 seeds, gentle odometry), or all (the "
      "first three in DIR/training, DIR/validation, DIR/reference)");
  dataset->add_option("--out", c.dataset_out, "output directory")->required();
  dataset->add_option("--set", c.set_name, "which set")
      ->capture_default_str()
      ->check(CLI::IsMember({"training", "validation", "reference", "arenas", "all"}));
  dataset->add_option("--runs", c.runs, "runs (seeds) per world instead of the set's own")
      ->check(CLI::Range(1, 1000));
  dataset->add_option("--duration", c.duration_s, "simulated seconds per run instead of 300")
      ->check(CLI::Range(0.1, 86400.0));
  app.set_version_flag("--version", std::string("slam-sim ") + SLAM_VERSION);
  return dataset;
}

/// --kidnap and --kidnap-to into `config` for a run in `world` (called `world_name`); false when
/// they are bad (said on stderr).
bool KidnapOptions(const SimConfig& c, const slam::sim::World& world, const std::string& world_name,
                   slam::sim::ScenarioConfig& config) {
  if (c.kidnap_to_given && !c.kidnap_given) {
    std::cerr << "slam-sim: --kidnap-to needs --kidnap T\n";
    return false;
  }
  if (!c.kidnap_given) return true;
  const std::optional<double> t = slam::cli::FiniteNumber(c.kidnap);
  if (!t || !(*t > 0.0 && *t < config.duration_s)) {
    std::cerr << "slam-sim: --kidnap " << c.kidnap
              << ": expected a time in seconds within the run, 0 < T < " << config.duration_s
              << " (--duration)\n";
    return false;
  }
  config.kidnap_t_s = *t;
  if (!c.kidnap_to_given) return true;
  const std::optional<slam::Pose2> target = slam::cli::PoseArgument(c.kidnap_to);
  if (!target) {
    std::cerr << "slam-sim: --kidnap-to " << c.kidnap_to
              << ": expected X,Y,THETA_DEG (three finite numbers: metres, metres, degrees)\n";
    return false;
  }
  if (const slam::Result<void> free =
          slam::sim::CheckFreePose(world, config.robot_radius_m, *target);
      !free.ok()) {
    std::cerr << "slam-sim: --kidnap-to " << c.kidnap_to << ": " << free.Message() << " ("
              << world_name << ", a robot of radius " << config.robot_radius_m << " m)\n";
    return false;
  }
  config.kidnap_to = *target;
  return true;
}

/// The jobs of `slam-sim dataset`, and each set's directory with the jobs of its index.json.
void PlanDatasetJobs(const SimConfig& c, bool own_duration, const slam::sim::ScenarioConfig& base,
                     std::vector<Job>& jobs,
                     std::vector<std::pair<std::string, std::vector<size_t>>>& indexes) {
  std::vector<std::pair<slam::sim::DatasetKind, std::string>> sets;
  if (c.set_name == "all") {
    for (const auto kind : {slam::sim::DatasetKind::kTraining, slam::sim::DatasetKind::kValidation,
                            slam::sim::DatasetKind::kReference}) {
      sets.emplace_back(kind, (std::filesystem::path(c.dataset_out) /
                               std::string(slam::sim::DatasetKindName(kind)))
                                  .string());
    }
  } else {
    sets.emplace_back(*slam::sim::DatasetKindFromName(c.set_name), c.dataset_out);
  }
  for (const auto& [kind, dir] : sets) {
    const slam::sim::DatasetPlan plan = slam::sim::PlanDataset(kind, c.runs);
    std::vector<size_t> members;
    for (const slam::sim::DatasetRun& run : plan.runs) {
      Job job{run.world, *slam::sim::BuiltinWorld(run.world), run.seed, "", {}};
      job.dir =
          (std::filesystem::path(dir) / (run.world + "-" + std::to_string(run.seed))).string();
      job.config = slam::sim::WithOdometryProfile(base, plan.odometry);
      if (!own_duration) job.config.duration_s = plan.duration_s;
      job.config.seed = run.seed;
      members.push_back(jobs.size());
      jobs.push_back(std::move(job));
    }
    indexes.emplace_back(dir, std::move(members));
  }
}

/// Writes every job's experiment, in parallel, with a line of progress each; false when one
/// could not be written (said on stderr).
bool WriteExperiments(const std::vector<Job>& jobs, const slam::RobotDescription& robot,
                      std::vector<slam::sim::ExperimentSummary>& summaries) {
  const auto start = std::chrono::steady_clock::now();
  std::atomic<size_t> done{0};
  std::atomic<bool> failed{false};
  std::mutex io_mutex;
  summaries.assign(jobs.size(), {});
  tbb::parallel_for(size_t{0}, jobs.size(), [&](size_t i) {
    const Job& job = jobs[i];
    const slam::Result<void> written = slam::sim::WriteSimulatedExperiment(
        job.dir, job.world, job.world_name, robot, job.config, &summaries[i]);
    const std::lock_guard lock(io_mutex);
    if (!written.ok()) {
      failed = true;
      std::cerr << "slam-sim: " << job.dir << ": " << written.Message() << "\n";
      return;
    }
    const double elapsed =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::fprintf(stderr,
                 "[%zu/%zu] %s: %s seed %llu, %.0f s, %s odometry, %llu frames (%.1f s "
                 "elapsed)\n",
                 ++done, jobs.size(), job.dir.c_str(), job.world_name.c_str(),
                 static_cast<unsigned long long>(job.seed), job.config.duration_s,
                 job.config.odometry.profile.c_str(),
                 static_cast<unsigned long long>(summaries[i].frames), elapsed);
  });
  return !failed;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Writes recorded experiments of the virtual marXbot: robot.json, can.log (candump -l; "
      "log.clf, a CARMEN log, for a robot whose scanner is a laser), groundtruth.tum, meta.json "
      "and world.json per experiment."};
  SimConfig config;
  CLI::App* dataset = AddOptions(app, config);
  if (const std::optional<int> exit_code = slam::cli::Parse(app, argc, argv)) return *exit_code;
  config.kidnap_given = app.count("--kidnap") > 0;
  config.kidnap_to_given = app.count("--kidnap-to") > 0;

  auto robot = slam::io::LoadRobot(config.robot_path);
  if (!robot.ok()) {
    std::cerr << "slam-sim: " << robot.Message() << "\n";
    return 1;
  }
  slam::sim::ScenarioConfig base;
  base.duration_s = config.duration_s;
  base.scans_per_s = config.scans_per_s;
  base.speed_m_s = config.speed_m_s;
  base.turn_rate_rad_s = config.turn_rate_rad_s;
  base.people = config.people;

  std::vector<Job> jobs;
  // Each set's directory and the jobs of its index.json.
  std::vector<std::pair<std::string, std::vector<size_t>>> indexes;
  if (dataset->parsed()) {
    if (config.kidnap_given || config.kidnap_to_given) {
      std::cerr << "slam-sim: --kidnap and --kidnap-to are for one experiment, not 'dataset'\n";
      return 2;
    }
    PlanDatasetJobs(config, dataset->count("--duration") > 0, base, jobs, indexes);
  } else {
    if (config.world_spec.empty() || config.out_dir.empty()) {
      std::cerr << "slam-sim: --world and --out are required (or use 'slam-sim dataset'); "
                   "see --help\n";
      return 2;
    }
    Job job;
    if (!ResolveWorld(config.world_spec, job.world, job.world_name)) return 1;
    job.seed = config.seed;
    job.dir = config.out_dir;
    job.config =
        slam::sim::WithOdometryProfile(base, *slam::sim::OdometryProfileFromName(config.odometry));
    job.config.seed = config.seed;
    if (!KidnapOptions(config, job.world, job.world_name, job.config)) return 2;
    jobs.push_back(std::move(job));
  }

  std::vector<slam::sim::ExperimentSummary> summaries;
  if (!WriteExperiments(jobs, robot.value(), summaries)) return 1;

  const auto entry = [&](size_t i) {
    return nlohmann::json{{"dir", jobs[i].dir},
                          {"world", jobs[i].world_name},
                          {"seed", jobs[i].seed},
                          {"duration_s", jobs[i].config.duration_s},
                          {"odometry", jobs[i].config.odometry.profile},
                          {"frames", summaries[i].frames},
                          {"events", summaries[i].events}};
  };
  if (!dataset->parsed()) {
    std::cout << entry(0).dump(2) << "\n";
    return 0;
  }
  nlohmann::json all = nlohmann::json::array();
  for (const auto& [dir, members] : indexes) {
    nlohmann::json index = nlohmann::json::array();
    for (const size_t i : members) index.push_back(entry(i));
    const slam::Result<void> written = slam::io::WriteFileAtomic(
        (std::filesystem::path(dir) / "index.json").string(), index.dump(2) + "\n");
    if (!written.ok()) {
      std::cerr << "slam-sim: " << written.Message() << "\n";
      return 1;
    }
    for (auto& item : index) all.push_back(std::move(item));
  }
  std::cout << all.dump(2) << "\n";
  return 0;
}
