#include "sim/experiment_writer.hpp"

#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <system_error>

#include "engine/io/atomic_file.hpp"
#include "engine/io/robot_json.hpp"
#include "engine/io/tum.hpp"
#include "hw_link/candump.hpp"
#include "sim/virtual_marxbot.hpp"

namespace slam::sim {

Result<void> WriteSimulatedExperiment(const std::string& dir, const World& world,
                                      const std::string& world_name, const RobotDescription& robot,
                                      const ScenarioConfig& config, ExperimentSummary* summary) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return Error("cannot create " + dir + ": " + ec.message());

  const ScenarioOutput output = RunScenario(world, robot, config);
  const auto frames = SimulatedFrames(robot, output);
  std::string log;
  log.reserve(frames.size() * 48);
  for (const auto& [t, frame] : frames) {
    log += hw::FormatCandumpLine(kSimulationEpochUs + std::llround(t * 1e6), kSimulatedInterface,
                                 frame);
    log += '\n';
  }
  std::vector<TimedPose> truth = output.ground_truth;
  for (TimedPose& p : truth) {
    p.t = static_cast<double>(kSimulationEpochUs + std::llround(p.t * 1e6)) * 1e-6;
  }
  nlohmann::json meta;
  meta["name"] = world_name + "-seed" + std::to_string(config.seed);
  meta["world"] = world_name;
  meta["duration_s"] = config.duration_s;
  meta["source"] = "sim";
  meta["seed"] = config.seed;
  meta["odometry"] = config.odometry.profile;

  const std::string base = (std::filesystem::path(dir) / "").string();
  for (const auto& [name, text] :
       {std::pair<std::string, std::string>{"robot.json", io::RobotToJson(robot).dump(2) + "\n"},
        {"can.log", log},
        {"groundtruth.tum", io::FormatTum(truth)},
        {"meta.json", meta.dump(2) + "\n"},
        {"world.json", WorldToJson(world)}}) {
    if (Result<void> written = io::WriteFileAtomic(base + name, text); !written.ok())
      return written;
  }
  if (summary != nullptr) {
    summary->frames = frames.size();
    summary->events = output.odometry.size() + output.scanner.size();
    summary->ground_truth_poses = truth.size();
  }
  return {};
}

}  // namespace slam::sim
