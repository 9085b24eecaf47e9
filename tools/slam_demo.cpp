// slam-demo: simulates the marXbot in a world, runs the SLAM twice on the same data (with pose
// refinement, and odometry-only with phase B off), prints a JSON summary and writes the map
// (PNG picture, ROS PGM + YAML) and the SLAM trajectory (TUM) into an output directory.

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "engine/io/atomic_file.hpp"
#include "engine/io/map_image.hpp"
#include "engine/io/params_json.hpp"
#include "engine/io/robot_json.hpp"
#include "engine/io/tum.hpp"
#include "engine/quality.hpp"
#include "engine/slam.hpp"
#include "scheduler/fixed_plan.hpp"
#include "sim/scenario.hpp"
#include "sim/world.hpp"

namespace {

using Json = nlohmann::json;

constexpr const char* kUsage = R"(usage: slam-demo [options]

Simulates the marXbot wandering in a world, runs the SLAM on the recorded scans twice (with pose
refinement, and odometry-only with phase B off), prints a JSON summary on stdout and writes
map.png, map.pgm, map.yaml and trajectory.tum into the output directory.

options:
  --world NAME|FILE   built-in arena (box, rooms, cluttered) or a world.json file [box]
  --duration S        simulated seconds [60]
  --seed N            seed of the simulation and of the SLAM [1]
  --budget RAYS       rays per scan (paper: 8125, 16250, 32500, 65000) [65000]
  --params FILE       SLAM parameters (JSON, Table II keys) [defaults]
  --robot FILE        robot description [)" SLAM_SOURCE_DIR R"(/config/marxbot.robot.json]
  --out DIR           output directory, created if needed [demo-out]
  --help              this text
)";

struct Options {
  std::string world = "box";
  double duration_s = 60.0;
  uint64_t seed = 1;
  int64_t budget = 65000;
  std::string params_path;
  std::string robot_path = std::string(SLAM_SOURCE_DIR) + "/config/marxbot.robot.json";
  std::string out_dir = "demo-out";
  bool help = false;
};

