// slam-sim: writes recorded experiments of the virtual marXbot (docs/design.md section 6).
//   slam-sim --world NAME|FILE --duration S --seed N --out DIR    one experiment
//   slam-sim dataset --out DIR                                     the reference set
// The same arguments always write the same files.

#include <tbb/parallel_for.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "engine/io/atomic_file.hpp"
#include "engine/io/robot_json.hpp"
#include "sim/experiment_writer.hpp"
#include "sim/scenario.hpp"
#include "sim/world.hpp"

namespace {

struct Job {
  std::string world_name;  // built-in name or the file's stem
  slam::sim::World world;
  uint64_t seed = 1;
  std::string dir;
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
  name = slam::sim::BuiltinArena(spec) ? spec : std::filesystem::path(spec).stem().string();
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Writes recorded experiments of the virtual marXbot: robot.json, can.log (candump -l), "
      "groundtruth.tum, meta.json and world.json per experiment."};
  std::string world_spec, out_dir;
  std::string robot_path = std::string(SLAM_SOURCE_DIR) + "/config/marxbot.robot.json";
  double duration_s = 300.0;
  uint64_t seed = 1;
  double scans_per_s = 1.5;
  app.add_option(
      "--world", world_spec,
      "built-in arena (" + std::string("box, rooms, cluttered") + ") or a world.json file");
  app.add_option("--duration", duration_s, "simulated seconds")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 86400.0));
  app.add_option("--seed", seed, "seed of the simulation")->capture_default_str();
  app.add_option("--out", out_dir, "output directory (created if needed)");
  app.add_option("--robot", robot_path, "robot description")->capture_default_str();
  app.add_option("--scans-per-s", scans_per_s, "half turns of the scanner per second")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 5.0));

  CLI::App* dataset = app.add_subcommand(
      "dataset",
      "the reference set: every built-in arena x RUNS seeds (1..RUNS) x DURATION s, "
      "in DIR/<arena>-<seed>/");
  std::string dataset_out;
  int runs = 5;
  dataset->add_option("--out", dataset_out, "output directory")->required();
  dataset->add_option("--runs", runs, "runs (seeds) per arena")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  dataset->add_option("--duration", duration_s, "simulated seconds per run")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 86400.0));
  CLI11_PARSE(app, argc, argv);

  auto robot = slam::io::LoadRobot(robot_path);
  if (!robot.ok()) {
    std::cerr << "slam-sim: " << robot.Message() << "\n";
    return 1;
  }
  slam::sim::ScenarioConfig base;
  base.duration_s = duration_s;
  base.scans_per_s = scans_per_s;

  std::vector<Job> jobs;
  if (dataset->parsed()) {
    out_dir = dataset_out;
    for (const std::string& name : slam::sim::BuiltinArenaNames()) {
      for (int r = 1; r <= runs; ++r) {
        Job job{name, *slam::sim::BuiltinArena(name), static_cast<uint64_t>(r), ""};
        job.dir = (std::filesystem::path(out_dir) / (name + "-" + std::to_string(r))).string();
        jobs.push_back(std::move(job));
      }
    }
  } else {
    if (world_spec.empty() || out_dir.empty()) {
      std::cerr << "slam-sim: --world and --out are required (or use 'slam-sim dataset'); "
                   "see --help\n";
      return 2;
    }
    Job job;
    if (!ResolveWorld(world_spec, job.world, job.world_name)) return 1;
    job.seed = seed;
    job.dir = out_dir;
    jobs.push_back(std::move(job));
  }

  const auto start = std::chrono::steady_clock::now();
  std::atomic<size_t> done{0};
  std::atomic<bool> failed{false};
  std::mutex io_mutex;
  std::vector<slam::sim::ExperimentSummary> summaries(jobs.size());
  tbb::parallel_for(size_t{0}, jobs.size(), [&](size_t i) {
    const Job& job = jobs[i];
    slam::sim::ScenarioConfig config = base;
    config.seed = job.seed;
    const slam::Result<void> written = slam::sim::WriteSimulatedExperiment(
        job.dir, job.world, job.world_name, robot.value(), config, &summaries[i]);
    const std::lock_guard lock(io_mutex);
    if (!written.ok()) {
      failed = true;
      std::cerr << "slam-sim: " << job.dir << ": " << written.Message() << "\n";
      return;
    }
    const double elapsed =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::fprintf(stderr, "[%zu/%zu] %s: %s seed %llu, %.0f s, %llu frames (%.1f s elapsed)\n",
                 ++done, jobs.size(), job.dir.c_str(), job.world_name.c_str(),
                 static_cast<unsigned long long>(job.seed), config.duration_s,
                 static_cast<unsigned long long>(summaries[i].frames), elapsed);
  });
  if (failed) return 1;

  nlohmann::json index = nlohmann::json::array();
  for (size_t i = 0; i < jobs.size(); ++i) {
    index.push_back({{"dir", jobs[i].dir},
                     {"world", jobs[i].world_name},
                     {"seed", jobs[i].seed},
                     {"duration_s", duration_s},
                     {"frames", summaries[i].frames},
                     {"events", summaries[i].events}});
  }
  if (dataset->parsed()) {
    const slam::Result<void> written = slam::io::WriteFileAtomic(
        (std::filesystem::path(out_dir) / "index.json").string(), index.dump(2) + "\n");
    if (!written.ok()) {
      std::cerr << "slam-sim: " << written.Message() << "\n";
      return 1;
    }
  }
  std::cout << (dataset->parsed() ? index.dump(2) : index[0].dump(2)) << "\n";
  return 0;
}
