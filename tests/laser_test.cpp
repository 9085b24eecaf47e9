// Range scanners end to end: CARMEN logs as experiments, the simulated lidar, and the SLAM on it.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "engine/io/robot_json.hpp"
#include "engine/odometry.hpp"
#include "engine/sensor_model.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/replay.hpp"
#include "offline/replay_report.hpp"
#include "scheduler/params_catalog.hpp"
#include "sim/experiment_writer.hpp"
#include "sim/world.hpp"
#include "tests/test_support.hpp"

namespace slam {
namespace {

namespace fs = std::filesystem;

RobotDescription LidarRobot() {
  const auto robot = io::LoadRobot(std::string(SLAM_SOURCE_DIR) + "/config/lidar.robot.json");
  if (!robot.ok()) ADD_FAILURE() << robot.Message();
  return robot.ok() ? robot.value() : RobotDescription{};
}

/// A replay of `e` with `options`, and the same with phase B off (dead reckoning's map).
struct SlamAndOdometry {
  offline::ReplayResult slam, odometry;
};
SlamAndOdometry ReplayBoth(const offline::Experiment& e, offline::ReplayOptions options) {
  offline::ReplayResult slam = offline::Replay(e.robot, e.scans, e.ground_truth, options);
  options.refine = false;
  return {std::move(slam), offline::Replay(e.robot, e.scans, e.ground_truth, options)};
}

TEST(LaserTest, ACarmenLogBecomesScansWithTheirOdometryAndBeams) {
  const testing::TempDir dir("carmen_experiment");
  const std::string path = dir.File("run.clf");
  std::ofstream(path) << "# hand-made\n"
                         "ODOM 0 0 0 0 0 0 10.0 h 10.0\n"
                         // No pose of its own: odometry halfway between 10 s and 11 s.
                         "FLASER 3 1.0 2.0 81.83 10.5 h 10.5\n"
                         "ODOM 1 0 0.5 0 0 0 11.0 h 11.0\n"
                         "FLASER 3 1.5 81.83 0.5 0 0 0 2 1 0.25 11.5 h 11.5\n"
                         "FLASER 3 1.5 1.5 1.5 11.2 h 11.2\n"  // back in time: left out
                         "FLASER 2 1.5 1.5 2 1 0.25 2 1 0.25 11.8 h 11.8\n"  // 2 beams, not 3
                         "FLASER 3 0.9 1.1 81.83 3 1 0.5 3 1 0.5 12.5 h 12.5\n";
  const Result<offline::Experiment> load = offline::LoadExperiment(path);
  ASSERT_TRUE(load.ok()) << load.Message();
  const offline::Experiment& e = load.value();
  EXPECT_EQ(e.meta.name, "run");
  EXPECT_TRUE(e.ground_truth.empty());

  // The derived robot: one range sensor, 3 beams over 180 degrees, 81.83 taken for no return;
  // its ODOM records turn by the wheels' encoders (the engine learns their drift per metre).
  EXPECT_FALSE(e.robot.base.heading_from_gyro);
  ASSERT_EQ(e.robot.scanner.sensors.size(), 1u);
  const SensorTypeDescription& laser = e.robot.sensor_types.at(e.robot.scanner.sensors[0].type);
  EXPECT_EQ(laser.kind, SensorKind::kRange);
  EXPECT_EQ(laser.beams.count, 3);
  EXPECT_DOUBLE_EQ(laser.beams.first_deg, -90.0);
  EXPECT_DOUBLE_EQ(laser.beams.increment_deg, 90.0);
  EXPECT_FLOAT_EQ(static_cast<float>(laser.no_return_m), 81.83f);
  EXPECT_LT(laser.use_max_m, laser.no_return_m);
  EXPECT_GE(laser.use_max_m, 2.0);

  ASSERT_EQ(e.scans.size(), 3u);
  EXPECT_EQ(e.counters.scans_out_of_order, 1u);
  EXPECT_EQ(e.counters.bad_lines, 1u);
  ASSERT_EQ(e.problems.size(), 1u);
  EXPECT_NE(e.problems[0].find("run.clf:7: FLASER has 2 readings"), std::string::npos)
      << e.problems[0];

  const Scan& first = e.scans[0];
  EXPECT_DOUBLE_EQ(first.t_end, 10.5);
  EXPECT_DOUBLE_EQ(first.t_begin, 9.5);  // as long as the gap to the next record
  EXPECT_NEAR(first.odom_end.x, 0.5, 1e-12);
  EXPECT_NEAR(first.odom_end.theta, 0.25, 1e-12);
  ASSERT_EQ(first.samples.size(), 3u);
  EXPECT_NEAR(first.samples[0].platform_angle_rad, -kPi / 2, 1e-12);
  EXPECT_NEAR(first.samples[2].platform_angle_rad, kPi / 2, 1e-12);
  EXPECT_EQ(first.samples[0].raw[0], 1000);  // millimetres
  EXPECT_EQ(first.samples[1].raw[0], 2000);
  EXPECT_EQ(first.samples[2].raw[0], 0);  // no return: no reading
  for (const ScanSample& s : first.samples) EXPECT_DOUBLE_EQ(s.t, 10.5);

  const Scan& second = e.scans[1];  // its own odometry pose (the last three pose numbers)
  EXPECT_DOUBLE_EQ(second.t_begin, 10.5);
  EXPECT_DOUBLE_EQ(second.odom_end.x, 2.0);
  EXPECT_DOUBLE_EQ(second.odom_end.theta, 0.25);
  EXPECT_DOUBLE_EQ(second.odom_begin.x, first.odom_end.x);
  EXPECT_DOUBLE_EQ(e.scans[2].t_begin, 11.5);  // after the records left out

  // The sensor model reads the millimetres back inside the use window.
  const SensorModel model(laser, {}, 0.05);
  EXPECT_NEAR(*model.Distance(first.samples[0].raw[0]), 1.0, 1e-12);
  EXPECT_FALSE(model.Distance(0));
  EXPECT_FALSE(model.Distance(RangeToRaw(laser.use_min_m / 2)));
  const std::optional<UpdateProfile> update = model.Update(first.samples[1].raw[0]);
  ASSERT_TRUE(update.has_value());
  EXPECT_NEAR(update->free_bins * update->step_m, 2.0, update->step_m);
}

TEST(LaserTest, RangesTravelAsMillimetres) {
  EXPECT_EQ(RangeToRaw(1.2345), 1235);  // rounded: 1234.5 mm -> 1235
  EXPECT_EQ(RangeToRaw(65.535), 65535);
  EXPECT_EQ(RangeToRaw(65.6), 0);
  EXPECT_EQ(RangeToRaw(0.0), 0);
  EXPECT_EQ(RangeToRaw(-1.0), 0);
  EXPECT_EQ(RangeToRaw(std::nan("")), 0);
  EXPECT_EQ(RangeToRaw(std::numeric_limits<double>::infinity()), 0);
}

TEST(LaserTest, ARangeSensorDescriptionIsCheckedAndRoundTrips) {
  const RobotDescription lidar = LidarRobot();
  EXPECT_TRUE(Validate(lidar).empty());
  const auto back = io::RobotFromJson(io::RobotToJson(lidar));
  ASSERT_TRUE(back.ok()) << back.Message();
  EXPECT_EQ(io::RobotToJson(back.value()), io::RobotToJson(lidar));
  EXPECT_DOUBLE_EQ(back.value().scanner.offset_x_m, 0.02);

  RobotDescription bad = lidar;
  SensorTypeDescription& type = bad.sensor_types.at("lidar");
  type.beams.count = 0;
  type.no_return_m = 5.0;   // inside the use window
  type.range_max_m = 80.0;  // beyond what millimetres in 16 bits carry
  type.use_min_m = 0.0;
  type.calibration = {{900, 0.1}, {100, 1.0}};
  const ConfigErrors errors = Validate(bad);
  std::string all;
  for (const ConfigError& e : errors) all += e.pointer + ": " + e.detail + "\n";
  for (const char* pointer : {"/sensor_types/lidar/beams/count", "/sensor_types/lidar/no_return_m",
                              "/sensor_types/lidar/range_m/1", "/sensor_types/lidar/use_m/0",
                              "/sensor_types/lidar/calibration"}) {
    EXPECT_NE(all.find(std::string(pointer) + ":"), std::string::npos) << pointer << "\n" << all;
  }
  // An unknown kind is refused by the reader.
  nlohmann::json json = io::RobotToJson(lidar);
  json["sensor_types"]["lidar"]["kind"] = "sonar";
  const auto sonar = io::RobotFromJson(json);
  ASSERT_FALSE(sonar.ok());
  EXPECT_NE(sonar.Message().find("/sensor_types/lidar/kind"), std::string::npos) << sonar.Message();
}

TEST(LaserTest, ARobotWithoutAGyroTurnsByItsEncoders) {
  RobotDescription robot = LidarRobot();
  robot.base.heading_from_gyro = false;
  const auto back = io::RobotFromJson(io::RobotToJson(robot));
  ASSERT_TRUE(back.ok()) << back.Message();
  EXPECT_FALSE(back.value().base.heading_from_gyro);
  EXPECT_EQ(io::RobotToJson(robot)["base"]["heading"], "encoders");
  EXPECT_FALSE(io::RobotToJson(LidarRobot())["base"].contains("heading"));  // the default: gyro

  nlohmann::json json = io::RobotToJson(robot);
  json["base"]["heading"] = "compass";
  const auto bad = io::RobotFromJson(json);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.Message().find("/base/heading"), std::string::npos) << bad.Message();