/// Parses a whole string as a number, nullopt when it is not one.
std::optional<double> ParseDouble(const std::string& text) {
  try {
    size_t used = 0;
    const double v = std::stod(text, &used);
    if (used != text.size()) return std::nullopt;
    return v;
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

std::optional<int64_t> ParseInt(const std::string& text) {
  try {
    size_t used = 0;
    const long long v = std::stoll(text, &used);
    if (used != text.size()) return std::nullopt;
    return static_cast<int64_t>(v);
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

/// The options, or an error message naming the offending argument.
struct ParsedOptions {
  Options options;
  std::string error;
};

ParsedOptions ParseArgs(int argc, char** argv) {
  ParsedOptions parsed;
  Options& o = parsed.options;
  const std::vector<std::string> args(argv + 1, argv + argc);
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& flag = args[i];
    if (flag == "--help" || flag == "-h") {
      o.help = true;
      continue;
    }
    if (flag != "--world" && flag != "--duration" && flag != "--seed" && flag != "--budget" &&
        flag != "--params" && flag != "--robot" && flag != "--out") {
      parsed.error = "unknown argument '" + flag + "'";
      return parsed;
    }
    if (i + 1 >= args.size()) {
      parsed.error = flag + " needs a value";
      return parsed;
    }
    const std::string& value = args[++i];
    if (flag == "--world") {
      o.world = value;
    } else if (flag == "--duration") {
      const auto v = ParseDouble(value);
      if (!v || !(*v > 0.0) || *v > 86400.0) {
        parsed.error = "--duration: expected seconds in (0, 86400], got '" + value + "'";
        return parsed;
      }
      o.duration_s = *v;
    } else if (flag == "--seed") {
      const auto v = ParseInt(value);
      if (!v || *v < 0) {
        parsed.error = "--seed: expected a non-negative integer, got '" + value + "'";
        return parsed;
      }
      o.seed = static_cast<uint64_t>(*v);
    } else if (flag == "--budget") {
      const auto v = ParseInt(value);
      if (!v || *v < 1) {
        parsed.error = "--budget: expected a positive number of rays, got '" + value + "'";
        return parsed;
      }
      o.budget = *v;
    } else if (flag == "--params") {
      o.params_path = value;
    } else if (flag == "--robot") {
      o.robot_path = value;
    } else {
      o.out_dir = value;
    }
  }
  return parsed;
}

/// What one SLAM run produced.
struct RunResult {
  std::vector<slam::TimedPose> trajectory;
  std::optional<slam::OccupancyGrid> map;
  std::optional<slam::TrajectoryQuality> quality;
  int64_t rays_total = 0;
  int64_t rays_per_scan_max = 0;
  double wall_s = 0.0;
  double cpu_s = 0.0;
};

RunResult RunSlam(const std::string& label, const slam::RobotDescription& robot,
                  const slam::SlamParams& params, uint64_t seed, int64_t budget, bool refine,
                  const std::vector<slam::Scan>& scans,
                  const std::vector<slam::TimedPose>& ground_truth) {
  slam::SlamConfig config;
  config.seed = seed;
  slam::Slam engine(robot, params, config);
  RunResult result;
  const bool interactive = ::isatty(STDERR_FILENO) != 0;
  const auto wall_start = std::chrono::steady_clock::now();
  const std::clock_t cpu_start = std::clock();
  for (size_t k = 0; k < scans.size(); ++k) {
    slam::ScanPlan plan = slam::FixedPlan(engine.Summarize(scans[k]), budget, params);
    plan.refine = refine;
    const slam::ScanReport report = engine.ProcessScan(scans[k], plan);
    result.rays_total += report.rays.total();
    result.rays_per_scan_max = std::max(result.rays_per_scan_max, report.rays.total());
    // Progress: rewritten in place on a terminal, every tenth of the run otherwise.
    const size_t tenth = std::max<size_t>(1, scans.size() / 10);
    if (k + 1 == scans.size() || (interactive && k % 10 == 0) || (!interactive && k % tenth == 0)) {
      std::fprintf(stderr, "%s[%s] scan %zu/%zu, %" PRId64 " rays%s", interactive ? "\r" : "",
                   label.c_str(), k + 1, scans.size(), report.rays.total(),
                   interactive ? "" : "\n");
      std::fflush(stderr);
    }
  }
  if (interactive) std::fprintf(stderr, "\n");
  result.wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  result.cpu_s = static_cast<double>(std::clock() - cpu_start) / CLOCKS_PER_SEC;
  result.trajectory = engine.Trajectory();
  result.map = engine.Best().map;
  result.quality = slam::EvaluateTrajectory(result.trajectory, ground_truth);
  return result;
}

Json RunJson(const RunResult& run, size_t scans, double duration_s) {
  Json j;
  if (run.quality) {
    j["q"] = run.quality->q_cm2;
    j["e"] = run.quality->e;
    j["ate_rmse_m"] = run.quality->ate_rmse_m;
    j["matched_poses"] = run.quality->matched;
  } else {
    j["q"] = nullptr;
    j["e"] = nullptr;
    j["ate_rmse_m"] = nullptr;
  }
  j["rays_total"] = run.rays_total;
  j["rays_per_scan_max"] = run.rays_per_scan_max;
  j["rays_per_scan_mean"] =
      scans > 0 ? static_cast<double>(run.rays_total) / static_cast<double>(scans) : 0.0;
  j["wall_s"] = run.wall_s;
  j["cpu_s"] = run.cpu_s;
  j["cpu_ms_per_scan"] = scans > 0 ? 1000.0 * run.cpu_s / static_cast<double>(scans) : 0.0;
  j["realtime_factor"] = run.wall_s > 0.0 ? duration_s / run.wall_s : 0.0;
  return j;
}

/// The reference trajectory brought into the estimate's frame (inverse of the alignment).
std::vector<slam::TimedPose> IntoEstimateFrame(const std::vector<slam::TimedPose>& reference,
                                               const slam::RigidTransform2& alignment) {
  const double c = std::cos(alignment.rotation_rad), s = std::sin(alignment.rotation_rad);
  std::vector<slam::TimedPose> out;
  out.reserve(reference.size());
  for (const slam::TimedPose& p : reference) {
    const slam::Vec2 d = p.pose.translation() - alignment.translation;
    out.push_back({p.t,
                   {c * d.x() + s * d.y(), -s * d.x() + c * d.y(),
                    slam::NormalizeAngle(p.pose.theta - alignment.rotation_rad)}});
  }
  return out;
}

int Fail(const std::string& message) {
  std::cerr << "slam-demo: " << message << "\n";
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  const ParsedOptions parsed = ParseArgs(argc, argv);
  if (!parsed.error.empty()) {
    std::cerr << "slam-demo: " << parsed.error << "\n(see slam-demo --help)\n";
    return 2;
  }
  const Options& options = parsed.options;
  if (options.help) {
    std::cout << kUsage;
    return 0;
  }

  const auto robot = slam::io::LoadRobot(options.robot_path);
  if (!robot.ok()) return Fail("cannot load the robot:\n" + robot.Message());
  slam::SlamParams params;
  if (!options.params_path.empty()) {
    const auto loaded = slam::io::LoadParams(options.params_path);
    if (!loaded.ok()) return Fail("cannot load the parameters:\n" + loaded.Message());
    params = loaded.value();
  }
  const slam::sim::WorldLoadResult world = slam::sim::ResolveWorld(options.world);
  if (!world.ok()) {
    std::string message;
    if (std::filesystem::exists(options.world)) {
      message = "cannot load the world:";
    } else {
      message = "unknown world '" + options.world + "' (built-in:";
      for (const std::string& name : slam::sim::BuiltinArenaNames()) message += " " + name;
      message += ", or a world.json file):";
    }
    for (const std::string& e : world.errors) message += "\n" + e;
    return Fail(message);
  }
  std::error_code ec;
  std::filesystem::create_directories(options.out_dir, ec);
  if (ec) return Fail("cannot create " + options.out_dir + ": " + ec.message());

  // Simulate.
  slam::sim::ScenarioConfig scenario;
  scenario.duration_s = options.duration_s;
  scenario.seed = options.seed;
  const auto sim_start = std::chrono::steady_clock::now();
  const slam::sim::ScenarioOutput recording =
      slam::sim::RunScenario(*world.world, robot.value(), scenario);
  const std::vector<slam::Scan> scans =
      slam::sim::BuildScans(robot.value(), recording.odometry, recording.scanner);
  const double sim_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - sim_start).count();
  std::fprintf(stderr, "[sim] %s, %.0f s, seed %" PRIu64 ": %zu scans in %.2f s\n",
               world.world->name.c_str(), options.duration_s, options.seed, scans.size(), sim_s);

  // SLAM with phase B, then odometry-only.
  const RunResult full = RunSlam("slam", robot.value(), params, options.seed, options.budget, true,
                                 scans, recording.ground_truth);
  const RunResult odometry = RunSlam("odometry-only", robot.value(), params, options.seed,
                                     options.budget, false, scans, recording.ground_truth);

  // Outputs.
  const std::string dir = options.out_dir + "/";
  std::vector<std::string> errors;
  const auto check = [&](std::optional<std::string> error) {
    if (error) errors.push_back(*error);
  };
  const slam::io::GridImage grid_image = slam::io::MakeGridImage(*full.map);
  check(slam::io::WritePgm(dir + "map.pgm", grid_image));
  check(slam::io::WriteMapYaml(dir + "map.yaml", "map.pgm", grid_image));
  check(slam::io::WriteFileAtomic(dir + "trajectory.tum", slam::io::FormatTum(full.trajectory)));
  std::vector<slam::io::TrajectoryLayer> layers;
  layers.push_back({"odometry only", odometry.trajectory, {150, 150, 150}});
  if (full.quality) {
    layers.push_back({"ground truth (aligned)",
                      IntoEstimateFrame(recording.ground_truth, full.quality->alignment),
                      {0, 60, 255}});
  }
  layers.push_back({"SLAM", full.trajectory, {230, 0, 0}});
  check(slam::io::WritePng(dir + "map.png", slam::io::RenderMapPicture(*full.map, layers, 3)));

  Json summary;
  summary["world"] = world.world->name;
  summary["duration_s"] = options.duration_s;
  summary["seed"] = options.seed;
  summary["budget"] = options.budget;
  summary["scans"] = scans.size();
  const Json slam_json = RunJson(full, scans.size(), options.duration_s);
  for (const auto& [key, value] : slam_json.items()) summary[key] = value;
  summary["odometry_only"] = RunJson(odometry, scans.size(), options.duration_s);
  summary["out"] = options.out_dir;
  std::cout << summary.dump(2) << "\n";
  for (const std::string& e : errors) std::cerr << "slam-demo: " << e << "\n";
  return errors.empty() ? 0 : 1;
}
