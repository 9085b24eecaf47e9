#include "engine/slam.hpp"

#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <cmath>

#include "engine/cell_encoding.hpp"
#include "engine/grid_traversal.hpp"
#include "engine/io/robot_json.hpp"
#include "engine/quality.hpp"
#include "engine/random.hpp"
#include "engine/sensor_model.hpp"
#include "scheduler/fixed_plan.hpp"
#include "sim/scenario.hpp"
#include "sim/world.hpp"
#include "test_support.hpp"

namespace slam {
namespace {

// A 1.0 m x 0.8 m room, off-centre around the robot, with a 15 cm box near it.
sim::World TestRoom() {
  sim::World w;
  w.name = "test-room";
  w.bounds = {-0.4, -0.35, 0.6, 0.45};
  // Off the cell boundaries, so that no wall lies exactly on a grid line.
  const Vec2 offset(0.0043, 0.0027);
  auto wall = [&](double x1, double y1, double x2, double y2) {
    w.segments.push_back({Vec2(x1, y1) + offset, Vec2(x2, y2) + offset});
  };
  wall(-0.4, -0.35, 0.6, -0.35);
  wall(0.6, -0.35, 0.6, 0.45);
  wall(0.6, 0.45, -0.4, 0.45);
  wall(-0.4, 0.45, -0.4, -0.35);
  wall(0.2, 0.1, 0.35, 0.1);
  wall(0.35, 0.1, 0.35, 0.25);
  wall(0.35, 0.25, 0.2, 0.25);
  wall(0.2, 0.25, 0.2, 0.1);
  return w;
}

// A 2 m x 1.6 m arena with two boxes and a pillar, for the end-to-end runs.
sim::World TestArena() {
  sim::World w;
  w.name = "test-arena";
  w.bounds = {-0.9987, -0.7963, 1.0013, 0.8037};
  auto box = [&](double x0, double y0, double x1, double y1) {
    w.segments.push_back({{x0, y0}, {x1, y0}});
    w.segments.push_back({{x1, y0}, {x1, y1}});
    w.segments.push_back({{x1, y1}, {x0, y1}});
    w.segments.push_back({{x0, y1}, {x0, y0}});
  };
  box(w.bounds[0], w.bounds[1], w.bounds[2], w.bounds[3]);
  box(0.3013, 0.2037, 0.5013, 0.3537);
  box(-0.6987, -0.4963, -0.5487, -0.2963);
  w.circles.push_back({{-0.3, 0.45}, 0.08});
  return w;
}

// One half turn of noise-free readings taken from `truth_begin` to `truth_end` (moving linearly
// over it) while the odometry reports a motion from odom_begin to odom_end.
Scan ScanAlong(const RobotDescription& robot, const sim::World& world, const Pose2& truth_begin,
               const Pose2& truth_end, int index, const Pose2& odom_begin, const Pose2& odom_end) {
  Scan scan;
  scan.index = index;
  scan.t_begin = index * (2.0 / 3.0);
  scan.t_end = scan.t_begin + 2.0 / 3.0;
  scan.odom_begin = odom_begin;
  scan.odom_end = odom_end;
  const int samples = 40;
  for (int i = 1; i <= samples; ++i) {
    ScanSample s;
    const double f = double(i) / samples;
    s.t = scan.t_begin + f * (scan.t_end - scan.t_begin);
    s.odom = Interpolate(odom_begin, odom_end, f);
    s.platform_angle_rad = NormalizeAngle((index + f) * kPi);
    const Pose2 truth = Interpolate(truth_begin, truth_end, f);
    for (int k = 0; k < kScannerSensors; ++k) {
      const auto& sensor = robot.scanner.sensors[size_t(k)];
      const auto& table = robot.sensor_types.at(sensor.type).calibration;
      const double local = s.platform_angle_rad + DegToRad(sensor.angle_deg);
      const Vec2 origin = truth.Transform({robot.scanner.mount_radius_m * std::cos(local),
                                           robot.scanner.mount_radius_m * std::sin(local)});
      const auto d = sim::RayDistance(world, origin, truth.theta + local, 3.0);
      const bool calibrated = d && *d >= table.front().distance_m && *d <= table.back().distance_m;
      s.raw[size_t(k)] = static_cast<uint16_t>(calibrated ? CalibratedRaw(table, *d) : 0);
    }
    scan.samples.push_back(s);
  }
  return scan;
}

// A scan whose readings are all taken at `truth`.
Scan ScanAt(const RobotDescription& robot, const sim::World& world, const Pose2& truth, int index,
            const Pose2& odom_begin, const Pose2& odom_end) {
  return ScanAlong(robot, world, truth, truth, index, odom_begin, odom_end);
}

// The engine settings of the matching tests: filter seed and phase B's estimator.
SlamConfig EstimatorConfig(uint64_t seed, bool fit_peak) {
  SlamConfig config;
  config.seed = seed;
  config.fit_peak = fit_peak;
  return config;
}

SlamParams NoMotionNoise() {
  SlamParams p;
  p.dist_error_ratio = p.dist_error_const_m = p.angle_error_ratio = p.angle_error_const_deg = 0;
  return p;
}

// The room drawn into a grid by hand: every cell a wall crosses is occupied.
OccupancyGrid DrawMap(const sim::World& world, double resolution) {
  OccupancyGrid grid(GridGeometry(resolution), kLogOddsLimit);
  for (const sim::Segment& s : world.segments) {
    for (const CellIndex& c : CellsOnRay(grid.geometry(), s.a, s.b)) grid.Add(c, 3000);
  }
  return grid;
}

TEST(Matching, RefinementRecoversAWrongPoseWithinOneCellAndHalfADegree) {
  const RobotDescription robot = testing::ShippedRobot();
  const sim::World room = TestRoom();
  SlamParams params = NoMotionNoise();
  // A search spread of 10 cm and 9 degrees: the motion prior's deviations are a third of it
  // (3.3 cm, 3 degrees).
  params.min_pos_uncertainty_m = 0.10;
  params.min_angle_uncertainty_deg = 9.0;
  const Pose2 truth{0.02, -0.03, DegToRad(10.0)};
  // The robot stands still. The filter believes it is off by `error` at the scan's end, within
  // one prior deviation: Slam::kStartShare of it already at the start (the previous match was
  // off), the rest drifting in over the scan (the odometry claims a motion that did not
  // happen), as phase B models a correction.
  const Pose2 error{0.025, -0.02, DegToRad(2.0)};
  const auto off = [&](double share) {
    return Pose2{truth.x + share * error.x, truth.y + share * error.y,
                 truth.theta + share * error.theta};
  };
  const Pose2 start = off(Slam::kStartShare), wrong = off(1.0);
  ScanPlan plan;
  plan.candidates = 3000;
  const auto pos_error = [&](const Pose2& p) { return std::hypot(p.x - truth.x, p.y - truth.y); };
  const auto angle_error = [&](const Pose2& p) {
    return std::abs(RadToDeg(NormalizeAngle(p.theta - truth.theta)));
  };
  // Scans of the robot standing still, the odometry agreeing: what phase B left of the error.
  const auto stand_still = [&](Slam& slam, int scans) {
    for (int i = 1; i <= scans; ++i) slam.ProcessScan(ScanAt(robot, room, truth, i, {}, {}), plan);
    return slam.Best().pose;
  };
  for (const bool fit_peak : {false, true}) {
    SCOPED_TRACE(fit_peak ? "fitted peak" : "best candidate");
    for (const uint64_t seed : {1u, 2u, 3u}) {
      const SlamConfig config = EstimatorConfig(seed, fit_peak);
      Slam slam(robot, params, config);
      slam.Restore(DrawMap(room, config.resolution_m), start);
      const ScanReport report = slam.ProcessScan(ScanAt(robot, room, truth, 0, start, wrong), plan);
      EXPECT_GT(report.matching_measurements, 60);
      EXPECT_EQ(report.rays.matching, int64_t{3000} * report.matching_measurements);
      const Pose2 found = slam.Best().pose;
      EXPECT_LT(pos_error(found), 0.01)
          << found.x << ", " << found.y << ", " << RadToDeg(found.theta);
      EXPECT_LT(angle_error(found), 0.5);
      // The scan's first pose moved with it.
      const std::vector<TimedPose> path = slam.Trajectory();
      ASSERT_GE(path.size(), 41u);  // the restored pose, then the scan's 40 samples
      const Pose2& first = path[path.size() - 40].pose;
      EXPECT_LT(pos_error(first), 0.01);
      // Scans that agree with the map keep it there.
      const Pose2 settled = stand_still(slam, 2);
      EXPECT_LT(pos_error(settled), 0.01);
      EXPECT_LT(angle_error(settled), 0.5) << RadToDeg(settled.theta);
    }
    // All of the error drifting in over one scan from a start that is right (a treel slipping):
    // phase B takes out some of it on every seed and most of it on average (of 3.2 cm and 2
    // degrees, 1.4 to 2.0 cm and 0.6 to 1.1 degrees are left on seeds 1-8), not all, since it
    // moves the start too.
    double pos_left = 0.0, angle_left = 0.0;
    constexpr int kSeeds = 8;
    for (uint64_t seed = 1; seed <= kSeeds; ++seed) {
      SCOPED_TRACE(seed);
      Slam slam(robot, params, EstimatorConfig(seed, fit_peak));
      slam.Restore(DrawMap(room, 0.01), truth);
      slam.ProcessScan(ScanAt(robot, room, truth, 0, truth, wrong), plan);
      const Pose2 found = slam.Best().pose;
      EXPECT_LT(pos_error(found), 0.75 * std::hypot(error.x, error.y))
          << found.x << ", " << found.y << ", " << RadToDeg(found.theta);
      EXPECT_LT(angle_error(found), 0.75 * RadToDeg(error.theta));
      pos_left += pos_error(found) / kSeeds;
      angle_left += angle_error(found) / kSeeds;
      const Pose2 settled = stand_still(slam, 2);
      EXPECT_LT(pos_error(settled), 0.01);
      EXPECT_LT(angle_error(settled), 0.5) << RadToDeg(settled.theta);
    }
    EXPECT_LT(pos_left, 0.6 * std::hypot(error.x, error.y));
    EXPECT_LT(angle_left, 0.5 * RadToDeg(error.theta));
  }
  // Without phase B the wrong odometry is kept.
  Slam blind(robot, params, SlamConfig{});
  blind.Restore(DrawMap(room, 0.01), truth);
  plan.refine = false;
  const ScanReport blind_report =
      blind.ProcessScan(ScanAt(robot, room, truth, 0, truth, wrong), plan);
  EXPECT_EQ(blind_report.rays.matching, 0);
  EXPECT_NEAR(blind.Best().pose.x, wrong.x, 1e-12);
}

RobotDescription LidarRobot() {
  const auto robot = io::LoadRobot(std::string(SLAM_SOURCE_DIR) + "/config/lidar.robot.json");
  if (!robot.ok()) ADD_FAILURE() << robot.Message();
  return robot.ok() ? robot.value() : RobotDescription{};
}

// One noise-free sweep of a range scanner taken at `truth` (every beam a sample at the scan's
// end, half a second long) while the odometry reports a motion from odom_begin to odom_end.
Scan SweepAt(const RobotDescription& robot, const sim::World& world, const Pose2& truth, int index,
             const Pose2& odom_begin, const Pose2& odom_end) {
  const SensorTypeDescription& type = robot.sensor_types.at(robot.scanner.sensors[0].type);
  Scan scan;
  scan.index = index;
  scan.t_begin = 0.5 * index;
  scan.t_end = scan.t_begin + 0.5;
  scan.odom_begin = odom_begin;
  scan.odom_end = odom_end;
  const Vec2 origin = truth.Transform({robot.scanner.offset_x_m, robot.scanner.offset_y_m});
  for (int beam = 0; beam < type.beams.count; ++beam) {
    ScanSample s;
    s.t = scan.t_end;
    s.odom = odom_end;
    s.platform_angle_rad = DegToRad(type.beams.AngleDeg(beam));
    const auto d = sim::RayDistance(world, origin, truth.theta + s.platform_angle_rad, 12.0);
    s.raw[0] = d ? RangeToRaw(*d) : 0;
    scan.samples.push_back(s);
  }
  return scan;
}

// A laser's readings are matched with at least a cell's deviation (SlamConfig::
// range_sigma_min_cells): a pose off by about a cell loses little likelihood, where matched at
// the laser's own centimetre it loses most. The infrared scanner's matching does not change.
TEST(Matching, ALasersReadingsAreMatchedWithAtLeastACellsDeviation) {
  const RobotDescription robot = LidarRobot();
  sim::World room = TestArena();
  const Pose2 truth{0.0213, -0.0117, DegToRad(7.0)};
  const Scan scan = SweepAt(robot, room, truth, 0, truth, truth);
  const Pose2 off{truth.x + 0.03, truth.y - 0.02, truth.theta + DegToRad(1.0)};
  const auto loss = [&](double min_cells) {
    SlamConfig config;
    config.resolution_m = 0.05;
    config.range_sigma_min_cells = min_cells;
    Slam slam(robot, SlamParams{}, config);
    slam.Restore(DrawMap(room, config.resolution_m), truth);
    const double at_truth = slam.ScoreScan(scan, truth), at_off = slam.ScoreScan(scan, off);
    EXPECT_GT(at_truth, at_off);  // the true pose wins either way
    return at_truth - at_off;
  };
  const double sharp = loss(0.0), floored = loss(1.0);
  EXPECT_GT(sharp, 2.0 * floored) << sharp << " vs " << floored;
  EXPECT_GT(floored, 0.0);
  // The marXbot's infrared readings keep their calibrated deviation whatever the floor.
  const RobotDescription marxbot = testing::ShippedRobot();
  const Scan ir = ScanAt(marxbot, room, truth, 0, truth, truth);
  double scores[2];
  for (const int cells : {0, 1}) {
    SlamConfig config;
    config.range_sigma_min_cells = cells;
    Slam slam(marxbot, SlamParams{}, config);
    slam.Restore(DrawMap(room, config.resolution_m), truth);
    scores[cells] = slam.ScoreScan(ir, off);
  }
  EXPECT_EQ(scores[0], scores[1]);
}

TEST(Matching, ALasersHeadingSearchFollowsTheCorrectionsItsMatchesMake) {
  // The robot shuttles 6 cm back and forth in the arena while its odometry errs in heading by a
  // deviation of 1.5 degrees a scan (a good odometry), then 8 (a tracked robot's), then stands
  // still. The matches turn the errors back; the least heading search follows three times
  // their root mean square, within the set's 12 degrees and no less than a quarter of it,
  // standing still leaves it as it was, and a set's thinning by angle lightens as much as the
  // search narrowed.
  const RobotDescription lidar = LidarRobot();
  const sim::World arena = TestArena();
  SlamParams params = NoMotionNoise();
  params.min_angle_uncertainty_deg = 12.0;
  SlamConfig config;
  config.resolution_m = 0.05;
  const std::array<Pose2, 2> spots{Pose2{0.0213, -0.0117, DegToRad(7.0)},
                                   Compose(Pose2{0.0213, -0.0117, DegToRad(7.0)}, {0.06, 0, 0})};
  ScanPlan plan;
  plan.candidates = 300;
  struct Outcome {
    double good = 0.0, tracked = 0.0, parked = 0.0;  // least heading search after each (deg)
    ScanSummary narrowed;  // of a scan after the good stretch, thinned to 4 degrees
    int matched = 0;       // readings that scan matched when a plan asked for more than all
    int64_t rays = 0, planned = 0;  // the rays it cast, and PlannedRays for it
  };
  const auto run = [&](const RobotDescription& robot, auto&& scan_at) {
    Slam slam(robot, params, config);
    slam.Restore(DrawMap(arena, config.resolution_m), spots[0]);
    EXPECT_DOUBLE_EQ(slam.LeastSearchAngle(), DegToRad(12.0));  // before any match
    Rng rng(7);
    int index = 0;
    const auto drive = [&](double error_deg, int scans, bool shuttle) {
      for (int k = 0; k < scans; ++k, ++index) {
        const Pose2 from = spots[static_cast<size_t>(index % 2)];
        const Pose2 to = shuttle ? spots[static_cast<size_t>((index + 1) % 2)] : from;
        const Pose2 believed = slam.Best().pose;
        Pose2 claimed = Compose(believed, Between(from, to));
        claimed.theta = NormalizeAngle(claimed.theta + DegToRad(rng.Normal(error_deg)));
        const ScanReport report = slam.ProcessScan(scan_at(index, to, believed, claimed), plan);
        EXPECT_GT(report.matching_measurements, 30);
        if (!shuttle) --index;  // stays on the same spot
      }
      if (HasRangeScanner(robot)) {  // the laser's matches found the true heading each time
        EXPECT_NEAR(NormalizeAngle(slam.Best().pose.theta - spots[0].theta), 0.0, DegToRad(1.0))
            << error_deg << " degrees a scan";
      }
      return RadToDeg(slam.LeastSearchAngle());
    };
    Outcome out;
    out.good = drive(1.5, 120, true);
    // What a set thinning to one reading in 4 degrees keeps now, and what the narrowed search
    // gives a plan asking for it.
    SlamParams thinning = params;
    thinning.angle_between_scans_deg = 4.0;
    slam.SetParams(thinning);
    const Pose2 here = spots[static_cast<size_t>(index % 2)];
    const Scan still = scan_at(index, here, slam.Best().pose, slam.Best().pose);
    out.narrowed = slam.Summarize(still);
    ScanPlan more = plan;
    more.candidates = 20;
    more.search = SearchMode::kNarrowed;
    more.matching_measurements = out.narrowed.matching_available + 10;
    const ScanReport report = slam.ProcessScan(still, more);
    out.matched = report.matching_measurements;
    out.rays = report.rays.total();
    out.planned = PlannedRays(more, out.narrowed);
    slam.SetParams(params);
    out.tracked = drive(8.0, 60, true);
    out.parked = drive(0.0, 60, false);
    return out;
  };
  const Outcome laser =
      run(lidar, [&](int index, const Pose2& truth, const Pose2& from, const Pose2& to) {
        return SweepAt(lidar, arena, truth, index, from, to);
      });
  EXPECT_GT(laser.good, 3.5);  // about 3 x 1.5, above the quarter of 12
  EXPECT_LT(laser.good, 6.5);
  EXPECT_GT(laser.tracked, 11.0);  // 3 x 8 is more than the set's 12: the set's search again
  EXPECT_LE(laser.tracked, 12.0 + 1e-9);
  EXPECT_DOUBLE_EQ(laser.parked, laser.tracked);  // a minute parked teaches it nothing
  // 360 beams a degree apart: 90 at the set's 4 degrees, and at 4 x good / 12 degrees (1.6,
  // so every second beam) as many more as the search narrowed, all of which the plan gets.
  EXPECT_NEAR(laser.narrowed.matching_measurements, 90, 2);
  EXPECT_NEAR(laser.narrowed.matching_available, 360 / std::ceil(4.0 * laser.good / 12.0), 2);
  EXPECT_EQ(laser.matched, laser.narrowed.matching_available);
  EXPECT_EQ(laser.rays, laser.planned);
  // The marXbot's infrared scanner keeps the set's search and thinning whatever its matches
  // correct.
  const RobotDescription marxbot = testing::ShippedRobot();
  const Outcome infrared =
      run(marxbot, [&](int index, const Pose2& truth, const Pose2& from, const Pose2& to) {
        return ScanAt(marxbot, arena, truth, index, from, to);
      });
  EXPECT_DOUBLE_EQ(infrared.good, 12.0);
  EXPECT_DOUBLE_EQ(infrared.tracked, 12.0);
  EXPECT_EQ(infrared.narrowed.matching_available, infrared.narrowed.matching_measurements);
  EXPECT_EQ(infrared.matched, infrared.narrowed.matching_measurements);
  EXPECT_EQ(infrared.rays, infrared.planned);
}

TEST(Matching, WhereTheReadingsCannotTellPosesApartTheOdometryWins) {
  // One long wall beside the robot fixes its distance to the wall and its heading, not where
  // along the wall it is: the candidates there score alike, and the motion prior keeps the
  // odometry's position instead of the luckiest of 2000 draws over 5 cm. The best candidate
  // drifts 5 to 6 mm along the wall; the fitted peak, whose curvature along the wall is nil,
  // stays within 2 mm.
  const RobotDescription robot = testing::ShippedRobot();
  sim::World wall;
  wall.name = "wall";
  wall.bounds = {-5.0, -1.0, 5.0, 1.0};
  wall.segments.push_back({{-5.0, 0.5043}, {5.0, 0.5043}});
  SlamParams params = NoMotionNoise();
  params.min_pos_uncertainty_m = 0.05;
  params.min_angle_uncertainty_deg = 3.0;
  const Pose2 truth{0.0, 0.0, 0.0};
  ScanPlan plan;
  plan.candidates = 2000;
  for (const bool fit_peak : {false, true}) {
    SCOPED_TRACE(fit_peak ? "fitted peak" : "best candidate");
    for (const uint64_t seed : {1u, 2u, 3u}) {
      const SlamConfig config = EstimatorConfig(seed, fit_peak);
      Slam slam(robot, params, config);
      slam.Restore(DrawMap(wall, config.resolution_m), truth);
      const ScanReport report = slam.ProcessScan(ScanAt(robot, wall, truth, 0, truth, truth), plan);
      EXPECT_GT(report.matching_measurements, 10);
      const Pose2 found = slam.Best().pose;
      EXPECT_LT(std::abs(found.x), fit_peak ? 0.003 : 0.01) << "seed " << seed << ": " << found.x;
      EXPECT_LT(std::abs(found.y), 0.003) << "seed " << seed << ": " << found.y;
    }
  }
}

TEST(Matching, AfterABlindStretchTheSearchWidensWithTheDriftLeftUncorrected) {
  // Twelve scans see nothing while the odometry claims 1 cm of motion each that did not happen
  // (a treel slipping). When the room is seen again the odometry is 13 cm off: the search has
  // widened with the uncorrected drift (about 5 cm from 1.5 cm per scan) and finds the room
  // again within a few centimetres; with the least spread of 2 cm it stayed 17 cm off.
  const RobotDescription robot = testing::ShippedRobot();
  const sim::World room = TestRoom();
  const sim::World nothing;
  SlamParams params = NoMotionNoise();
  params.dist_error_const_m = 0.015;
  params.min_pos_uncertainty_m = 0.02;
  params.min_angle_uncertainty_deg = 2.0;
  const Pose2 truth{0.02, -0.03, DegToRad(10.0)};
  ScanPlan plan;
  plan.candidates = 3000;
  Slam slam(robot, params, SlamConfig{});
  slam.Restore(DrawMap(room, SlamConfig{}.resolution_m), truth);
  Pose2 odometry = truth;
  int index = 0;
  for (; index < 12; ++index) {
    const Pose2 next = Compose(odometry, {0.01, 0.0, 0.0});
    const ScanReport blind =
        slam.ProcessScan(ScanAt(robot, nothing, truth, index, odometry, next), plan);
    EXPECT_EQ(blind.matching_measurements, 0);
    odometry = next;
  }
  const Pose2 next = Compose(odometry, {0.01, 0.0, 0.0});
  const ScanReport seen = slam.ProcessScan(ScanAt(robot, room, truth, index, odometry, next), plan);
  EXPECT_GT(seen.matching_measurements, 60);
  const Pose2 found = slam.Best().pose;
  EXPECT_LT(std::hypot(found.x - truth.x, found.y - truth.y), 0.04)
      << found.x << ", " << found.y << " (odometry " << next.x << ", " << next.y << ")";
}

TEST(Matching, TheGyrosBiasIsLearntFromTheMatchesAndTakenOutInABlindStretch) {
  // The robot stands still in the room while its gyro reads 1 deg/s: every scan the odometry
  // turns 0.67 degree that did not happen. The matches turn it back; after 60 s the particle's
  // drift estimate has most of the bias, so that over 8 s of seeing nothing the heading drifts
  // far less than the 8 degrees the odometry alone turns.
  const RobotDescription robot = testing::ShippedRobot();
  const sim::World room = TestRoom();
  const sim::World nothing;
  SlamParams params = NoMotionNoise();
  params.min_angle_uncertainty_deg = 2.0;
  const Pose2 truth{0.02, -0.03, DegToRad(10.0)};
  const double bias = DegToRad(1.0);
  ScanPlan plan;
  plan.candidates = 200;
  Slam slam(robot, params, SlamConfig{});
  slam.Restore(DrawMap(room, SlamConfig{}.resolution_m), truth);
  Pose2 odometry = truth;
  int index = 0;
  const auto step = [&](const sim::World& world) {
    Scan probe = ScanAt(robot, world, truth, index, odometry, odometry);
    const Pose2 next = Compose(odometry, {0.0, 0.0, bias * (probe.t_end - probe.t_begin)});
    const ScanReport report =
        slam.ProcessScan(ScanAt(robot, world, truth, index, odometry, next), plan);
    odometry = next;
    ++index;
    return report;
  };
  for (int k = 0; k < 90; ++k) EXPECT_GT(step(room).matching_measurements, 30);
  const double learnt = slam.Best().heading_drift;
  EXPECT_NEAR(learnt, bias, 0.25 * bias) << RadToDeg(learnt) << " deg/s";
  const double before = slam.Best().pose.theta;
  EXPECT_NEAR(NormalizeAngle(before - truth.theta), 0.0, DegToRad(1.0));
  for (int k = 0; k < 12; ++k) EXPECT_EQ(step(nothing).matching_measurements, 0);
  const double drifted = NormalizeAngle(slam.Best().pose.theta - before);
  // Odometry alone: 12 x 0.67 = 8 degrees; what is left is the estimate's error over 8 s.
  EXPECT_LT(std::abs(drifted), DegToRad(2.0)) << RadToDeg(drifted) << " degrees";
}

TEST(Matching, WheelsDriftIsLearntPerMetreAndNotTakenOutStandingStill) {
  // A robot that turns by its encoders (base.heading_from_gyro false) drives a circle of 15 cm
  // radius in the room while its wheels err by 8 degrees a metre: every scan (5 cm) the
  // odometry turns 0.4 degree more than the robot. The matches turn it back and the particle
  // learns the drift per metre; standing still afterwards, blind, nothing turns (a drift per
  // second would keep turning by what it learnt while driving); driving on blind, the heading
  // errs far less than the odometry's 8 degrees a metre.
  RobotDescription robot = testing::ShippedRobot();
  robot.base.heading_from_gyro = false;
  const sim::World room = TestRoom();
  const sim::World nothing;
  SlamParams params = NoMotionNoise();
  params.min_angle_uncertainty_deg = 2.0;
  const double radius = 0.15, step_m = 0.05, bias_per_m = DegToRad(8.0);
  const Vec2 centre(-0.1, 0.05);
  const auto on_circle = [&](double arc) {
    const double a = arc / radius;
    return Pose2{centre.x() + radius * std::cos(a), centre.y() + radius * std::sin(a),
                 NormalizeAngle(a + kPi / 2)};
  };
  ScanPlan plan;
  plan.candidates = 200;
  Slam slam(robot, params, SlamConfig{});
  double arc = 0.0;
  Pose2 truth = on_circle(arc);
  slam.Restore(DrawMap(room, SlamConfig{}.resolution_m), truth);
  Pose2 odometry = truth;
  int index = 0;
  const auto drive = [&](const sim::World& world, double distance) {
    arc += distance;
    const Pose2 next_truth = on_circle(arc);
    Pose2 next = Compose(odometry, Between(truth, next_truth));
    next.theta = NormalizeAngle(next.theta + bias_per_m * distance);
    const ScanReport report =
        slam.ProcessScan(ScanAlong(robot, world, truth, next_truth, index, odometry, next), plan);
    truth = next_truth;
    odometry = next;
    ++index;
    return report;
  };
  for (int k = 0; k < 160; ++k) EXPECT_GT(drive(room, step_m).matching_measurements, 30);
  // 8 m driven against the estimate's 10 m average: about 1 - exp(-0.8) = 55 % learnt.
  const double learnt = slam.Best().heading_drift;
  EXPECT_GT(learnt, 0.35 * bias_per_m) << RadToDeg(learnt) << " deg/m";
  EXPECT_LT(learnt, 0.8 * bias_per_m) << RadToDeg(learnt) << " deg/m";
  const double before = slam.Best().pose.theta;
  EXPECT_NEAR(NormalizeAngle(before - truth.theta), 0.0, DegToRad(1.5));
  for (int k = 0; k < 12; ++k) EXPECT_EQ(drive(nothing, 0.0).matching_measurements, 0);
  EXPECT_NEAR(NormalizeAngle(slam.Best().pose.theta - before), 0.0, 1e-9)
      << RadToDeg(NormalizeAngle(slam.Best().pose.theta - before)) << " degrees standing still";
  for (int k = 0; k < 12; ++k) EXPECT_EQ(drive(nothing, step_m).matching_measurements, 0);
  // Odometry alone: 0.6 m x 8 degrees a metre = 4.8 degrees.
  const double drifted = NormalizeAngle(slam.Best().pose.theta - truth.theta);
  EXPECT_LT(std::abs(drifted), DegToRad(3.0)) << RadToDeg(drifted) << " degrees";
}

TEST(Matching, AnInterruptedScanEvaluatesEachParticlesFirstCandidateOnly) {
  // A scan of 1e8 rays takes seconds; slamd's stop and a tuning job's cancel waited for it.
  const RobotDescription robot = testing::ShippedRobot();
  const sim::World room = TestRoom();
  const SlamParams params = NoMotionNoise();
  const Pose2 truth{0.02, -0.03, DegToRad(10.0)};
  const Pose2 wrong = Compose(truth, {0.03, -0.02, DegToRad(3.0)});
  ScanPlan plan;
  plan.candidates = 500;
  const auto run = [&](const std::atomic<bool>* flag) {
    Slam slam(robot, params, SlamConfig{});
    slam.set_interrupt(flag);
    slam.Restore(DrawMap(room, 0.01), truth);
    const ScanReport report = slam.ProcessScan(ScanAt(robot, room, truth, 0, truth, wrong), plan);
    return std::make_pair(report, slam.Best().pose);
  };
  const auto [plain, plain_pose] = run(nullptr);
  std::atomic<bool> flag{false};
  const auto [calm, calm_pose] = run(&flag);  // a flag that stays false changes nothing
  EXPECT_FALSE(calm.interrupted);
  EXPECT_EQ(calm.rays.matching, plain.rays.matching);
  EXPECT_EQ(calm_pose.x, plain_pose.x);
  EXPECT_EQ(calm_pose.theta, plain_pose.theta);
  flag = true;
  const auto [cut, cut_pose] = run(&flag);
  EXPECT_TRUE(cut.interrupted);
  EXPECT_EQ(cut.rays.matching, cut.matching_measurements);  // one candidate, one particle
  EXPECT_GT(cut.rays.update, 0);                            // the map is still updated
  EXPECT_NEAR(cut_pose.x, wrong.x, 1e-12);  // the first candidate is the odometry's prediction
}

TEST(Matching, ThinningByAngleBetweenScansAndCapsBoundTheRays) {
  const RobotDescription robot = testing::ShippedRobot();
  SlamParams params = NoMotionNoise();
  Slam slam(robot, params, SlamConfig{});
  const Scan scan = ScanAt(robot, TestRoom(), {}, 0, {}, {});
  const ScanSummary all = slam.Summarize(scan);
  EXPECT_EQ(all.usable_measurements, all.matching_measurements);
  params.angle_between_scans_deg = 9.0;  // samples are 4.5 degrees apart: keep every other one
  slam.SetParams(params);
  const ScanSummary thinned = slam.Summarize(scan);
  EXPECT_NEAR(thinned.matching_measurements, all.matching_measurements / 2.0,
              all.matching_measurements * 0.15);
  ScanPlan plan;
  plan.candidates = 7;
  plan.matching_measurements = 10;
  plan.update_rays = 25;
  const ScanReport report = slam.ProcessScan(scan, plan);
  EXPECT_EQ(report.matching_measurements, 10);
  EXPECT_EQ(report.rays.matching, 70);
  EXPECT_EQ(report.rays.update, 25);
  EXPECT_EQ(report.rays.total(), PlannedRays(plan, thinned));
}

TEST(Relocate, PutsEveryParticleAtThePoseOnTheBestsMapAndRefusesAPoseOffTheMap) {
  const RobotDescription robot = testing::ShippedRobot();
  const sim::World room = TestRoom();
  SlamParams params;
  params.particles = 3;
  Slam slam(robot, params, SlamConfig{});
  for (int i = 0; i < 3; ++i) slam.ProcessScan(ScanAt(robot, room, {}, i, {}, {}), ScanPlan{3});
  const Particle best = slam.Best();
  const Pose2 there{0.2, -0.1, 1.0};
  EXPECT_FALSE(slam.Relocate({1e9, 0.0, 0.0}));
  EXPECT_FALSE(slam.Relocate({0.0, std::nan(""), 0.0}));
  ASSERT_TRUE(slam.Relocate(there));
  ASSERT_EQ(slam.particles().size(), 3u);
  for (const Particle& p : slam.particles()) {
    EXPECT_EQ(p.pose.x, there.x);
    EXPECT_EQ(p.pose.y, there.y);
    EXPECT_EQ(p.pose.theta, there.theta);
    EXPECT_EQ(p.log_weight, 0.0);
    EXPECT_EQ(p.history, best.history);
    for (const TileRef& t : best.map.Tiles()) EXPECT_TRUE(p.map.SharesTileWith(best.map, t.index));
  }
  // The next scan starts there.
  ScanPlan odometry_only{3};
  odometry_only.refine = false;
  const ScanReport r = slam.ProcessScan(ScanAt(robot, room, {}, 3, {}, {}), odometry_only);
  EXPECT_NEAR(r.pose.x, there.x, 1e-9);
  EXPECT_NEAR(r.pose.theta, there.theta, 1e-9);
}

TEST(Resampling, CopiesShareTilesAndHistoryUntilWritten) {
  const RobotDescription robot = testing::ShippedRobot();
  const sim::World room = TestRoom();
  Slam slam(robot, NoMotionNoise(), SlamConfig{});
  slam.ProcessScan(ScanAt(robot, room, {}, 0, {}, {}), ScanPlan{});
  // The new count applies from this scan on (resampled before it); a scan that writes nothing
  // leaves every tile shared, and the histories share everything before it.
  ScanPlan four;
  four.particles = 4;
  four.update_rays = 0;
  four.refine = false;
  const ScanReport grown = slam.ProcessScan(ScanAt(robot, room, {}, 1, {}, {}), four);
  EXPECT_TRUE(grown.resampled);
  EXPECT_EQ(grown.particles, 4);
  EXPECT_EQ(grown.rays.update, 0);
  ASSERT_EQ(slam.particles().size(), 4u);
  const auto tiles = slam.particles()[0].map.Tiles();
  ASSERT_FALSE(tiles.empty());
  for (const Particle& p : slam.particles()) {
    for (const TileRef& t : tiles)
      EXPECT_TRUE(p.map.SharesTileWith(slam.particles()[0].map, t.index));
    ASSERT_TRUE(p.history && p.history->parent);
    EXPECT_EQ(p.history->parent, slam.particles()[0].history->parent);
  }
  four.update_rays = ScanPlan::kUnlimited;
  four.refine = true;
  const std::vector<TileRef> before = slam.particles()[1].map.Tiles();
  std::vector<uint64_t> versions_before;
  for (const TileRef& t : before) versions_before.push_back(t.tile->version);

  four.candidates = 5;
  four.update_rays = 3;  // touch only a few tiles
  slam.ProcessScan(ScanAt(robot, room, {}, 2, {}, {}), four);
  const auto& particles = slam.particles();
  int shared = 0, separate = 0;
  for (const TileRef& t : tiles) {
    if (particles[0].map.SharesTileWith(particles[1].map, t.index)) {
      ++shared;
    } else {
      ++separate;
    }
  }
  EXPECT_GT(shared, 0);
  EXPECT_GT(separate, 0);
  // The tiles held before the write are intact and their versions did not change.
  for (size_t i = 0; i < before.size(); ++i) EXPECT_EQ(before[i].tile->version, versions_before[i]);
  // Every particle's history still reaches back to the common ancestor.
  for (const Particle& p : particles)
    EXPECT_EQ(p.history->parent->parent, particles[0].history->parent->parent);
  // Versions only grow.
  for (const Particle& p : particles)
    EXPECT_GE(p.map.Version(), *std::max_element(versions_before.begin(), versions_before.end()));
}

// A short simulated run shared by the following tests.
struct SimRun {
  RobotDescription robot;
  std::vector<Scan> scans;
  std::vector<TimedPose> truth;
};

SimRun Simulate(double duration_s, uint64_t seed, double gyro_bias_dps = 0.05) {
  SimRun run;
  run.robot = testing::ShippedRobot();
  sim::ScenarioConfig config;
  config.duration_s = duration_s;
  config.seed = seed;
  config.odometry.gyro_bias_dps = gyro_bias_dps;
  const sim::ScenarioOutput out = sim::RunScenario(TestArena(), run.robot, config);
  run.scans = sim::BuildScans(run.robot, out.odometry, out.scanner);
  run.truth = out.ground_truth;
  return run;
}

// Runs the engine over every scan with the paper's fixed policy at `budget` rays per scan.
std::pair<Slam, RayCounts> RunSlam(const SimRun& run, const SlamParams& params,
                                   const SlamConfig& config, int64_t budget, bool refine) {
  Slam slam(run.robot, params, config);
  RayCounts total;
  for (const Scan& scan : run.scans) {
    ScanPlan plan = FixedPlan(slam.Summarize(scan), budget, params);
    plan.refine = refine;
    const ScanReport r = slam.ProcessScan(scan, plan);
    EXPECT_LE(r.rays.total(), budget);
    total.matching += r.rays.matching;
    total.update += r.rays.update;
  }
  return {std::move(slam), total};
}

TEST(Parallel, SerialAndParallelPathsGiveIdenticalResults) {
  const SimRun run = Simulate(8.0, 3);
  SlamParams params;
  params.particles = 3;
  params.resampling_period_scans = 2;
  SlamConfig serial;
  serial.parallel = false;
  SlamConfig parallel;
  parallel.parallel = true;
  const auto [a, rays_a] = RunSlam(run, params, serial, 16250, true);
  const auto [b, rays_b] = RunSlam(run, params, parallel, 16250, true);
  EXPECT_EQ(rays_a.total(), rays_b.total());
  ASSERT_EQ(a.particles().size(), b.particles().size());
  for (size_t i = 0; i < a.particles().size(); ++i) {
    const Particle& pa = a.particles()[i];
    const Particle& pb = b.particles()[i];
    EXPECT_EQ(pa.pose.x, pb.pose.x);
    EXPECT_EQ(pa.pose.y, pb.pose.y);
    EXPECT_EQ(pa.pose.theta, pb.pose.theta);
    EXPECT_EQ(pa.log_weight, pb.log_weight);
    const auto ta = pa.map.Tiles(), tb = pb.map.Tiles();
    ASSERT_EQ(ta.size(), tb.size());
    for (size_t t = 0; t < ta.size(); ++t) {
      EXPECT_EQ(ta[t].index, tb[t].index);
      EXPECT_EQ(ta[t].tile->version, tb[t].tile->version);
      EXPECT_TRUE(ta[t].tile->cells == tb[t].tile->cells);
    }
  }
  const auto traj_a = a.Trajectory(), traj_b = b.Trajectory();
  ASSERT_EQ(traj_a.size(), traj_b.size());
  for (size_t i = 0; i < traj_a.size(); ++i) EXPECT_EQ(traj_a[i].pose.x, traj_b[i].pose.x);
}

TEST(History, WithoutSamplePosesItKeepsTheSameScanEndsAtOnePoseAScan) {
  // slamd keeps scan ends only (history_samples = false): the filter is the same, bit for bit,
  // and the history holds the start and one pose a scan instead of one a reading.
  const SimRun run = Simulate(8.0, 3);
  SlamParams params;
  params.particles = 3;
  params.resampling_period_scans = 2;
  SlamConfig samples;
  SlamConfig ends;
  ends.history_samples = false;
  const auto [a, rays_a] = RunSlam(run, params, samples, 16250, true);
  const auto [b, rays_b] = RunSlam(run, params, ends, 16250, true);
  EXPECT_EQ(rays_a.total(), rays_b.total());
  const auto full = a.Trajectory(), kept = b.Trajectory();
  ASSERT_EQ(kept.size(), run.scans.size() + 1);  // the start and each scan's end
  EXPECT_GT(full.size(), 4 * kept.size());       // a reading's pose each, several a scan
  size_t j = 0;
  for (const TimedPose& end : kept) {
    while (j < full.size() && full[j].t < end.t) ++j;
    ASSERT_LT(j, full.size()) << "no pose at t = " << end.t;
    EXPECT_EQ(full[j].t, end.t);
    EXPECT_EQ(full[j].pose.x, end.pose.x);
    EXPECT_EQ(full[j].pose.y, end.pose.y);
    EXPECT_EQ(full[j].pose.theta, end.pose.theta);
  }
  EXPECT_EQ(kept.back().t, run.scans.back().t_end);
}

// End to end on a world built here: noisy odometry and gyro along the simulated wander, readings
// through the Sharp curves; SLAM's trajectory error must be well below odometry-only mapping.
TEST(EndToEnd, SlamBeatsOdometryOnlyOnASimulatedRun) {
  // A gyro with a poorly known bias (0.3 deg/s scale) makes the odometry drift visibly.
  const SimRun run = Simulate(150.0, 11, 0.3);
  ASSERT_GT(run.scans.size(), 200u);
  const SlamParams params;
  const auto [slam, rays] = RunSlam(run, params, SlamConfig{}, 16250, true);
  const auto [odometry, odo_rays] = RunSlam(run, params, SlamConfig{}, 16250, false);
  EXPECT_GT(rays.matching, 0);
  EXPECT_EQ(odo_rays.matching, 0);
  const std::vector<TimedPose> trajectory = slam.Trajectory();
  for (size_t i = 1; i < trajectory.size(); ++i)
    ASSERT_GT(trajectory[i].t, trajectory[i - 1].t) << i;
  const auto q_slam = EvaluateTrajectory(trajectory, run.truth);
  const auto q_odo = EvaluateTrajectory(odometry.Trajectory(), run.truth);
  ASSERT_TRUE(q_slam && q_odo);
  RecordProperty("ate_slam_m", std::to_string(q_slam->ate_rmse_m));
  RecordProperty("ate_odometry_m", std::to_string(q_odo->ate_rmse_m));
  std::printf("ATE RMSE: SLAM %.4f m, odometry only %.4f m\n", q_slam->ate_rmse_m,
              q_odo->ate_rmse_m);
  EXPECT_LT(q_slam->ate_rmse_m, 0.5 * q_odo->ate_rmse_m);
  EXPECT_LT(q_slam->ate_rmse_m, 0.05);
}

}  // namespace
}  // namespace slam