  // 20 ms apart, the gyro claiming 90 deg/s: the encoders alone turn a robot without one.
  const BaseDescription& base = robot.base;
  const auto ticks = [&](double metres) { return static_cast<int32_t>(metres * base.ticks_per_m); };
  const int16_t gyro = static_cast<int16_t>(90.0 / base.gyro_unit_dps);
  for (const bool from_gyro : {true, false}) {
    BaseDescription b = base;
    b.heading_from_gyro = from_gyro;
    OdometryIntegrator odometry(b);
    odometry.Add({0.0, 0, 0, 0, gyro});
    // The right treel 1 cm ahead of the left one: 0.01 / track_width radians.
    const Pose2 p = odometry.Add({0.02, 1, ticks(0.0), ticks(0.01), gyro});
    const double expected = from_gyro ? DegToRad(90.0) * 0.02 : 0.01 / b.track_width_m;
    EXPECT_NEAR(p.theta, expected, 1e-3) << (from_gyro ? "gyro" : "encoders");
  }
}

TEST(LaserTest, ALaserRobotGetsFiveCentimetreCellsAndTheLaserParameters) {
  const RobotDescription lidar = LidarRobot();
  const RobotDescription marxbot = testing::ShippedRobot();
  EXPECT_TRUE(HasRangeScanner(lidar));
  EXPECT_FALSE(HasRangeScanner(marxbot));
  EXPECT_DOUBLE_EQ(DefaultResolution(lidar), 0.05);
  EXPECT_DOUBLE_EQ(DefaultResolution(marxbot), 0.01);
  EXPECT_EQ(FamilyOf(lidar), ParamsFamily::kRange);
  EXPECT_EQ(FamilyOf(marxbot), ParamsFamily::kInfrared);
  const ParamsChoice shipped;
  EXPECT_EQ(shipped.ForRobot(lidar).For(8125).name, "shipped-laser-8125");
  EXPECT_EQ(shipped.ForRobot(marxbot).For(8125).name, "shipped-8125");
  const ParamsChoice given("mine.json", SlamParams{});
  EXPECT_EQ(given.ForRobot(lidar).For(8125).name, "mine.json");

  // A replay of a laser robot without a resolution or parameters of its own takes both.
  const testing::TempDir dir("lidar_defaults");
  sim::ScenarioConfig config = sim::WithOdometryProfile({}, sim::OdometryProfile::kTracked);
  config.duration_s = 10.0;
  config.scans_per_s = 1.0;
  const std::string out = dir.File("rooms");
  ASSERT_TRUE(
      sim::WriteSimulatedExperiment(out, *sim::BuiltinWorld("rooms"), "rooms", lidar, config).ok());
  const Result<offline::Experiment> load = offline::LoadExperiment(out);
  ASSERT_TRUE(load.ok()) << load.Message();
  offline::ReplayOptions options;
  options.params = ParamsChoice{};
  options.budget.rays_per_scan = 16250;
  const offline::ReplayResult run =
      offline::Replay(load.value().robot, load.value().scans, load.value().ground_truth, options);
  EXPECT_DOUBLE_EQ(run.map.geometry().resolution(), 0.05);
  EXPECT_EQ(run.params_set.name, "shipped-laser-16250");
  const nlohmann::json summary = offline::ReplaySummary(load.value(), run, options);
  EXPECT_DOUBLE_EQ(summary["resolution_m"].get<double>(), 0.05);
}

TEST(LaserTest, ALogDirectoryNeedsNoMetaAndIsNamedAfterItself) {
  const testing::TempDir dir("carmen_dir");
  const std::string exp = dir.File("hallway-run");
  fs::create_directories(exp);
  std::ofstream(exp + "/log.clf") << "ODOM 0 0 0 0 0 0 10.0 h 10.0\n"
                                     "FLASER 3 1.0 2.0 1.5 0 0 0 0 0 0 10.0 h 10.0\n"
                                     "ODOM 0.1 0 0 0 0 0 11.0 h 11.0\n"
                                     "FLASER 3 1.0 2.0 1.5 0.1 0 0 0.1 0 0 11.0 h 11.0\n";
  const Result<offline::Experiment> load = offline::LoadExperiment(exp + "/");
  ASSERT_TRUE(load.ok()) << load.Message();
  EXPECT_EQ(load.value().meta.name, "hallway-run");
  EXPECT_EQ(load.value().scans.size(), 2u);
  // A meta.json that is there must be valid.
  std::ofstream(exp + "/meta.json") << "{\"name\": 3}";
  const Result<offline::Experiment> bad = offline::LoadExperiment(exp);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.Message().find("meta.json"), std::string::npos) << bad.Message();
}

