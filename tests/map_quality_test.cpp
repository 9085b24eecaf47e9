// Tests of map quality against the true world (sim/map_quality.hpp): hand-painted grids on tiny
// worlds whose precision and recall follow from the geometry.

#include "sim/map_quality.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "engine/grid_geometry.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"
#include "engine/quality.hpp"
#include "sim/world.hpp"

namespace slam::sim {
namespace {

constexpr double kResolution = 0.01;
constexpr int kLimit = 5000;

/// The unit square room [0, 1] x [0, 1].
World Box() {
  World world;
  world.name = "box";
  world.bounds = {0.0, 0.0, 1.0, 1.0};
  world.segments.push_back({{0.0, 0.0}, {1.0, 0.0}});
  world.segments.push_back({{1.0, 0.0}, {1.0, 1.0}});
  world.segments.push_back({{1.0, 1.0}, {0.0, 1.0}});
  world.segments.push_back({{0.0, 1.0}, {0.0, 0.0}});
  return world;
}

const Circle kPillar{{0.6, 0.6}, 0.1};

/// The unit box with a round pillar of 10 cm radius.
World BoxWithPillar() {
  World world = Box();
  world.circles.push_back(kPillar);
  return world;
}

/// Centre of cell (i, j) of a 1 cm grid.
Vec2 Centre(int i, int j) { return {(i + 0.5) * kResolution, (j + 0.5) * kResolution}; }

/// Centres of the 396 cells lining the inside of the box walls (columns / rows 0 and 99).
std::vector<Vec2> BoxRing() {
  std::vector<Vec2> cells;
  for (int i = 0; i < 100; ++i) {
    cells.push_back(Centre(i, 0));
    cells.push_back(Centre(i, 99));
  }
  for (int j = 1; j < 99; ++j) {
    cells.push_back(Centre(0, j));
    cells.push_back(Centre(99, j));
  }
  return cells;
}

/// Centres of the cells within 7.5 mm (more than half a cell diagonal) of a circle's boundary:
/// every boundary point lies in one of them.
std::vector<Vec2> CircleRing(const Circle& circle) {
  std::vector<Vec2> cells;
  for (int j = 0; j < 100; ++j) {
    for (int i = 0; i < 100; ++i) {
      const Vec2 c = Centre(i, j);
      if (std::abs((c - circle.center).norm() - circle.radius_m) <= 0.0075) cells.push_back(c);
    }
  }
  return cells;
}

std::vector<Vec2> Concat(std::vector<Vec2> a, const std::vector<Vec2>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

/// World point -> map point for a map whose frame maps onto the world by `map_to_world`.
Vec2 ToMap(const RigidTransform2& map_to_world, const Vec2& w) {
  const double c = std::cos(map_to_world.rotation_rad), s = std::sin(map_to_world.rotation_rad);
  const Vec2 d = w - map_to_world.translation;
  return {c * d.x() + s * d.y(), -s * d.x() + c * d.y()};
}

/// A 1 cm grid with the cells at the given world points set to `delta`, drawn in the frame that
/// `map_to_world` maps onto the world.
OccupancyGrid Paint(const std::vector<Vec2>& world_points, const RigidTransform2& map_to_world = {},
                    int delta = kLimit) {
  OccupancyGrid grid(GridGeometry(kResolution), kLimit);
  for (const Vec2& w : world_points) {
    grid.Add(grid.geometry().CellOf(ToMap(map_to_world, w)), delta);
  }
  return grid;
}

/// Adds delta to the cells at the given world points of a grid drawn in the world frame.
void AddCells(OccupancyGrid& grid, const std::vector<Vec2>& world_points, int delta) {
  for (const Vec2& w : world_points) grid.Add(grid.geometry().CellOf(w), delta);
}

/// Ground truth at the given positions, one second apart.
std::vector<TimedPose> Trajectory(const std::vector<Vec2>& positions) {
  std::vector<TimedPose> poses;
  for (size_t k = 0; k < positions.size(); ++k) {
    poses.push_back({static_cast<double>(k), {positions[k].x(), positions[k].y(), 0.0}});
  }
  return poses;
}

/// Four poses around the pillar, from which every surface of BoxWithPillar() is in sight.
std::vector<TimedPose> AroundThePillar() {
  return Trajectory({{0.2, 0.2}, {0.85, 0.2}, {0.85, 0.85}, {0.2, 0.85}});
}

/// Sees the whole box: range beyond the box diagonal.
MapQualityConfig WideView() {
  MapQualityConfig config;
  config.visible_range_m = 2.0;
  return config;
}

// Samples at 1 cm: 100 per wall of the box, ceil(2 pi 0.1 / 0.01) = 63 round the pillar.
constexpr int64_t kBoxSamples = 400;
constexpr int64_t kPillarSamples = 63;

// ---------------------------------------------------------------------------------------------

TEST(MapQualityTest, ExactWallsScoreOne) {
  const std::vector<Vec2> cells = Concat(BoxRing(), CircleRing(kPillar));
  const MapQuality q =
      EvaluateMap(Paint(cells), {}, BoxWithPillar(), AroundThePillar(), WideView());
  EXPECT_EQ(q.occupied_cells, static_cast<int64_t>(cells.size()));
  EXPECT_EQ(q.true_occupied_cells, q.occupied_cells);
  EXPECT_DOUBLE_EQ(q.precision, 1.0);
  EXPECT_EQ(q.surface_points, kBoxSamples + kPillarSamples);
  EXPECT_EQ(q.surface_points_found, kBoxSamples + kPillarSamples);
  EXPECT_DOUBLE_EQ(q.recall, 1.0);
  EXPECT_DOUBLE_EQ(q.f1, 1.0);
  EXPECT_DOUBLE_EQ(q.tolerance_m, 0.05);
}

TEST(MapQualityTest, MapShiftedTenCentimetresIsWrongWithoutItsTransform) {
  // The ring drawn 10 cm up and right: only the cells of the shifted left wall near y = 1 and of
  // the shifted bottom wall near x = 1 (ten each, centres within 5 cm) cross a true wall.
  const OccupancyGrid map = Paint(BoxRing(), {0.0, {-0.1, -0.1}});
  const MapQuality q = EvaluateMap(map, {}, Box(), Trajectory({{0.5, 0.5}}), WideView());
  EXPECT_EQ(q.occupied_cells, 396);
  EXPECT_EQ(q.true_occupied_cells, 20);
  EXPECT_DOUBLE_EQ(q.precision, 20.0 / 396.0);
  // Samples of the right wall within 5 cm of the cell at (0.995 or 1.005, 0.105): y in
  // [0.065, 0.145], nine of them; the same on the top wall.
  EXPECT_EQ(q.surface_points, kBoxSamples);
  EXPECT_EQ(q.surface_points_found, 18);
  EXPECT_DOUBLE_EQ(q.recall, 18.0 / 400.0);
}

TEST(MapQualityTest, CorrectingTranslationRestoresTheScore) {
  const OccupancyGrid map = Paint(BoxRing(), {0.0, {-0.1, -0.1}});
  const auto trajectory = Trajectory({{0.5, 0.5}});
  const MapQuality right = EvaluateMap(map, {0.0, {-0.1, -0.1}}, Box(), trajectory, WideView());
  EXPECT_EQ(right.true_occupied_cells, 396);
  EXPECT_DOUBLE_EQ(right.precision, 1.0);
  EXPECT_EQ(right.surface_points_found, kBoxSamples);
  EXPECT_DOUBLE_EQ(right.recall, 1.0);
  // The inverse transform moves the ring 20 cm off instead: again only 20 crossing cells.
  const MapQuality wrong = EvaluateMap(map, {0.0, {0.1, 0.1}}, Box(), trajectory, WideView());
  EXPECT_EQ(wrong.true_occupied_cells, 20);
}

TEST(MapQualityTest, CorrectingRotationRestoresTheScore) {
  // The map frame is the world turned by -90 degrees and moved: its cells land on cell centres.
  const RigidTransform2 map_to_world{kPi / 2.0, {0.3, -0.2}};
  const std::vector<Vec2> cells = Concat(BoxRing(), CircleRing(kPillar));
  const OccupancyGrid map = Paint(cells, map_to_world);
  const MapQuality right =
      EvaluateMap(map, map_to_world, BoxWithPillar(), AroundThePillar(), WideView());
  EXPECT_EQ(right.occupied_cells, static_cast<int64_t>(cells.size()));
  EXPECT_DOUBLE_EQ(right.precision, 1.0);
  EXPECT_DOUBLE_EQ(right.recall, 1.0);

  const RigidTransform2 inverse{-kPi / 2.0, ToMap(map_to_world, Vec2::Zero())};
  const MapQuality wrong =
      EvaluateMap(map, inverse, BoxWithPillar(), AroundThePillar(), WideView());
  EXPECT_LT(wrong.precision, 0.2);
  EXPECT_LT(wrong.recall, 0.2);
  const MapQuality none = EvaluateMap(map, {}, BoxWithPillar(), AroundThePillar(), WideView());
  EXPECT_LT(none.precision, 0.2);
}

TEST(MapQualityTest, HalfTheWallsHalveRecall) {
  // Only the left and bottom walls (199 cells). They also cover the five samples of the top and
  // right walls nearest to them: (x - 0.005)^2 + 0.005^2 <= 0.05^2 for x = 0.005 .. 0.045.
  std::vector<Vec2> cells;
  for (int i = 0; i < 100; ++i) cells.push_back(Centre(i, 0));
  for (int j = 1; j < 100; ++j) cells.push_back(Centre(0, j));
  const MapQuality q = EvaluateMap(Paint(cells), {}, Box(), Trajectory({{0.5, 0.5}}), WideView());
  EXPECT_EQ(q.occupied_cells, 199);
  EXPECT_DOUBLE_EQ(q.precision, 1.0);
  EXPECT_EQ(q.surface_points, kBoxSamples);
  EXPECT_EQ(q.surface_points_found, 210);
  EXPECT_DOUBLE_EQ(q.recall, 210.0 / 400.0);
  EXPECT_DOUBLE_EQ(q.f1, 2.0 * 0.525 / 1.525);
}

TEST(MapQualityTest, SpuriousCellsLowerPrecisionByTheirShare) {
  // 396 wall cells and a 4 x 11 block of phantom cells at least 30 cm from every wall.
  std::vector<Vec2> phantom;
  for (int j = 30; j < 41; ++j) {
    for (int i = 30; i < 34; ++i) phantom.push_back(Centre(i, j));
  }
  const MapQuality q = EvaluateMap(Paint(Concat(BoxRing(), phantom)), {}, Box(),
                                   Trajectory({{0.5, 0.5}}), WideView());
  EXPECT_EQ(q.occupied_cells, 440);
  EXPECT_EQ(q.true_occupied_cells, 396);
  EXPECT_DOUBLE_EQ(q.precision, 0.9);
  EXPECT_DOUBLE_EQ(q.recall, 1.0);
}

TEST(MapQualityTest, OnlyCellsAtTheProbabilityThresholdCount) {
  // Log odds 0.5 (p = 0.62) is below the default 0.65, 0.7 (p = 0.67) above; free cells never
  // count.
  OccupancyGrid map = Paint(BoxRing());
  AddCells(map, {Centre(20, 20), Centre(21, 20), Centre(22, 20)}, 500);
  AddCells(map, {Centre(20, 30), Centre(21, 30)}, 700);
  AddCells(map, {Centre(50, 50), Centre(51, 50)}, -kLimit);
  const auto trajectory = Trajectory({{0.5, 0.5}});
  const MapQuality q = EvaluateMap(map, {}, Box(), trajectory, WideView());
  EXPECT_EQ(q.occupied_cells, 398);
  EXPECT_EQ(q.true_occupied_cells, 396);

  MapQualityConfig lower = WideView();
  lower.occupied_probability = 0.6;
  EXPECT_EQ(EvaluateMap(map, {}, Box(), trajectory, lower).occupied_cells, 401);
}

TEST(MapQualityTest, CellDeepInsideAnObstacleIsWrong) {
  // ClearanceAt is 0 anywhere inside a disc; the centre of a 20 cm disc is 19 cm from its edge.
  World world;
  world.circles.push_back({{0.5, 0.5}, 0.2});
  const OccupancyGrid map = Paint({{0.5, 0.5}, {0.67, 0.5}});  // centres 0.505 / 0.675
  const MapQuality q = EvaluateMap(map, {}, world, {}, WideView());
  EXPECT_EQ(q.occupied_cells, 2);
  EXPECT_EQ(q.true_occupied_cells, 1);
  EXPECT_DOUBLE_EQ(q.precision, 0.5);
  EXPECT_EQ(q.surface_points, 0);  // no trajectory, nothing observable
  EXPECT_DOUBLE_EQ(q.recall, 0.0);
  EXPECT_DOUBLE_EQ(q.f1, 0.0);
}

/// A long wall at x = 0.5 hiding a short wall at x = 0.6 (y in [0.3, 0.7]) from the left.
World WallBehindWall() {
  World world;
  world.segments.push_back({{0.5, 0.0}, {0.5, 1.0}});
  world.segments.push_back({{0.6, 0.3}, {0.6, 0.7}});
  return world;
}

/// The cells of the long wall (column 49) only.
OccupancyGrid LongWallMap() {
  std::vector<Vec2> cells;
  for (int j = 0; j < 100; ++j) cells.push_back(Centre(49, j));
  return Paint(cells);
}

TEST(MapQualityTest, SurfaceHiddenBehindAWallIsNotObservable) {
  // From the left every ray to the short wall crosses the long one 10 cm or more before it.
  const auto left = Trajectory({{0.2, 0.5}, {0.2, 0.3}});
  const MapQuality hidden = EvaluateMap(LongWallMap(), {}, WallBehindWall(), left, WideView());
  EXPECT_EQ(hidden.surface_points, 100);
  EXPECT_EQ(hidden.surface_points_found, 100);
  EXPECT_DOUBLE_EQ(hidden.recall, 1.0);

  // Seen from the right too, its 40 samples count and are missing from the map.
  const auto both = Trajectory({{0.2, 0.5}, {0.2, 0.3}, {0.8, 0.5}});
  const MapQuality seen = EvaluateMap(LongWallMap(), {}, WallBehindWall(), both, WideView());
  EXPECT_EQ(seen.surface_points, 140);
  EXPECT_EQ(seen.surface_points_found, 100);
  EXPECT_DOUBLE_EQ(seen.recall, 100.0 / 140.0);
}

TEST(MapQualityTest, SurfaceBeyondVisibleRangeIsNotObservable) {
  // From (0.2, 0.5) within 0.5 m: the long wall's samples with |y - 0.5| <= 0.4, y = 0.105 ..
  // 0.895.
  MapQualityConfig config;
  config.visible_range_m = 0.5;
  const MapQuality q =
      EvaluateMap(LongWallMap(), {}, WallBehindWall(), Trajectory({{0.2, 0.5}}), config);
  EXPECT_EQ(q.surface_points, 80);
  EXPECT_EQ(q.surface_points_found, 80);
}

TEST(MapQualityTest, PosesCloserInTimeThanPoseStepAreSkipped) {
  std::vector<TimedPose> poses{{0.0, {0.2, 0.5, 0.0}}, {0.2, {0.8, 0.5, 0.0}}};
  MapQualityConfig config = WideView();
  EXPECT_EQ(EvaluateMap(LongWallMap(), {}, WallBehindWall(), poses, config).surface_points, 100);
  config.pose_step_s = 0.1;
  EXPECT_EQ(EvaluateMap(LongWallMap(), {}, WallBehindWall(), poses, config).surface_points, 140);
}

TEST(MapQualityTest, EmptyMapScoresZeroWithoutNaN) {
  const OccupancyGrid empty(GridGeometry(kResolution), kLimit);
  const MapQuality q = EvaluateMap(empty, {}, Box(), Trajectory({{0.5, 0.5}}), WideView());
  EXPECT_EQ(q.occupied_cells, 0);
  EXPECT_EQ(q.true_occupied_cells, 0);
  EXPECT_EQ(q.precision, 0.0);
  EXPECT_EQ(q.surface_points, kBoxSamples);
  EXPECT_EQ(q.surface_points_found, 0);
  EXPECT_EQ(q.recall, 0.0);
  EXPECT_EQ(q.f1, 0.0);

  const MapQuality nothing = EvaluateMap(empty, {}, World{}, {}, WideView());
  EXPECT_EQ(nothing.surface_points, 0);
  EXPECT_EQ(nothing.precision, 0.0);
  EXPECT_EQ(nothing.recall, 0.0);
  EXPECT_EQ(nothing.f1, 0.0);

  // Cells in an empty world are all wrong.
  const MapQuality no_world = EvaluateMap(Paint(BoxRing()), {}, World{}, {}, WideView());
  EXPECT_EQ(no_world.occupied_cells, 396);
  EXPECT_EQ(no_world.true_occupied_cells, 0);
  EXPECT_EQ(no_world.f1, 0.0);
}

TEST(MapQualityConfigTest, DefaultsAreValid) { EXPECT_TRUE(MapQualityConfig{}.Validate().empty()); }

TEST(MapQualityConfigTest, RejectsEachInvalidValue) {
  const double nan = std::nan("");
  const double inf = HUGE_VAL;
  struct Case {
    void (*set)(MapQualityConfig&, double);
    double value;
    const char* pointer;
  };
  const Case cases[] = {
      {[](MapQualityConfig& c, double v) { c.tolerance_m = v; }, 0.0, "/tolerance_m"},
      {[](MapQualityConfig& c, double v) { c.tolerance_m = v; }, nan, "/tolerance_m"},
      {[](MapQualityConfig& c, double v) { c.tolerance_m = v; }, 2.0, "/tolerance_m"},
      {[](MapQualityConfig& c, double v) { c.occupied_probability = v; }, 0.5,
       "/occupied_probability"},
      {[](MapQualityConfig& c, double v) { c.occupied_probability = v; }, 1.0,
       "/occupied_probability"},
      {[](MapQualityConfig& c, double v) { c.occupied_probability = v; }, nan,
       "/occupied_probability"},
      {[](MapQualityConfig& c, double v) { c.visible_range_m = v; }, 0.0, "/visible_range_m"},
      {[](MapQualityConfig& c, double v) { c.visible_range_m = v; }, inf, "/visible_range_m"},
      {[](MapQualityConfig& c, double v) { c.surface_step_m = v; }, 0.0, "/surface_step_m"},
      {[](MapQualityConfig& c, double v) { c.surface_step_m = v; }, -0.01, "/surface_step_m"},
      {[](MapQualityConfig& c, double v) { c.pose_step_s = v; }, -1.0, "/pose_step_s"},
      {[](MapQualityConfig& c, double v) { c.pose_step_s = v; }, nan, "/pose_step_s"},
  };
  for (const Case& c : cases) {
    MapQualityConfig config;
    c.set(config, c.value);
    const ConfigErrors errors = config.Validate();
    ASSERT_EQ(errors.size(), 1u) << c.pointer << " = " << c.value;
    EXPECT_EQ(errors[0].pointer, c.pointer) << c.value;
  }
  // A zero pose step (every pose) is fine.
  MapQualityConfig every_pose;
  every_pose.pose_step_s = 0.0;
  EXPECT_TRUE(every_pose.Validate().empty());
}

TEST(MapQualityConfigTest, InvalidConfigGivesAnAllZeroResult) {
  MapQualityConfig config;
  config.surface_step_m = 0.0;
  const MapQuality q = EvaluateMap(Paint(BoxRing()), {}, Box(), Trajectory({{0.5, 0.5}}), config);
  EXPECT_EQ(q.occupied_cells, 0);
  EXPECT_EQ(q.surface_points, 0);
  EXPECT_EQ(q.f1, 0.0);
}

}  // namespace
}  // namespace slam::sim
