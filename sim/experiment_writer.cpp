#include "sim/experiment_writer.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <nlohmann/json.hpp>
#include <system_error>

#include "engine/io/atomic_file.hpp"
#include "engine/io/robot_json.hpp"
#include "engine/io/tum.hpp"
#include "hw_link/candump.hpp"
#include "sim/virtual_marxbot.hpp"

namespace slam::sim {
namespace {

double LogTime(double t) {
  return static_cast<double>(kSimulationEpochUs + std::llround(t * 1e6)) * 1e-6;
}

/// A laser robot's run as a CARMEN log: ODOM lines (the dead-reckoned pose of every odometry
/// reading) and FLASER lines with the sweep's odometry, in time order.
std::string CarmenLog(const RobotDescription& robot, const ScenarioOutput& output) {
  const std::vector<TimedPose> odometry = DeadReckoning(robot, output.odometry);
  const auto odometry_at = [&](double t) {
    const auto after = std::lower_bound(odometry.begin(), odometry.end(), t,
                                        [](const TimedPose& p, double time) { return p.t < time; });
    if (after == odometry.end()) return odometry.back().pose;
    if (after == odometry.begin() || after->t == t) return after->pose;
    const TimedPose& before = *std::prev(after);
    return Interpolate(before.pose, after->pose, (t - before.t) / (after->t - before.t));
  };
  // Where the laser is on the robot, as CARMEN's laser pose says it (the reader derives the
  // mount from it).
  const Pose2 offset{
      robot.scanner.offset_x_m, robot.scanner.offset_y_m,
      robot.scanner.sensors.empty() ? 0.0 : DegToRad(robot.scanner.sensors.front().angle_deg)};
  std::string text =
      "# Simulated by slam-sim: a robot with a range scanner, CARMEN format.\n"
      "# ODOM x y theta tv rv accel timestamp hostname logger_timestamp\n"
      "# FLASER n r1..rn x y theta odom_x odom_y odom_theta timestamp hostname logger_timestamp\n";
  char line[128];
  size_t next_odometry = 0;
  const auto write_odometry_until = [&](double t) {
    for (; next_odometry < odometry.size() && odometry[next_odometry].t <= t; ++next_odometry) {
      const TimedPose& p = odometry[next_odometry];
      std::snprintf(line, sizeof(line), "ODOM %.6f %.6f %.6f 0 0 0 %.6f slam-sim %.6f\n", p.pose.x,
                    p.pose.y, p.pose.theta, LogTime(p.t), LogTime(p.t));
      text += line;
    }
  };
  for (const LaserSweep& sweep : output.sweeps) {
    write_odometry_until(sweep.t);
    if (odometry.empty()) break;
    const Pose2 at = odometry_at(sweep.t);
    const Pose2 laser = Compose(at, offset);
    text += "FLASER " + std::to_string(sweep.ranges.size());
    for (float r : sweep.ranges) {
      std::snprintf(line, sizeof(line), " %.3f", static_cast<double>(r));
      text += line;
    }
    std::snprintf(line, sizeof(line), " %.6f %.6f %.6f %.6f %.6f %.6f %.6f slam-sim %.6f\n",
                  laser.x, laser.y, laser.theta, at.x, at.y, at.theta, LogTime(sweep.t),
                  LogTime(sweep.t));
    text += line;
  }
  write_odometry_until(std::numeric_limits<double>::infinity());
  return text;
}

}  // namespace

Result<void> WriteSimulatedExperiment(const std::string& dir, const World& world,
                                      const std::string& world_name, const RobotDescription& robot,
                                      const ScenarioConfig& config, ExperimentSummary* summary) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return Error("cannot create " + dir + ": " + ec.message());

  const ScenarioOutput output = RunScenario(world, robot, config);
  // A robot with Sharp sensors talks CAN (can.log); one with a laser is recorded as CARMEN
  // logs are (log.clf).
  const bool laser = !output.sweeps.empty();
  std::string log;
  uint64_t frame_count = 0;
  if (laser) {
    log = CarmenLog(robot, output);
  } else {
    const auto frames = SimulatedFrames(robot, output);
    log.reserve(frames.size() * 48);
    for (const auto& [t, frame] : frames) {
      log += hw::FormatCandumpLine(kSimulationEpochUs + std::llround(t * 1e6), kSimulatedInterface,
                                   frame);
      log += '\n';
    }
    frame_count = frames.size();
  }
  std::vector<TimedPose> truth = output.ground_truth;
  for (TimedPose& p : truth) p.t = LogTime(p.t);
  nlohmann::json meta;
  meta["name"] = world_name + "-seed" + std::to_string(config.seed);
  meta["world"] = world_name;
  meta["duration_s"] = config.duration_s;
  meta["source"] = "sim";
  meta["seed"] = config.seed;
  meta["odometry"] = config.odometry.profile;
  if (config.people > 0) meta["people"] = config.people;
  if (!output.kidnaps.empty()) {
    // The jump as the ground truth shows it: when (the control step's start, to the microsecond)
    // and from where to where, in the world frame.
    const Kidnapping& k = output.kidnaps.front();
    const auto pose = [](const Pose2& p) { return nlohmann::json::array({p.x, p.y, p.theta}); };
    meta["kidnap"] = {
        {"t", std::round(k.t * 1e6) * 1e-6}, {"from", pose(k.from)}, {"to", pose(k.to)}};
  }

  const std::string base = (std::filesystem::path(dir) / "").string();
  for (const auto& [name, text] :
       {std::pair<std::string, std::string>{"robot.json", io::RobotToJson(robot).dump(2) + "\n"},
        {laser ? "log.clf" : "can.log", log},
        {"groundtruth.tum", io::FormatTum(truth)},
        {"meta.json", meta.dump(2) + "\n"},
        {"world.json", WorldToJson(world)}}) {
    if (Result<void> written = io::WriteFileAtomic(base + name, text); !written.ok())
      return written;
  }
  if (summary != nullptr) {
    summary->frames = frame_count;
    summary->events = output.odometry.size() + output.scanner.size() + output.sweeps.size();
    summary->ground_truth_poses = truth.size();
  }
  return {};
}

}  // namespace slam::sim