/// A simulated minute of the lidar robot in the rooms world (a tracked robot's odometry, two
/// sweeps a second, seed 7), written into `dir` as an experiment directory; its path.
std::string SimulatedLidarRooms(const testing::TempDir& dir) {
  sim::ScenarioConfig config = sim::WithOdometryProfile({}, sim::OdometryProfile::kTracked);
  config.duration_s = 60.0;
  config.scans_per_s = 2.0;
  config.seed = 7;
  const std::string out = dir.File("rooms");
  const Result<void> written = sim::WriteSimulatedExperiment(out, *sim::BuiltinWorld("rooms"),
                                                             "rooms", LidarRobot(), config);
  EXPECT_TRUE(written.ok()) << written.Message();
  return out;
}

TEST(LaserTest, TheSimulatedLidarIsRecordedAsACarmenLogAndMappedBetterThanOdometry) {
  const testing::TempDir dir("lidar_experiment");
  const std::string out = SimulatedLidarRooms(dir);
  EXPECT_TRUE(fs::exists(out + "/log.clf"));
  EXPECT_FALSE(fs::exists(out + "/can.log"));

  const Result<offline::Experiment> load = offline::LoadExperiment(out);
  ASSERT_TRUE(load.ok()) << load.Message();
  const offline::Experiment& e = load.value();
  EXPECT_EQ(e.meta.source, "sim");
  EXPECT_EQ(e.robot.name, "marxbot-lidar");  // robot.json's, not one derived from the log
  EXPECT_EQ(e.counters.bad_lines, 0u);
  EXPECT_NEAR(static_cast<double>(e.scans.size()), 60.0 * 2.0, 2.0);
  EXPECT_FALSE(e.ground_truth.empty());
  ASSERT_FALSE(e.scans.empty());
  EXPECT_EQ(e.scans.back().samples.size(), 360u);
  size_t readings = 0;
  for (const ScanSample& s : e.scans.back().samples) readings += s.raw[0] != 0;
  EXPECT_GT(readings, 300u);  // a room: most beams see a wall within 12 m

  offline::ReplayOptions options;
  options.budget.rays_per_scan = 32500;
  options.config.seed = 1;
  const auto [slam, odometry] = ReplayBoth(e, options);
  ASSERT_TRUE(slam.quality && odometry.quality);
  EXPECT_LE(slam.rays_per_scan_max, 32500);
  EXPECT_LT(slam.quality->ate_rmse_m, odometry.quality->ate_rmse_m);
  EXPECT_LT(slam.quality->ate_rmse_m, 0.05);
}

