#pragma once
// Recorded experiments (docs/design.md section 5): a directory with robot.json, can.log (candump
// -l), groundtruth.tum, meta.json and, for simulated worlds, world.json. This writes the simulated
// ones; the virtual marXbot's frames go through the same fragmenter and bus model as live.

#include <cstdint>
#include <optional>
#include <string>

#include "engine/result.hpp"
#include "engine/robot.hpp"
#include "sim/scenario.hpp"
#include "sim/world.hpp"

namespace slam::sim {

/// Simulated time 0 is this instant in the recordings (2023-11-14T22:13:20Z), so that logs
/// look like candump's (seconds since the epoch).
inline constexpr int64_t kSimulationEpochUs = 1'700'000'000'000'000;

/// The CAN interface name written in simulated logs.
inline constexpr const char* kSimulatedInterface = "can0";

struct ExperimentSummary {
  uint64_t frames = 0;
  uint64_t events = 0;
  uint64_t ground_truth_poses = 0;
};

/// Simulates `config` in `world` and writes the experiment into `dir` (created if needed; files
/// are replaced atomically). `world_name` goes into meta.json, and so does a kidnapping
/// (config.kidnap_t_s), as "kidnap": {"t": s, "from": [x, y, theta], "to": [x, y, theta]} (metres,
/// radians, world frame).
Result<void> WriteSimulatedExperiment(const std::string& dir, const World& world,
                                      const std::string& world_name, const RobotDescription& robot,
                                      const ScenarioConfig& config,
                                      ExperimentSummary* summary = nullptr);

}  // namespace slam::sim
