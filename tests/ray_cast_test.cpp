#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <utility>
#include <vector>

#include "engine/random.hpp"
#include "engine/ray_cast.hpp"

namespace slam {
namespace {

using Cells = std::vector<std::pair<int, int>>;

// Cells of a segment given in cell units on a unit grid (resolution 1 m makes drawings exact).
Cells Traverse(double x0, double y0, double x1, double y1) {
  Cells out;
  for (const CellIndex& c : CellsOnRay(GridGeometry(1.0), {x0, y0}, {x1, y1})) out.emplace_back(c.x, c.y);
  return out;
}

TEST(TraverseCells, AlongTheAxes) {
  EXPECT_EQ(Traverse(0.5, 0.5, 3.5, 0.5), (Cells{{0, 0}, {1, 0}, {2, 0}, {3, 0}}));
  EXPECT_EQ(Traverse(0.5, 0.5, -2.5, 0.5), (Cells{{0, 0}, {-1, 0}, {-2, 0}, {-3, 0}}));
  EXPECT_EQ(Traverse(0.5, 0.5, 0.5, 2.5), (Cells{{0, 0}, {0, 1}, {0, 2}}));
  EXPECT_EQ(Traverse(0.5, 0.5, 0.5, -1.5), (Cells{{0, 0}, {0, -1}, {0, -2}}));
}

// One hand-drawn line per octant, from the centre of cell (0, 0) along (+-3.5, +-1.5) or
// (+-1.5, +-3.5), stopping at 95 %: slope 3/7 is at y = 0.71 on x = 1, crosses y = 1 at
// x = 1.67, and is at y = 1.14 on x = 2 and y = 1.57 on x = 3.
TEST(TraverseCells, EveryOctantMatchesTheDrawing) {
  EXPECT_EQ(Traverse(0.5, 0.5, 3.825, 1.925), (Cells{{0, 0}, {1, 0}, {1, 1}, {2, 1}, {3, 1}}));
  EXPECT_EQ(Traverse(0.5, 0.5, 1.925, 3.825), (Cells{{0, 0}, {0, 1}, {1, 1}, {1, 2}, {1, 3}}));
  EXPECT_EQ(Traverse(0.5, 0.5, -0.925, 3.825), (Cells{{0, 0}, {0, 1}, {-1, 1}, {-1, 2}, {-1, 3}}));
  EXPECT_EQ(Traverse(0.5, 0.5, -2.825, 1.925), (Cells{{0, 0}, {-1, 0}, {-1, 1}, {-2, 1}, {-3, 1}}));
  EXPECT_EQ(Traverse(0.5, 0.5, -2.825, -0.925), (Cells{{0, 0}, {-1, 0}, {-1, -1}, {-2, -1}, {-3, -1}}));
  EXPECT_EQ(Traverse(0.5, 0.5, -0.925, -2.825), (Cells{{0, 0}, {0, -1}, {-1, -1}, {-1, -2}, {-1, -3}}));
  EXPECT_EQ(Traverse(0.5, 0.5, 1.925, -2.825), (Cells{{0, 0}, {0, -1}, {1, -1}, {1, -2}, {1, -3}}));
  EXPECT_EQ(Traverse(0.5, 0.5, 3.825, -0.925), (Cells{{0, 0}, {1, 0}, {1, -1}, {2, -1}, {3, -1}}));
}

TEST(TraverseCells, ThroughCellCornersStepsDiagonally) {
  EXPECT_EQ(Traverse(0.5, 0.5, 3.5, 3.5), (Cells{{0, 0}, {1, 1}, {2, 2}, {3, 3}}));
  EXPECT_EQ(Traverse(0.5, 0.5, -2.5, 3.5), (Cells{{0, 0}, {-1, 1}, {-2, 2}, {-3, 3}}));
  EXPECT_EQ(Traverse(0.5, 0.5, -1.5, -1.5), (Cells{{0, 0}, {-1, -1}, {-2, -2}}));
  // Slope 1/2 from a corner-aligned start passes the corner (2, 1) exactly.
  EXPECT_EQ(Traverse(0.0, 0.0, 3.8, 1.9), (Cells{{0, 0}, {1, 0}, {2, 1}, {3, 1}}));
}

TEST(TraverseCells, GridLinesAndZeroLengthStarts) {
  // Along the line y = 1: belongs to row 1 (cells are half-open).
  EXPECT_EQ(Traverse(0.5, 1.0, 2.5, 1.0), (Cells{{0, 1}, {1, 1}, {2, 1}}));
  // Starting on x = 1 and moving left: cell (1, 0) is not crossed.
  EXPECT_EQ(Traverse(1.0, 0.5, -0.5, 0.5), (Cells{{0, 0}, {-1, 0}}));
  // A zero-length ray visits its own cell only.
  EXPECT_EQ(Traverse(2.3, -0.7, 2.3, -0.7), (Cells{{2, -1}}));
  // Ending exactly on a boundary does not enter the next cell.
  EXPECT_EQ(Traverse(0.5, 0.5, 2.0, 0.5), (Cells{{0, 0}, {1, 0}}));
}

TEST(TraverseCells, ReportsEntryAndExitDistances) {
  std::vector<std::pair<double, double>> spans;
  TraverseCells(GridGeometry(0.1), {0.05, 0.05}, {1.0, 0.0}, 0.3, [&](CellIndex, double in, double out) {
    spans.emplace_back(in, out);
    return true;
  });
  ASSERT_EQ(spans.size(), 4u);
  EXPECT_NEAR(spans[0].first, 0.0, 1e-12);
  EXPECT_NEAR(spans[0].second, 0.05, 1e-12);
  EXPECT_NEAR(spans[1].first, 0.05, 1e-12);
  EXPECT_NEAR(spans[3].second, 0.3, 1e-12);
}

// Oracle: dense sampling along random segments finds no cell the traversal missed, and the
// traversal is a connected chain from the start cell to the end cell.
TEST(TraverseCells, AgreesWithDenseSamplingOnRandomRays) {
  Rng rng(42);
  const GridGeometry g(0.01);
  for (int trial = 0; trial < 300; ++trial) {
    const Vec2 a(rng.Uniform() * 2 - 1, rng.Uniform() * 2 - 1);
    const Vec2 b = a + Vec2(rng.Uniform() - 0.5, rng.Uniform() - 0.5) * 3.0;
    const std::vector<CellIndex> cells = CellsOnRay(g, a, b);
    std::set<std::pair<int, int>> visited;
    for (const CellIndex& c : cells) visited.insert({c.x, c.y});
    ASSERT_EQ(visited.size(), cells.size()) << "a cell was visited twice";
    EXPECT_EQ(cells.front(), g.CellOf(a));
    for (size_t i = 1; i < cells.size(); ++i) {
      EXPECT_LE(std::abs(cells[i].x - cells[i - 1].x), 1);
      EXPECT_LE(std::abs(cells[i].y - cells[i - 1].y), 1);
    }
    const int samples = 20000;
    for (int s = 1; s < samples; ++s) {
      const CellIndex c = g.CellOf(a + (b - a) * (double(s) / samples));
      ASSERT_TRUE(visited.count({c.x, c.y})) << "trial " << trial << " missed " << c.x << "," << c.y;
    }
  }
}

TEST(CastToObstacle, StopsAtTheFirstOccupiedCell) {
  OccupancyGrid grid(GridGeometry(0.01), 5000);
  for (int y = -100; y < 100; ++y) grid.Add({30, y}, 1000);  // a wall at x = [0.30, 0.31)
  grid.Add({10, 20}, -500);                                // free cells do not stop a ray
  const RayHit hit = CastToObstacle(grid, {0.005, 0.005}, 0.0, 1.0, 0);
  EXPECT_TRUE(hit.hit);
  EXPECT_NEAR(hit.distance_m, 0.295, 1e-9);
  EXPECT_EQ(hit.cells, 31);
  // At 60 degrees the wall is reached at 0.295 / cos(60) = 0.59 m.
  const RayHit slanted = CastToObstacle(grid, {0.005, 0.005}, DegToRad(60), 1.0, 0);
  EXPECT_TRUE(slanted.hit);
  EXPECT_NEAR(slanted.distance_m, 0.59, 1e-9);
  // Away from the wall: nothing within range.
  const RayHit away = CastToObstacle(grid, {0.005, 0.005}, kPi, 0.5, 0);
  EXPECT_FALSE(away.hit);
  EXPECT_DOUBLE_EQ(away.distance_m, 0.5);
  EXPECT_EQ(away.cells, 51);  // from x = 0.5 cells to x = -49.5: cells 0 to -50
  // Short of the wall: the range limits the ray.
  EXPECT_FALSE(CastToObstacle(grid, {0.005, 0.005}, 0.0, 0.2, 0).hit);
  // Starting inside an obstacle.
  EXPECT_DOUBLE_EQ(CastToObstacle(grid, {0.305, 0.0}, 0.0, 1.0, 0).distance_m, 0.0);
  // A higher threshold sees through weak evidence.
  EXPECT_FALSE(CastToObstacle(grid, {0.005, 0.005}, 0.0, 1.0, 1000).hit);
}

TEST(ApplyUpdateRay, AddsTheProfileByDistance) {
  OccupancyGrid grid(GridGeometry(0.01), 5000);
  UpdateProfile profile;
  profile.step_m = 0.005;
  profile.delta.assign(10, -100);  // free up to 5 cm
  profile.delta.push_back(700);    // occupied from 5 to 5.5 cm
  // From the centre of cell 0: cell k is crossed around k cm, so cells 0-4 are free, cell 5 is
  // occupied and the ray ends inside it.
  const int changed = ApplyUpdateRay(grid, {0.005, 0.005}, 0.0, profile);
  EXPECT_EQ(changed, 6);
  for (int x = 0; x < 5; ++x) EXPECT_EQ(grid.At({x, 0}), -100) << x;
  EXPECT_EQ(grid.At({5, 0}), 700);
  EXPECT_EQ(grid.At({6, 0}), 0);  // nothing beyond
  EXPECT_EQ(grid.At({0, 1}), 0);
  EXPECT_EQ(ApplyUpdateRay(grid, {0.0, 0.0}, 0.0, UpdateProfile{}), 0);
}

}  // namespace
}  // namespace slam