TEST(LaserTest, ABaseRestartedMidRunIsCountedAndTheMapHoldsAcrossIt) {
  const testing::TempDir dir("restart_experiment");
  const std::string out = SimulatedLidarRooms(dir);

  // From 30 s on, the log's odometry restarts from 25 m away and turned by 2 rad: every ODOM
  // record's pose and every FLASER record's poses (the laser's and the odometry's) move there.
  const std::string log = out + "/log.clf";
  std::ifstream in(log);
  std::vector<std::string> lines;
  std::optional<double> t_start;
  const Pose2 restart{25.0, -8.0, 2.0};
  for (std::string line; std::getline(in, line);) {
    std::istringstream fields(line);
    std::vector<std::string> f{std::istream_iterator<std::string>(fields), {}};
    size_t pose_at = 0, poses = 0;  // the first pose field, and how many poses follow
    if (!f.empty() && f[0] == "ODOM") {
      pose_at = 1;
      poses = 1;
    } else if (!f.empty() && f[0] == "FLASER") {
      pose_at = 2 + std::stoul(f[1]);
      poses = 2;
    }
    if (poses > 0) {
      const double t = std::stod(f[pose_at + 3 * poses + (f[0] == "ODOM" ? 3 : 0)]);
      if (!t_start) t_start = t;
      if (t - *t_start >= 30.0) {
        for (size_t k = 0; k < poses; ++k) {
          const size_t i = pose_at + 3 * k;
          const Pose2 moved =
              Compose(restart, {std::stod(f[i]), std::stod(f[i + 1]), std::stod(f[i + 2])});
          f[i] = std::to_string(moved.x);
          f[i + 1] = std::to_string(moved.y);
          f[i + 2] = std::to_string(moved.theta);
        }
        line.clear();
        for (const std::string& field : f) line += (line.empty() ? "" : " ") + field;
      }
    }
    lines.push_back(line);
  }
  in.close();
  {
    std::ofstream rewritten(log);
    for (const std::string& line : lines) rewritten << line << "\n";
  }

  const Result<offline::Experiment> load = offline::LoadExperiment(out);
  ASSERT_TRUE(load.ok()) << load.Message();
  const offline::Experiment& e = load.value();
  EXPECT_EQ(e.counters.assembler.odometry_jumps, 1u);
  EXPECT_TRUE(e.problems.empty());  // nothing is left out
  ASSERT_EQ(e.notes.size(), 1u);    // the reader's assumption, said
  EXPECT_NE(e.notes[0].find("taken for a restart of the base"), std::string::npos) << e.notes[0];
  EXPECT_NE(e.notes[0].find("log.clf:"), std::string::npos) << e.notes[0];
  // Across the restart the pose holds: no scan moves further than a sweep's drive.
  for (size_t i = 1; i < e.scans.size(); ++i) {
    const Pose2 step = Between(e.scans[i].odom_begin, e.scans[i].odom_end);
    EXPECT_LT(std::hypot(step.x, step.y), 0.5) << "scan " << i;
  }

  // The map holds too: as accurate as the log without the restart (the same bound).
  offline::ReplayOptions options;
  options.budget.rays_per_scan = 32500;
  options.config.seed = 1;
  const auto [slam, odometry] = ReplayBoth(e, options);
  ASSERT_TRUE(slam.quality && odometry.quality);
  EXPECT_LT(slam.quality->ate_rmse_m, 0.05);
  EXPECT_LT(odometry.quality->ate_rmse_m, 2.0);  // one held step, not a 25 m teleport
}

