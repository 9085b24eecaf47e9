// The engine on coordinates beyond the map's bound (issue 46, item 2): every traversal ends in
// bounded time and visits only cells inside the bound, for any finite input; the SLAM refuses
// poses and odometry that would take it there, and counts what it refused.

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <limits>
#include <vector>

#include "engine/grid_geometry.hpp"
#include "engine/grid_traversal.hpp"
#include "engine/matching_rays.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/slam.hpp"
#include "engine/update_ray.hpp"
#include "test_support.hpp"

namespace slam {
namespace {

constexpr double kMax = std::numeric_limits<double>::max();

bool CellInBound(CellIndex c) {
  return c.x >= -kMapCellBound && c.x < kMapCellBound && c.y >= -kMapCellBound &&
         c.y < kMapCellBound;
}

// The reference: GridWalk over the whole segment, as TraverseCells walked it before it clipped
// to the map's bound, keeping the cells inside the bound. Only for segments whose cells fit in
// int32 and are few enough to walk.
std::vector<CellIndex> WalkedInBound(const GridGeometry& g, const Vec2& from, const Vec2& to) {
  const Vec2 d = to - from;
  const double length = d.norm() / g.resolution();
  GridWalk walk(g.ToGrid(from), d / d.norm());
  std::vector<CellIndex> cells;
  while (true) {
    const double t_next = walk.NextCrossing();
    if (std::min(t_next, length) > walk.t && CellInBound({walk.cx, walk.cy}))
      cells.push_back({walk.cx, walk.cy});
    if (t_next >= length) break;
    walk.Step();
  }
  return cells;
}

TEST(TraversalBound, HugeAndExtremeCoordinatesVisitOnlyCellsInsideTheBoundPromptly) {
  const GridGeometry g(0.01);
  const std::vector<double> values = {1e300, -1e300, 1e9, -1e9, kMax, -kMax, 0.0, 50.0, -81.9};
  const std::vector<Vec2> directions = {{1, 0}, {-1, 0}, {0, 1}, {0.6, -0.8}, {-0.28, 0.96}};
  const std::vector<double> lengths = {0.0, 1.0, 1e9, 1e300, kMax};
  const auto start = std::chrono::steady_clock::now();
  int64_t visited = 0;
  for (double x : values) {
    for (double y : values) {
      for (const Vec2& d : directions) {
        for (double length : lengths) {
          const int n =
              TraverseCells(g, {x, y}, d, length, [&](CellIndex c, double in, double out) {
                EXPECT_TRUE(CellInBound(c)) << c.x << " " << c.y << " from " << x << " " << y;
                EXPECT_TRUE(std::isfinite(in) && std::isfinite(out) && in <= out);
                return true;
              });
          // No more than a segment across the whole map crosses (two cells a step at most).
          EXPECT_LE(n, 4 * kMapCellBound + 2) << x << " " << y << " " << length;
          visited += n;
        }
      }
    }
  }
  EXPECT_GT(visited, 0);  // the segments from inside, and those crossing the bound, visit cells
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(5));
  // Not finite: nothing.
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const auto never = [](CellIndex, double, double) { return true; };
  EXPECT_EQ(TraverseCells(g, {nan, 0.0}, {1, 0}, 1.0, never), 0);
  EXPECT_EQ(TraverseCells(g, {0.0, 0.0}, {nan, nan}, 1.0, never), 0);
  EXPECT_EQ(TraverseCells(g, {0.0, 0.0}, {1, 0}, nan, never), 0);
  EXPECT_EQ(TraverseCells(g, {0.0, 0.0}, {1, 0}, -1.0, never), 0);
  // An infinite length ends at the bound.
  EXPECT_EQ(TraverseCells(g, {0.0, 0.0}, {1, 0}, std::numeric_limits<double>::infinity(), never),
            kMapCellBound);
}

TEST(TraversalBound, SegmentsCrossingTheBoundAreThePlainTraversalInsideIt) {
  // 1 m cells: grid coordinates are metres, the bound is at +-8192.
  const GridGeometry g(1.0);
  struct Segment {
    Vec2 from, to;
  };
  const std::vector<Segment> segments = {
      {{100.3, 7.7}, {9000.1, 3311.9}},          // leaves through x = 8192
      {{-9000.4, 5.3}, {10.6, -20.2}},           // enters through x = -8192
      {{-10000.2, -9000.7}, {10000.9, 9500.1}},  // crosses the whole map, corner to corner
      {{20.5, 9000.25}, {-30.75, -9100.5}},      // in through y = 8192, out through y = -8192
      {{8191.6, 0.4}, {8192.0, 0.4}},            // ends on the bound
      {{9000.5, 0.5}, {9500.5, 700.5}},          // never inside
  };
  for (const Segment& s : segments) {
    const std::vector<CellIndex> expected = WalkedInBound(g, s.from, s.to);
    const std::vector<CellIndex> cells = CellsOnRay(g, s.from, s.to);
    ASSERT_EQ(cells.size(), expected.size()) << s.from.transpose() << " -> " << s.to.transpose();
    for (size_t i = 0; i < cells.size(); ++i) {
      ASSERT_EQ(cells[i], expected[i]) << i << ": " << s.from.transpose();
    }
  }
  // Within the bound the traversal is the walk itself, distances included.
  const Vec2 from(-3.3, 2.1), to(57.9, -40.2);
  const Vec2 d = (to - from).normalized();
  std::vector<double> enters;
  TraverseCells(g, from, d, (to - from).norm(), [&](CellIndex, double in, double) {
    enters.push_back(in);
    return true;
  });
  EXPECT_EQ(enters.size(), WalkedInBound(g, from, to).size());
  EXPECT_EQ(enters.front(), 0.0);
}

TEST(TraversalBound, RaysFromFarAwayHitWhatTheMapHoldsAndNothingElse) {
  const GridGeometry g(1.0);
  OccupancyGrid grid(g, kLogOddsLimit);
  grid.BeginWrite();
  grid.Add({8000, 0}, 3000);
  grid.RefreshSummaries();
  const Vec2 left(-1.0, 0.0);
  // From 1e6 m: within the fast path's reach; from 1e9 m: cell by cell, clipped to the bound.
  for (double x : {1e6, 1e9}) {
    const RayHit fast = CastToObstacle(grid, Vec2(x, 0.5), left, 2 * x, 0);
    const RayHit plain = CastToObstaclePlain(grid, Vec2(x, 0.5), left, 2 * x, 0);
    EXPECT_TRUE(fast.hit && plain.hit) << x;
    EXPECT_DOUBLE_EQ(fast.distance_m, x - 8001.0) << x;
    EXPECT_DOUBLE_EQ(plain.distance_m, x - 8001.0) << x;
  }
  // Beyond reach, or past the map: nothing, at once.
  for (double x : {1e300, -1e300, kMax, 1e9}) {
    EXPECT_FALSE(CastToObstacle(grid, Vec2(x, x), left, 100.0, 0).hit) << x;
    EXPECT_FALSE(CastToObstacle(grid, Vec2(0.5, 0.5), Vec2(0.6, 0.8), x > 0 ? x : 1.0, 0).hit);
  }
  std::vector<RayHit> hits;
  CastToObstacles(grid, {{Vec2(1e12, 0.5), left, 2e12}, {Vec2(1e6, 0.5), left, 2e6}}, 0, hits);
  ASSERT_EQ(hits.size(), 2u);
  EXPECT_TRUE(hits[0].hit && hits[1].hit);
  EXPECT_DOUBLE_EQ(hits[0].distance_m, 1e12 - 8001.0);  // cell by cell from the bound on
  EXPECT_DOUBLE_EQ(hits[1].distance_m, 1e6 - 8001.0);
  EXPECT_LE(hits[0].cells, 8192 - 8000 + 1);
  // An update ray from far away writes nothing, and ends.
  UpdateProfile profile{0.01, 100, 10, -10, 30};
  EXPECT_EQ(ApplyUpdateRay(grid, Vec2(1e300, -1e300), 1.0, profile), 0);
  EXPECT_EQ(ApplyUpdateRay(grid, Vec2(1e9, 0), kPi, profile), 0);
}

TEST(TraversalBound, CellsSaturateInsteadOfOverflowing) {
  const GridGeometry g(0.01);
  EXPECT_EQ(g.CellOf({1e300, -1e300}),
            (CellIndex{GridGeometry::kCellSaturation, -GridGeometry::kCellSaturation}));
  EXPECT_EQ(g.CellOf({std::numeric_limits<double>::quiet_NaN(), 1.234}), (CellIndex{0, 123}));
  EXPECT_TRUE(g.InMapBound({81.91, -81.92}));
  EXPECT_FALSE(g.InMapBound({81.92, 0.0}));
  EXPECT_FALSE(g.InMapBound({1e9, 0.0}));
  EXPECT_FALSE(g.InMapBound({std::numeric_limits<double>::quiet_NaN(), 0.0}));
}

// A scan of the marXbot standing at `odom_end` after `odom_begin`, every sample reading 0.3 m.
Scan StandingScan(const RobotDescription& robot, int index, const Pose2& odom_begin,
                  const Pose2& odom_end) {
  Scan scan;
  scan.index = index;
  scan.t_begin = index * 0.5;
  scan.t_end = scan.t_begin + 0.5;
  scan.odom_begin = odom_begin;
  scan.odom_end = odom_end;
  for (int i = 1; i <= 30; ++i) {
    ScanSample s;
    s.t = scan.t_begin + i * 0.5 / 30;
    s.odom = Interpolate(odom_begin, odom_end, i / 30.0);
    s.platform_angle_rad = NormalizeAngle(index * kPi + i * kPi / 30);
    for (int k = 0; k < kScannerSensors; ++k) {
      const auto& type = robot.sensor_types.at(robot.scanner.sensors[size_t(k)].type);
      s.raw[size_t(k)] = static_cast<uint16_t>(type.calibration[type.calibration.size() / 2].raw);
    }
    scan.samples.push_back(s);
  }
  return scan;
}

TEST(SlamBound, APoseBeyondTheMapIsRefusedAndTheEngineGoesOn) {
  const RobotDescription robot = testing::ShippedRobot();
  Slam slam(robot, SlamParams{}, SlamConfig{});
  const OccupancyGrid empty(GridGeometry(0.01), kLogOddsLimit);
  // A resumed trajectory ending 1e9 m away: refused, nothing changed.
  for (const Pose2& far : {Pose2{1e9, 0, 0}, Pose2{0, -1e300, 0}, Pose2{81.92, 0, 0},
                           Pose2{0, 0, std::numeric_limits<double>::infinity()}}) {
    EXPECT_FALSE(slam.AcceptsPose(far)) << far.x << " " << far.y;
    EXPECT_FALSE(slam.Restore(empty, far)) << far.x << " " << far.y;
  }
  EXPECT_TRUE(slam.Restore(empty, {81.5, -81.0, 0.0}));
  ScanPlan plan;
  plan.particles = 4;
  plan.candidates = 20;
  const auto start = std::chrono::steady_clock::now();
  // Odometry at 1e9 m, standing still: only the motion counts, the scan is mapped.
  const Pose2 far{1e9, -1e9, 0.5};
  const ScanReport still = slam.ProcessScan(StandingScan(robot, 0, far, far), plan);
  EXPECT_EQ(still.refused, ScanRefusal::kNone);
  EXPECT_NEAR(still.pose.x, 81.5, 0.3);
  // A step of 1e300 m (the CARMEN log's Inverse / Compose of such poses), and one of 2e9 m:
  // faster than the robot drives.
  EXPECT_EQ(
      slam.ProcessScan(StandingScan(robot, 1, {1e300, -1e300, 1e300}, {-1e300, 1e300, 0}), plan)
          .refused,
      ScanRefusal::kImplausibleMotion);
  EXPECT_EQ(slam.ProcessScan(StandingScan(robot, 2, far, {-1e9, 1e9, 0}), plan).refused,
            ScanRefusal::kImplausibleMotion);
  // Infinite or NaN odometry.
  const double inf = std::numeric_limits<double>::infinity();
  EXPECT_EQ(slam.ProcessScan(StandingScan(robot, 3, {}, {inf, 0, 0}), plan).refused,
            ScanRefusal::kNotFinite);
  // A plausible step (0.6 m in 0.5 s) that would leave the map: the robot stands at 81.5 m.
  const ScanReport edge = slam.ProcessScan(StandingScan(robot, 4, {0, 0, 0}, {0.6, 0, 0}), plan);
  EXPECT_EQ(edge.refused, ScanRefusal::kOutsideMap);
  EXPECT_EQ(slam.scans_refused(), 4);
  EXPECT_EQ(slam.scans_processed(), 1);
  // The engine goes on from where it stood: inward is fine.
  const ScanReport inward = slam.ProcessScan(StandingScan(robot, 5, {0, 0, 0}, {-0.3, 0, 0}), plan);
  EXPECT_EQ(inward.refused, ScanRefusal::kNone);
  for (const Particle& p : slam.particles()) EXPECT_TRUE(slam.AcceptsPose(p.pose));
  for (const TimedPose& p : slam.Trajectory()) EXPECT_TRUE(slam.AcceptsPose(p.pose));
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(10));
  EXPECT_STREQ(ToString(ScanRefusal::kOutsideMap), "outside_map");
}

}  // namespace
}  // namespace slam
