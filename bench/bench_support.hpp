#pragma once
// Shared inputs of the benchmark suites: the shipped robot, seeded simulated runs (built once
// per process and cached), a map built by the engine itself, and thread limits for oneTBB.
// Everything is deterministic: the same binary always measures the same inputs.

#include <benchmark/benchmark.h>
#include <tbb/global_control.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <tuple>
#include <vector>

#include "engine/io/robot_json.hpp"
#include "engine/pose.hpp"
#include "engine/robot.hpp"
#include "engine/scan.hpp"
#include "engine/slam.hpp"
#include "scheduler/fixed_plan.hpp"
#include "sim/scenario.hpp"
#include "sim/world.hpp"

namespace slam::bench {

/// The marXbot description the project ships (config/marxbot.robot.json); exits on failure.
inline const RobotDescription& ShippedRobot() {
  static const RobotDescription robot = [] {
    const auto loaded = io::LoadRobot(std::string(SLAM_SOURCE_DIR) + "/config/marxbot.robot.json");
    if (!loaded.ok()) {
      std::fprintf(stderr, "bench: %s\n", loaded.Message().c_str());
      std::exit(2);
    }
    return loaded.value();
  }();
  return robot;
}

/// A simulated run in a built-in arena, as the engine and the tuner consume it.
struct SimulatedRun {
  std::string name;  // "rooms-seed2-300s"
  double duration_s = 0.0;
  std::vector<Scan> scans;              // as a ScanAssembler makes them (half turns)
  std::vector<TimedPose> ground_truth;  // the overhead tracker's poses
  sim::ScenarioOutput output;           // every reading (for the link benchmarks)
};

/// The run of `arena` for `duration_s` with `seed`, simulated once per process (thread-safe).
inline const SimulatedRun& Run(const std::string& arena, double duration_s, uint64_t seed) {
  static std::mutex mutex;
  static std::map<std::tuple<std::string, double, uint64_t>, std::unique_ptr<SimulatedRun>> cache;
  const std::lock_guard lock(mutex);
  auto& slot = cache[{arena, duration_s, seed}];
  if (!slot) {
    sim::ScenarioConfig config;
    config.duration_s = duration_s;
    config.seed = seed;
    auto run = std::make_unique<SimulatedRun>();
    run->name = arena + "-seed" + std::to_string(seed) + "-" +
                std::to_string(static_cast<int>(duration_s)) + "s";
    run->duration_s = duration_s;
    run->output = sim::RunScenario(*sim::BuiltinWorld(arena), ShippedRobot(), config);
    run->scans = sim::BuildScans(ShippedRobot(), run->output.odometry, run->output.scanner);
    run->ground_truth = run->output.ground_truth;
    slot = std::move(run);
  }
  return *slot;
}

/// The run the engine benchmarks use: the "rooms" arena, seed 2 (the README's example experiment).
inline const SimulatedRun& RoomsRun(double duration_s) { return Run("rooms", duration_s, 2); }

/// Engine settings for benchmarks: the defaults, parallel as asked.
inline SlamConfig BenchConfig(bool parallel) {
  SlamConfig config;
  config.parallel = parallel;
  return config;
}

/// Table II defaults with `particles` particles.
inline SlamParams ParamsWith(int particles) {
  SlamParams params;
  params.particles = particles;
  return params;
}

/// The engine after mapping the first `scans` scans of `run` at `budget` rays/scan (fixed
/// policy): a realistic, partly explored map with walls, free space and unknown. The engine keeps
/// `parallel` (copies of it too); results do not depend on it.
inline Slam MappedEngine(const SimulatedRun& run, size_t scans, int64_t budget, int particles,
                         bool parallel = false) {
  Slam engine(ShippedRobot(), ParamsWith(particles), BenchConfig(parallel));
  for (size_t i = 0; i < scans && i < run.scans.size(); ++i) {
    const Scan& scan = run.scans[i];
    const PreparedScan prepared = engine.Prepare(scan);
    engine.ProcessScan(prepared, FixedPlan(prepared.summary, budget, engine.params()));
  }
  return engine;
}

/// Limits oneTBB to `threads` worker threads (the benchmark's thread argument) while alive.
class ThreadLimit {
 public:
  explicit ThreadLimit(int64_t threads)
      : control_(tbb::global_control::max_allowed_parallelism, static_cast<size_t>(threads)) {}

 private:
  tbb::global_control control_;
};

/// Sets an items/s counter and the label naming what an item is.
inline void Items(benchmark::State& state, int64_t items, const char* what) {
  state.SetItemsProcessed(items);
  state.SetLabel(what);
}

}  // namespace slam::bench