/// A FLASER record of three beams at time `t`: the robot's odometry `odometry` and the laser's
/// pose, `mount` on the robot.
std::string FlaserLine(double t, const Pose2& odometry, const Pose2& mount) {
  const Pose2 laser = Compose(odometry, mount);
  char line[200];
  std::snprintf(line, sizeof(line),
                "FLASER 3 1.0 2.0 3.0 %.6f %.6f %.6f %.6f %.6f %.6f %.3f h %.3f\n", laser.x,
                laser.y, laser.theta, odometry.x, odometry.y, odometry.theta, t, t);
  return line;
}

TEST(LaserTest, ABareLogsLaserIsWhereItsParamsOrItsRecordsPutIt) {
  const Pose2 mount{0.15, -0.04, DegToRad(5.0)};
  const std::vector<Pose2> path = {
      {0.0, 0.0, 0.0}, {1.0, 0.5, 0.3}, {2.0, 1.0, 1.2}, {-3.0, 4.0, -2.5}, {5.0, -2.0, 3.1}};
  const auto log_of = [&](const std::string& head, const std::vector<Pose2>& mounts) {
    std::string text = head;
    for (size_t i = 0; i < path.size(); ++i) {
      text += FlaserLine(10.0 + 10.0 * static_cast<double>(i), path[i], mounts[i]);
    }
    const Result<offline::CarmenLog> log = offline::ParseCarmenLog(text, "t.clf");
    EXPECT_TRUE(log.ok()) << log.Message();
    return log.ok() ? log.value() : offline::CarmenLog{};
  };
  const std::vector<Pose2> fixed(path.size(), mount);
  // (The records are 10 s apart: the path's steps, up to 10 m, are drives, not restarts.)

  // A raw log: every record puts the laser at one place on the robot.
  const offline::CarmenMount raw = offline::DeriveCarmenMount(log_of("", fixed));
  EXPECT_NEAR(raw.pose.x, 0.15, 1e-9);
  EXPECT_NEAR(raw.pose.y, -0.04, 1e-9);
  EXPECT_NEAR(RadToDeg(raw.pose.theta), 5.0, 1e-9);
  EXPECT_NE(raw.source.find("FLASER records"), std::string::npos) << raw.source;
  const RobotDescription robot = offline::DeriveCarmenRobot(log_of("", fixed), "t");
  EXPECT_NEAR(robot.scanner.offset_x_m, 0.15, 1e-9);
  EXPECT_NEAR(robot.scanner.offset_y_m, -0.04, 1e-9);
  EXPECT_NEAR(robot.scanner.sensors.at(0).angle_deg, 5.0, 1e-9);

  // CARMEN's parameters say it first.
  const offline::CarmenMount param = offline::DeriveCarmenMount(
      log_of("PARAM robot_frontlaser_offset 0.3 h 0\nPARAM robot_frontlaser_side_offset 0.02 h 0\n",
             fixed));
  EXPECT_DOUBLE_EQ(param.pose.x, 0.3);
  EXPECT_DOUBLE_EQ(param.pose.y, 0.02);
  EXPECT_DOUBLE_EQ(param.pose.theta, 0.0);
  EXPECT_NE(param.source.find("PARAM"), std::string::npos) << param.source;

  // A log whose laser poses were corrected after the run: they move about the robot, so they
  // say nothing of the mount; the laser is taken at the centre, and the reason given.
  std::vector<Pose2> moved = fixed;
  moved[3] = {0.4, 0.1, 0.02};
  const offline::CarmenMount corrected = offline::DeriveCarmenMount(log_of("", moved));
  EXPECT_EQ(corrected.pose.x, 0.0);
  EXPECT_EQ(corrected.pose.y, 0.0);
  EXPECT_EQ(corrected.pose.theta, 0.0);
  EXPECT_NE(corrected.source.find("1 of 5 elsewhere"), std::string::npos) << corrected.source;

  // Records without poses (the short FLASER form): the centre, and why.
  const Result<offline::CarmenLog> bare = offline::ParseCarmenLog(
      "ODOM 0 0 0 0 0 0 1 h 1\nFLASER 3 1 2 3 1.5 h 1.5\n"
      "ODOM 1 0 0 0 0 0 2 h 2\n",
      "b.clf");
  ASSERT_TRUE(bare.ok()) << bare.Message();
  const offline::CarmenMount none = offline::DeriveCarmenMount(bare.value());
  EXPECT_EQ(none.pose.x, 0.0);
  EXPECT_NE(none.source.find("does not say"), std::string::npos) << none.source;

  // Loading the log tells the user where the laser was put.
  const testing::TempDir dir("carmen_mount");
  const std::string path_file = dir.File("raw.clf");
  {
    std::ofstream out(path_file);
    for (size_t i = 0; i < path.size(); ++i) {
      out << FlaserLine(10.0 + 10.0 * static_cast<double>(i), path[i], mount);
    }
  }
  const Result<offline::Experiment> load = offline::LoadExperiment(path_file);
  ASSERT_TRUE(load.ok()) << load.Message();
  ASSERT_EQ(load.value().notes.size(), 1u);
  EXPECT_NE(load.value().notes[0].find("0.150 m ahead, -0.040 m left, turned 5.0 deg"),
            std::string::npos)
      << load.value().notes[0];
  EXPECT_NEAR(load.value().robot.scanner.offset_x_m, 0.15, 1e-9);
}

TEST(LaserTest, ABareFlaserLogsBeamsFollowItsParamsOrCarmensGuessFromTheCount) {
  // A log of one FLASER record of n beams, after `head`; the derived robot's beams.
  const auto beams_of = [](const std::string& head, int n) {
    std::string text = head + "FLASER " + std::to_string(n);
    for (int i = 0; i < n; ++i) text += " 2.5";
    text += " 1.5 h 1.5\n";
    const Result<offline::CarmenLog> log = offline::ParseCarmenLog(text, "t.clf");
    EXPECT_TRUE(log.ok()) << log.Message();
    const RobotDescription robot =
        offline::DeriveCarmenRobot(log.ok() ? log.value() : offline::CarmenLog{}, "t");
    return robot.sensor_types.at(robot.scanner.sensors.at(0).type).beams;
  };
  const auto expect_beams = [](const BeamPattern& b, double first, double increment, int count) {
    EXPECT_NEAR(b.first_deg, first, 1e-9);
    EXPECT_NEAR(b.increment_deg, increment, 1e-9);
    EXPECT_EQ(b.count, count);
  };
  // Without PARAM lines: 180 degrees, edge to edge...
  expect_beams(beams_of("", 181), -90.0, 1.0, 181);
  expect_beams(beams_of("", 361), -90.0, 0.5, 361);
  // ...except a SICK LMS in its 100-degree mode, 0.25 degree apart (not 0.45).
  expect_beams(beams_of("", 401), -50.0, 0.25, 401);
  expect_beams(beams_of("", 400), -50.0, 0.25, 400);
  // The log's parameters say it first: its field of view, and its resolution.
  expect_beams(beams_of("PARAM laser_front_laser_fov 100 h 0\n", 401), -50.0, 0.25, 401);
  expect_beams(beams_of("PARAM laser_front_laser_fov 90 h 0\n", 181), -45.0, 0.5, 181);
  expect_beams(beams_of("PARAM laser_front_laser_fov 180 h 0\n"
                        "PARAM laser_front_laser_resolution 0.5 h 0\n",
                        360),
               -90.0, 0.5, 360);
  expect_beams(beams_of("PARAM laser_front_laser_resolution 0.5 h 0\n", 361), -90.0, 0.5, 361);
  expect_beams(beams_of("PARAM laser_front_laser_resolution 0.25 h 0\n", 401), -50.0, 0.25, 401);

  // A resolution that cannot be: the log is refused, and the error says why.
  const testing::TempDir dir("flaser_beams");
  const std::string path = dir.File("wide.clf");
  {
    std::ofstream out(path);
    out << "PARAM laser_front_laser_resolution 5 h 0\nFLASER 181";
    for (int i = 0; i < 181; ++i) out << " 2.5";
    out << " 1.5 h 1.5\n";
  }
  const Result<offline::Experiment> load = offline::LoadExperiment(path);
  ASSERT_FALSE(load.ok());
  EXPECT_NE(load.Message().find("spans more than a turn"), std::string::npos) << load.Message();
}

TEST(LaserTest, ALasersMountComesBackFromItsLogAndMapsFarBetterThanTheCentre) {
  // A Pioneer whose laser sits 20 cm ahead, 5 cm right, turned 10 degrees: its log, read bare,
  // gives the mount back; ignoring it maps the run far worse.
  const testing::TempDir dir("mounted_laser");
  auto loaded = io::LoadRobot(std::string(SLAM_SOURCE_DIR) + "/config/pioneer-lms.robot.json");
  ASSERT_TRUE(loaded.ok()) << loaded.Message();
  RobotDescription robot = loaded.value();
  robot.scanner.offset_x_m = 0.2;
  robot.scanner.offset_y_m = -0.05;
  robot.scanner.sensors.at(0).angle_deg = 10.0;
  sim::ScenarioConfig config = sim::WithOdometryProfile({}, sim::OdometryProfile::kTracked);
  config.duration_s = 60.0;
  config.scans_per_s = 1.0;
  config.seed = 5;
  const std::string out = dir.File("rooms");
  const Result<void> written =
      sim::WriteSimulatedExperiment(out, *sim::BuiltinWorld("rooms"), "rooms", robot, config);
  ASSERT_TRUE(written.ok()) << written.Message();

  const Result<offline::Experiment> bare = offline::LoadExperiment(out + "/log.clf");
  ASSERT_TRUE(bare.ok()) << bare.Message();
  const ScannerDescription& derived = bare.value().robot.scanner;
  EXPECT_NEAR(derived.offset_x_m, 0.2, 1e-3);
  EXPECT_NEAR(derived.offset_y_m, -0.05, 1e-3);
  EXPECT_NEAR(derived.sensors.at(0).angle_deg, 10.0, 0.1);

  const Result<offline::Experiment> full = offline::LoadExperiment(out);  // with ground truth
  ASSERT_TRUE(full.ok()) << full.Message();
  const offline::Experiment& e = full.value();
  offline::ReplayOptions options;
  options.budget.rays_per_scan = 32500;
  options.config.seed = 1;
  const offline::ReplayResult mounted =
      offline::Replay(bare.value().robot, e.scans, e.ground_truth, options);
  RobotDescription centred = bare.value().robot;
  centred.scanner.offset_x_m = 0.0;
  centred.scanner.offset_y_m = 0.0;
  centred.scanner.sensors.at(0).angle_deg = 0.0;
  const offline::ReplayResult at_centre =
      offline::Replay(centred, e.scans, e.ground_truth, options);
  ASSERT_TRUE(mounted.quality && at_centre.quality);
  EXPECT_LT(mounted.quality->ate_rmse_m, 0.05);
  // The replay's outputs carry the robot it used: robot.json reads back with the mount.
  const std::string replayed = dir.File("replayed");
  fs::create_directories(replayed);
  const offline::ReplayOutputs outputs =
      offline::WriteReplayOutputs(replayed, bare.value(), mounted, false, options.budget);
  EXPECT_TRUE(outputs.errors.empty());
  const auto read_back = io::LoadRobot(replayed + "/robot.json");
  ASSERT_TRUE(read_back.ok()) << read_back.Message();
  EXPECT_DOUBLE_EQ(read_back.value().scanner.offset_x_m, derived.offset_x_m);
  EXPECT_DOUBLE_EQ(read_back.value().scanner.offset_y_m, derived.offset_y_m);
  EXPECT_DOUBLE_EQ(read_back.value().scanner.sensors.at(0).angle_deg,
                   derived.sensors.at(0).angle_deg);
  EXPECT_GT(at_centre.quality->ate_rmse_m, 3.0 * mounted.quality->ate_rmse_m);
}

TEST(LaserTest, ARealLogFromAnotherLabIsReadWithItsLaserAheadAndMapped) {
  // data/malaga-hall: a laser 0.78 m ahead of the robot's odometry, ROBOTLASER1 records.
  const std::string path = std::string(SLAM_SOURCE_DIR) + "/data/malaga-hall/malaga-hall.clf";
  const Result<offline::Experiment> load = offline::LoadExperiment(path);
  ASSERT_TRUE(load.ok()) << load.Message();
  const offline::Experiment& e = load.value();
  EXPECT_EQ(e.counters.bad_lines, 0u);
  EXPECT_EQ(e.scans.size(), 225u);
  EXPECT_NEAR(e.robot.scanner.offset_x_m, 0.78, 1e-9);
  EXPECT_NEAR(e.robot.scanner.offset_y_m, 0.0, 1e-9);
  ASSERT_EQ(e.notes.size(), 1u);
  EXPECT_NE(e.notes[0].find("ROBOTLASER1 records"), std::string::npos) << e.notes[0];
  const SensorTypeDescription& laser = e.robot.sensor_types.at(e.robot.scanner.sensors[0].type);
  EXPECT_EQ(laser.beams.count, 361);
  EXPECT_NEAR(laser.beams.first_deg, -90.0, 1e-5);
  EXPECT_NEAR(laser.beams.increment_deg, 0.5, 1e-5);
  EXPECT_FLOAT_EQ(static_cast<float>(laser.no_return_m), 80.0f);  // the SICK's no return

  // Mapped within the quota. The robot drives down the same aisle twice (the trajectory's
  // poses 20-90 and 188-212, as the map shows): the SLAM's second pass lies on its first (0.5 m
  // at most when this was written), dead reckoning's drifts metres off it (4.2 m).
  offline::ReplayOptions options;
  options.budget.rays_per_scan = 65000;
  options.config.seed = 1;
  const auto [slam, odometry] = ReplayBoth(e, options);
  EXPECT_LE(slam.rays_per_scan_max, 65000);
  const auto off_first_pass = [](const std::vector<TimedPose>& run) {
    double worst = 0.0;
    for (size_t i = 188; i <= 212 && i < run.size(); ++i) {
      double nearest = std::numeric_limits<double>::infinity();
      for (size_t k = 20; k < 90 && k < run.size(); ++k) {
        nearest = std::min(
            nearest, std::hypot(run[i].pose.x - run[k].pose.x, run[i].pose.y - run[k].pose.y));
      }
      worst = std::max(worst, nearest);
    }
    return worst;
  };
  ASSERT_EQ(slam.trajectory.size(), 226u);  // the start, then one pose per scan
  EXPECT_LT(off_first_pass(slam.trajectory), 1.0);
  EXPECT_GT(off_first_pass(odometry.trajectory), 2.0);
}

/// A simulated run of `seconds` in a built-in world by the robot of `robot_file` (config/), with
/// a tracked robot's odometry errors, as scripts/tune-laser records them; written under `dir`.
offline::Experiment SimulatedRun(const testing::TempDir& dir, const std::string& world,
                                 const std::string& robot_file, double seconds, uint64_t seed) {
  sim::ScenarioConfig config = sim::WithOdometryProfile({}, sim::OdometryProfile::kTracked);
  config.duration_s = seconds;
  config.scans_per_s = 1.0;
  config.speed_m_s = 0.4;
  config.turn_rate_rad_s = 0.5;
  config.seed = seed;
  const auto robot = io::LoadRobot(std::string(SLAM_SOURCE_DIR) + "/config/" + robot_file);
  EXPECT_TRUE(robot.ok()) << robot.Message();
  const std::optional<sim::World> w = sim::BuiltinWorld(world);
  EXPECT_TRUE(w);
  const std::string out = dir.File(world);
  const Result<void> written = sim::WriteSimulatedExperiment(out, *w, world, robot.value(), config);
  EXPECT_TRUE(written.ok()) << written.Message();
  Result<offline::Experiment> load = offline::LoadExperiment(out);
  EXPECT_TRUE(load.ok()) << load.Message();
  return load.ok() ? std::move(load).value() : offline::Experiment{};
}

TEST(LaserTest, InTheBuildingTheShippedLaserSetMapsFarBetterThanOdometry) {
  // The world the laser family is tuned in for its loops (scripts/tune-laser): 20 x 14 m, a
  // corridor ring around four rooms. A Pioneer-like robot without a gyro, as there.
  const testing::TempDir dir("building_experiment");
  const offline::Experiment e = SimulatedRun(dir, "building", "pioneer-lms.robot.json", 180, 3);
  ASSERT_FALSE(e.scans.empty());

  offline::ReplayOptions options;
  options.params = ParamsChoice{};  // the shipped set of the robot's family, as the tools pick
  options.budget.rays_per_scan = 65000;
  options.config.seed = 1;
  const auto [slam, odometry] = ReplayBoth(e, options);
  ASSERT_TRUE(slam.quality && odometry.quality);
  EXPECT_EQ(slam.params_set.name, "shipped-laser-65000");
  EXPECT_LE(slam.rays_per_scan_max, 65000);
  EXPECT_GT(odometry.quality->ate_rmse_m, 0.3);  // the heading from the wheels drifts
  EXPECT_LT(slam.quality->ate_rmse_m, odometry.quality->ate_rmse_m / 3.0);
  EXPECT_LT(slam.quality->ate_rmse_m, 0.15);
}

/// Whether two trajectories are the same, bit for bit.
bool Same(const std::vector<TimedPose>& a, const std::vector<TimedPose>& b) {
  return std::equal(a.begin(), a.end(), b.begin(), b.end(), [](const auto& p, const auto& q) {
    return p.t == q.t && p.pose.x == q.pose.x && p.pose.y == q.pose.y &&
           p.pose.theta == q.pose.theta;
  });
}

TEST(LaserTest, TheHeadingSweepRunsOnLargeTurnsOfARangeScannerOnly) {
  const testing::TempDir dir("sweep_experiments");
  offline::ReplayOptions options;
  options.params = ParamsChoice{};
  options.budget.rays_per_scan = 65000;
  options.config.seed = 1;
  const auto poses = [&](const offline::Experiment& e, double turn_deg) {
    options.config.heading_sweep_turn_deg = turn_deg;
    const offline::ReplayResult r = offline::Replay(e.robot, e.scans, e.ground_truth, options);
    EXPECT_LE(r.rays_per_scan_max, 65000);  // the sweep's headings are candidates of the quota
    return r;
  };
  // The Pioneer turns by up to some 30 degrees a scan here: turns above 20 are swept, none
  // above 360.
  const offline::Experiment laser = SimulatedRun(dir, "building", "pioneer-lms.robot.json", 120, 3);
  ASSERT_FALSE(laser.scans.empty());
  const offline::ReplayResult off = poses(laser, 0.0);
  EXPECT_TRUE(Same(poses(laser, 360.0).trajectory, off.trajectory));
  const offline::ReplayResult swept = poses(laser, 20.0);
  EXPECT_FALSE(Same(swept.trajectory, off.trajectory));
  ASSERT_TRUE(swept.quality && off.quality);
  EXPECT_LT(swept.quality->ate_rmse_m, 0.15);
  // The marXbot's infrared scanner is never swept (its gyro keeps the heading).
  const offline::Experiment infrared = SimulatedRun(dir, "rooms", "marxbot.robot.json", 40, 3);
  ASSERT_FALSE(infrared.scans.empty());
  EXPECT_TRUE(Same(poses(infrared, 20.0).trajectory, poses(infrared, 0.0).trajectory));
}

}  // namespace
}  // namespace slam
