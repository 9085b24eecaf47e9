#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "engine/grid_traversal.hpp"
#include "engine/match_window.hpp"
#include "engine/matching_rays.hpp"
#include "engine/random.hpp"
#include "engine/update_ray.hpp"

namespace slam {
namespace {

using Cells = std::vector<std::pair<int, int>>;

// Cells of a segment given in cell units on a unit grid (resolution 1 m makes drawings exact).
Cells Traverse(double x0, double y0, double x1, double y1) {
  Cells out;
  for (const CellIndex& c : CellsOnRay(GridGeometry(1.0), {x0, y0}, {x1, y1}))
    out.emplace_back(c.x, c.y);
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
  EXPECT_EQ(Traverse(0.5, 0.5, -2.825, -0.925),
            (Cells{{0, 0}, {-1, 0}, {-1, -1}, {-2, -1}, {-3, -1}}));
  EXPECT_EQ(Traverse(0.5, 0.5, -0.925, -2.825),
            (Cells{{0, 0}, {0, -1}, {-1, -1}, {-1, -2}, {-1, -3}}));
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
  TraverseCells(GridGeometry(0.1), {0.05, 0.05}, {1.0, 0.0}, 0.3,
                [&](CellIndex, double in, double out) {
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
      ASSERT_TRUE(visited.count({c.x, c.y}))
          << "trial " << trial << " missed " << c.x << "," << c.y;
    }
  }
}

TEST(CastToObstacle, StopsAtTheFirstOccupiedCell) {
  OccupancyGrid grid(GridGeometry(0.01), 5000);
  for (int y = -100; y < 100; ++y) grid.Add({30, y}, 1000);  // a wall at x = [0.30, 0.31)
  grid.Add({10, 20}, -500);                                  // free cells do not stop a ray
  const RayHit hit = CastToObstacle(grid, {0.005, 0.005}, 0.0, 1.0, 0);
  EXPECT_TRUE(hit.hit);
  EXPECT_NEAR(hit.distance_m, 0.295, 1e-9);
  EXPECT_EQ(CastToObstaclePlain(grid, {0.005, 0.005}, 0.0, 1.0, 0).cells, 31);
  // At 60 degrees the wall is reached at 0.295 / cos(60) = 0.59 m.
  const RayHit slanted = CastToObstacle(grid, {0.005, 0.005}, DegToRad(60), 1.0, 0);
  EXPECT_TRUE(slanted.hit);
  EXPECT_NEAR(slanted.distance_m, 0.59, 1e-9);
  // Away from the wall: nothing within range.
  const RayHit away = CastToObstacle(grid, {0.005, 0.005}, kPi, 0.5, 0);
  EXPECT_FALSE(away.hit);
  EXPECT_DOUBLE_EQ(away.distance_m, 0.5);
  // from x = 0.5 cells to x = -49.5: cells 0 to -50 (the fast path jumps over the empty ones)
  EXPECT_EQ(CastToObstaclePlain(grid, {0.005, 0.005}, kPi, 0.5, 0).cells, 51);
  EXPECT_LT(away.cells, 51);
  // Short of the wall: the range limits the ray.
  EXPECT_FALSE(CastToObstacle(grid, {0.005, 0.005}, 0.0, 0.2, 0).hit);
  // Starting inside an obstacle.
  EXPECT_DOUBLE_EQ(CastToObstacle(grid, {0.305, 0.0}, 0.0, 1.0, 0).distance_m, 0.0);
  // A higher threshold sees through weak evidence.
  EXPECT_FALSE(CastToObstacle(grid, {0.005, 0.005}, 0.0, 1.0, 1000).hit);
}

// A map for the fast path: walls, scattered obstacles, free space, unknown holes, missing tiles
// and negative coordinates, at resolution `res`.
OccupancyGrid RandomMap(uint64_t seed, double res) {
  Rng rng(seed);
  OccupancyGrid grid(GridGeometry(res), 2000);
  grid.BeginWrite();
  // Free space over most of [-200, 200)^2 cells, with holes left unknown.
  for (int y = -200; y < 200; ++y) {
    for (int x = -200; x < 200; ++x) {
      if (((x * 7 + y * 13) & 31) != 0 && rng.Uniform() < 0.9) grid.Add({x, y}, -300);
    }
  }
  // Wall segments of random length and direction, and isolated occupied cells.
  for (int w = 0; w < 12; ++w) {
    double x = rng.Uniform() * 400 - 200, y = rng.Uniform() * 400 - 200;
    const double a = rng.Uniform() * 2 * kPi;
    const int n = 10 + static_cast<int>(rng.Uniform() * 120);
    for (int i = 0; i < n; ++i, x += std::cos(a), y += std::sin(a)) {
      grid.Add({static_cast<int32_t>(std::floor(x)), static_cast<int32_t>(std::floor(y))}, 900);
    }
  }
  for (int k = 0; k < 200; ++k) {
    grid.Add({static_cast<int32_t>(rng.Uniform() * 500 - 250),
              static_cast<int32_t>(rng.Uniform() * 500 - 250)},
             static_cast<int>(rng.Uniform() * 600));  // some exactly at or just above 0
  }
  // A far tile alone, so that rays cross missing tiles between.
  grid.Add({700, -650}, 1000);
  return grid;
}

// Seeded rays anywhere in [-3, 3)^2 m (also from cell and block boundaries, along the axes and
// diagonals, of zero length), up to 1.5 m, or 10 m for one in three, of 1 cm cells.
std::vector<RayQuery> RandomRays(uint64_t seed, int rays, double res) {
  Rng rng(seed);
  std::vector<RayQuery> queries;
  for (int i = 0; i < rays; ++i) {
    Vec2 origin(rng.Uniform() * 6 - 3, rng.Uniform() * 6 - 3);
    if (i % 5 == 0) origin = Vec2(std::round(origin.x() / res / 8) * 8 * res, origin.y());
    if (i % 7 == 0) origin = Vec2(origin.x(), std::round(origin.y() / res) * res);
    double angle = rng.Uniform() * 2 * kPi;
    if (i % 11 == 0) angle = std::round(angle / (kPi / 4)) * (kPi / 4);  // axes and diagonals
    const double range =
        (i % 13 == 0 ? 0.0 : rng.Uniform()) * (i % 3 == 0 ? 10.0 : 1.5) * res / 0.01;
    queries.push_back({origin, Vec2(std::cos(angle), std::sin(angle)), range});
  }
  return queries;
}

void ExpectSameAs(const std::vector<RayHit>& plain, const std::vector<RayHit>& fast,
                  const std::vector<RayQuery>& rays, const char* what) {
  ASSERT_EQ(fast.size(), plain.size());
  for (size_t i = 0; i < plain.size(); ++i) {
    const RayQuery& q = rays[i];
    ASSERT_EQ(fast[i].hit, plain[i].hit)
        << what << " ray " << i << " from (" << q.origin.x() << ", " << q.origin.y() << ") along ("
        << q.direction.x() << ", " << q.direction.y() << ") over " << q.max_range_m;
    ASSERT_NEAR(fast[i].distance_m, plain[i].distance_m, 1e-9 * (1 + q.max_range_m))
        << what << " ray " << i;
    ASSERT_NEAR(fast[i].exit_m, plain[i].exit_m, 1e-9 * (1 + q.max_range_m))
        << what << " ray " << i;
    EXPECT_LE(fast[i].cells, plain[i].cells) << what << " ray " << i;
  }
}

// The fast paths (one ray, and a batch of rays in flight together) against the plain traversal.
void ExpectSameHits(const OccupancyGrid& grid, uint64_t seed, int rays, LogOdds occupied_above) {
  const std::vector<RayQuery> queries = RandomRays(seed, rays, grid.geometry().resolution());
  std::vector<RayHit> plain, single;
  int hits = 0;
  for (const RayQuery& q : queries) {
    plain.push_back(
        CastToObstaclePlain(grid, q.origin, q.direction, q.max_range_m, occupied_above));
    single.push_back(CastToObstacle(grid, q.origin, q.direction, q.max_range_m, occupied_above));
    hits += plain.back().hit ? 1 : 0;
  }
  // The rays meet walls often enough for the comparison to mean something, but not always.
  EXPECT_GT(hits, rays / 10);
  EXPECT_LT(hits, rays * 9 / 10);
  ExpectSameAs(plain, single, queries, "single");

  std::vector<RayHit> batch(3, RayHit{});  // resized by the call
  CastToObstacles(grid, queries, occupied_above, batch);
  ExpectSameAs(plain, batch, queries, "batch");
}

TEST(CastToObstacleFast, FindsWhatThePlainTraversalFinds) {
  OccupancyGrid grid = RandomMap(7, 0.01);
  grid.RefreshSummaries();
  ExpectSameHits(grid, 1, 100000, 0);
  ExpectSameHits(grid, 2, 20000, 400);  // a higher threshold: the summary still bounds it
}

TEST(CastToObstacleFast, StaleAndMissingSummariesOnlyCostTime) {
  OccupancyGrid grid = RandomMap(8, 0.01);
  ExpectSameHits(grid, 3, 20000, 0);  // never refreshed: every block examined
  grid.RefreshSummaries();
  // Writes after the refresh: new obstacles in blocks the summary showed empty.
  grid.BeginWrite();
  Rng rng(9);
  for (int k = 0; k < 300; ++k) {
    grid.Add({static_cast<int32_t>(rng.Uniform() * 400 - 200),
              static_cast<int32_t>(rng.Uniform() * 400 - 200)},
             800);
  }
  ExpectSameHits(grid, 4, 20000, 0);
  ExpectSameHits(grid, 5, 5000, -100);  // below the summary's threshold: the plain path
}

TEST(CastToObstacleFast, OtherResolutionsAndSharedTiles) {
  OccupancyGrid grid = RandomMap(10, 0.05);
  const OccupancyGrid copy = grid;  // shares every tile
  // A stale tile held by another grid is copied before its summary is computed: the copy's
  // stay stale (cell by cell), the refreshed grid's get summaries.
  grid.RefreshSummaries();
  EXPECT_FALSE(copy.SharesTileWith(grid, {0, 0}));
  EXPECT_EQ(copy.FindTile({0, 0})->occupied_blocks.load(), kUnknownSummary);
  EXPECT_NE(grid.FindTile({0, 0})->occupied_blocks.load(), kUnknownSummary);
  ExpectSameHits(copy, 6, 20000, 0);
  ExpectSameHits(grid, 12, 20000, 0);
  // Refreshed tiles are shared by later copies, summaries and all.
  const OccupancyGrid later = grid;
  OccupancyGrid again = grid;
  again.RefreshSummaries();
  EXPECT_TRUE(again.SharesTileWith(later, {0, 0}));
}

TEST(CastToObstacleFast, SkipsEmptySpace) {
  OccupancyGrid grid = RandomMap(11, 0.01);
  grid.RefreshSummaries();
  // Through the big free area and the missing tiles beyond: far fewer cells examined.
  const RayHit plain = CastToObstaclePlain(grid, {0.004, 0.003}, 0.3, 10.0, 0);
  const RayHit fast = CastToObstacle(grid, {0.004, 0.003}, 0.3, 10.0, 0);
  EXPECT_EQ(fast.hit, plain.hit);
  EXPECT_LT(fast.cells * 3, plain.cells) << fast.cells << " vs " << plain.cells;
}

TEST(CastToObstacleFast, CrossesMissingTilesInOneJumpEach) {
  OccupancyGrid grid(GridGeometry(0.01), 2000);
  grid.Add({0, 0}, 500);
  grid.Add({640, 0}, 500);  // tile (10, 0): tiles 1 to 9 of the window between are missing
  grid.RefreshSummaries();
  const RayHit hit = CastToObstacle(grid, {0.655, 0.003}, 0.0, 8.0, 0);
  EXPECT_TRUE(hit.hit);
  EXPECT_NEAR(hit.distance_m, 6.40 - 0.655, 1e-9);
  EXPECT_EQ(hit.cells, 0);   // not one cell by cell
  EXPECT_LE(hit.jumps, 12);  // one per missing tile, and a few in tile (10, 0)
}

TEST(OccupancyGrid, SummariesMarkBlocksAboveTheThreshold) {
  OccupancyGrid grid(GridGeometry(0.01), 2000);
  grid.Add({3, 5}, 10);      // block (0, 0)
  grid.Add({63, 63}, 1);     // block (7, 7)
  grid.Add({20, 40}, -500);  // free: no bit
  grid.Add({9, 0}, 0);       // exactly 0: not above
  const Tile* tile = grid.FindTile({0, 0});
  EXPECT_EQ(tile->occupied_blocks.load(), kUnknownSummary);  // written, not refreshed
  grid.RefreshSummaries();
  EXPECT_EQ(tile->occupied_blocks.load(), (uint64_t{1} << 0) | (uint64_t{1} << 63));
  grid.Add({-1, -1}, 5);  // tile (-1, -1), cell (63, 63) of it
  grid.Add({3, 5}, 0);    // rewritten: the summary is unknown again
  EXPECT_EQ(grid.FindTile({0, 0})->occupied_blocks.load(), kUnknownSummary);
  grid.RefreshSummaries();
  EXPECT_EQ(grid.FindTile({-1, -1})->occupied_blocks.load(), uint64_t{1} << 63);
}

TEST(OccupancyGrid, ARefreshWithoutClearanceLeavesOnlyChangedObstaclesStale) {
  OccupancyGrid grid = RandomMap(30, 0.01);
  grid.RefreshSummaries();
  const Tile* changed = grid.FindTile({0, 0});
  const Tile* freer = grid.FindTile({1, 1});
  ASSERT_NE(changed->occupied_blocks.load(), kUnknownSummary);
  ASSERT_NE(changed->clearance[5 * kTileSize + 5], 0);  // (5, 5) is not occupied yet
  ASSERT_NE(freer->occupied_blocks.load(), kUnknownSummary);
  const std::array<uint8_t, kTileCells> freer_clearance = freer->clearance;

  grid.BeginWrite();
  grid.Add({5, 5}, 900);     // a new obstacle in tile (0, 0)
  grid.Add({70, 70}, -300);  // tile (1, 1): a free cell freer, the obstacles unchanged
  grid.RefreshSummaries(/*clearance=*/false);
  // Changed obstacles: stale (rays examine the tile cell by cell, never a stale clearance).
  EXPECT_EQ(changed->occupied_blocks.load(), kUnknownSummary);
  EXPECT_TRUE(changed->clearance_known_stale);
  // Unchanged obstacles get their summary back, with the clearance they had.
  EXPECT_NE(freer->occupied_blocks.load(), kUnknownSummary);
  EXPECT_EQ(freer->clearance, freer_clearance);
  ExpectSameHits(grid, 31, 20000, 0);

  // Written again: the mark goes; a full refresh computes the clearance of what is there now.
  grid.Add({5, 6}, 900);
  EXPECT_FALSE(changed->clearance_known_stale);
  grid.RefreshSummaries();
  EXPECT_NE(changed->occupied_blocks.load(), kUnknownSummary);
  EXPECT_EQ(changed->clearance[5 * kTileSize + 5], 0);
  EXPECT_EQ(changed->clearance[6 * kTileSize + 5], 0);
  ExpectSameHits(grid, 32, 20000, 0);
}

TEST(OccupancyGrid, ClearanceIsTheChessboardDistanceToTheNearestCellAboveTheThreshold) {
  Rng rng(21);
  for (const double density : {0.0005, 0.01, 0.2}) {
    Tile tile;
    std::vector<std::pair<int, int>> occupied;
    for (int y = 0; y < kTileSize; ++y) {
      for (int x = 0; x < kTileSize; ++x) {
        const double r = rng.Uniform();
        // Above the threshold, exactly at it (not occupied), or free.
        const LogOdds value =
            r < density ? LogOdds{1} : (r < 2 * density ? LogOdds{0} : LogOdds{-300});
        tile.cells[static_cast<size_t>(y * kTileSize + x)] = value;
        if (value > kSummaryThreshold) occupied.emplace_back(x, y);
      }
    }
    ASSERT_FALSE(occupied.empty());
    std::array<uint8_t, kTileCells> clearance{};
    ComputeClearance(ComputeOccupiedRows(tile), clearance);
    for (int y = 0; y < kTileSize; ++y) {
      for (int x = 0; x < kTileSize; ++x) {
        int nearest = kClearanceFar;
        for (const auto& [ox, oy] : occupied)
          nearest = std::min(nearest, std::max(std::abs(ox - x), std::abs(oy - y)));
        ASSERT_EQ(clearance[static_cast<size_t>(y * kTileSize + x)], nearest)
            << x << ", " << y << " at " << density;
      }
    }
  }
  Tile empty;
  std::array<uint8_t, kTileCells> clearance{};
  ComputeClearance(ComputeOccupiedRows(empty), clearance);
  EXPECT_EQ(clearance[0], kClearanceFar);
  EXPECT_EQ(clearance[kTileCells - 1], kClearanceFar);
}

TEST(OccupancyGrid, RefreshComputesTheClearanceOfWrittenTiles) {
  OccupancyGrid grid(GridGeometry(0.01), 2000);
  grid.Add({10, 20}, 500);
  grid.RefreshSummaries();
  const Tile* tile = grid.FindTile({0, 0});
  EXPECT_EQ(tile->clearance[20 * kTileSize + 10], 0);
  EXPECT_EQ(tile->clearance[20 * kTileSize + 13], 3);
  EXPECT_EQ(tile->clearance[63 * kTileSize + 0], 43);
  grid.Add({12, 20}, 500);  // written: stale until the next refresh
  EXPECT_EQ(grid.FindTile({0, 0})->occupied_blocks.load(), kUnknownSummary);
  grid.RefreshSummaries();
  EXPECT_EQ(grid.FindTile({0, 0})->clearance[20 * kTileSize + 13], 1);
  // Writes that leave the same cells above the threshold keep the clearance; a copy carries it.
  const OccupancyGrid before = grid;
  grid.Add({30, 30}, -400);
  grid.Add({12, 20}, 300);
  EXPECT_FALSE(grid.SharesTileWith(before, {0, 0}));
  grid.RefreshSummaries();
  const Tile* kept = grid.FindTile({0, 0});
  EXPECT_EQ(kept->clearance, before.FindTile({0, 0})->clearance);
  EXPECT_EQ(kept->clearance[20 * kTileSize + 13], 1);
  // A cell falling to the threshold is not occupied any more: recomputed.
  grid.Add({12, 20}, -800);
  grid.RefreshSummaries();
  EXPECT_EQ(grid.FindTile({0, 0})->clearance[20 * kTileSize + 13], 3);
  EXPECT_EQ(grid.FindTile({0, 0})->clearance[20 * kTileSize + 10], 0);
}

// The side of the largest square of cells not above `threshold` with corner c, growing towards
// -x when back_x and -y when back_y, capped at kClearanceFar; cells outside [lo, hi] count as
// free. Grown one ring (the square's far row and column) at a time.
int FreeSquare(const OccupancyGrid& grid, LogOdds threshold, CellIndex lo, CellIndex hi,
               CellIndex c, bool back_x, bool back_y) {
  const int sx = back_x ? -1 : 1, sy = back_y ? -1 : 1;
  const auto occupied = [&](int x, int y) {
    return x >= lo.x && x <= hi.x && y >= lo.y && y <= hi.y && grid.At({x, y}) > threshold;
  };
  for (int k = 0; k < kClearanceFar; ++k) {
    for (int j = 0; j <= k; ++j) {
      if (occupied(c.x + sx * k, c.y + sy * j) || occupied(c.x + sx * j, c.y + sy * k)) return k;
    }
  }
  return kClearanceFar;
}

TEST(MatchWindow, FreeSquaresAreTheLargestInEachQuadrant) {
  OccupancyGrid grid = RandomMap(31, 0.01);
  grid.RefreshSummaries();
  // Across tile edges and negative coordinates, wider than 128 (the row relaxation's reach),
  // at the summary's threshold, above it, and below it (unknown cells then count).
  const CellIndex lo{-170, -90}, hi{29, 60};
  for (const LogOdds threshold : {LogOdds{0}, LogOdds{400}, LogOdds{-100}}) {
    const MatchWindow window(grid, threshold, lo, hi);
    EXPECT_EQ(window.cells(), 200 * 151);
    for (int quadrant = 0; quadrant < 4; ++quadrant) {
      const bool back_x = (quadrant & 1) != 0, back_y = (quadrant & 2) != 0;
      for (int y = lo.y; y <= hi.y; y += 5) {
        for (int x = lo.x; x <= hi.x; x += 2) {
          ASSERT_EQ(window.FreeSquareAt({x, y}, back_x, back_y),
                    FreeSquare(grid, threshold, lo, hi, {x, y}, back_x, back_y))
              << x << ", " << y << " quadrant " << quadrant << " above " << threshold;
        }
      }
    }
  }
  // Far from anything: capped.
  const OccupancyGrid empty(GridGeometry(0.01), 2000);
  const MatchWindow nothing(empty, 0, {0, 0}, {299, 9});
  EXPECT_EQ(nothing.FreeSquareAt({150, 5}, false, true), kClearanceFar);
}

// Rays through a window around the origin: those it covers through its field, the others
// through the grid; all as the plain traversal finds them.
// The kernels a test runs: the portable one always, the others where this processor has them.
std::vector<WindowKernel> KernelsHere() {
  std::vector<WindowKernel> kernels{WindowKernel::kPortable};
  for (const WindowKernel k : {WindowKernel::kAvx2, WindowKernel::kAvx512}) {
    if (WindowKernelAvailable(k)) kernels.push_back(k);
  }
  return kernels;
}

const char* KernelName(WindowKernel kernel) {
  return kernel == WindowKernel::kAvx512 ? "avx512"
         : kernel == WindowKernel::kAvx2 ? "avx2"
                                         : "portable";
}

// Rays through a window around the origin: those it covers through its field, the others
// through the grid; all as the plain traversal finds them, with each kernel.
void ExpectWindowFindsWhatThePlainTraversalFinds(const OccupancyGrid& grid, uint64_t seed,
                                                 LogOdds threshold) {
  const MatchWindow window(grid, threshold, {-250, -250}, {249, 249});
  const std::vector<RayQuery> queries = RandomRays(seed, 30000, grid.geometry().resolution());
  std::vector<RayHit> plain;
  int covered = 0, hits = 0;
  for (const RayQuery& q : queries) {
    plain.push_back(CastToObstaclePlain(grid, q.origin, q.direction, q.max_range_m, threshold));
    covered += window.Covers(q) ? 1 : 0;
    hits += plain.back().hit ? 1 : 0;
  }
  EXPECT_GT(covered, 30000 / 4);
  EXPECT_LT(covered, 30000 * 3 / 4);
  EXPECT_GT(hits, 30000 / 10);
  for (const WindowKernel kernel : KernelsHere()) {
    std::vector<RayHit> fast;
    CastToObstacles(window, queries, fast, kernel);
    ExpectSameAs(plain, fast, queries, KernelName(kernel));
  }
}

TEST(MatchWindow, FindsWhatThePlainTraversalFinds) {
  OccupancyGrid grid = RandomMap(32, 0.01);
  ExpectWindowFindsWhatThePlainTraversalFinds(grid, 33, 0);  // never refreshed
  grid.RefreshSummaries();
  ExpectWindowFindsWhatThePlainTraversalFinds(grid, 34, 0);
  ExpectWindowFindsWhatThePlainTraversalFinds(grid, 35, 400);
  ExpectWindowFindsWhatThePlainTraversalFinds(grid, 36, -100);  // unknown cells stop rays
  // Rays in a window of empty space jump across it.
  const RayQuery q{{0.004, 0.003}, Vec2(std::cos(0.3), std::sin(0.3)), 1.2};
  const OccupancyGrid empty(GridGeometry(0.01), 2000);
  const MatchWindow window(empty, 0, {-200, -200}, {199, 199});
  ASSERT_TRUE(window.Covers(q));
  for (const WindowKernel kernel : KernelsHere()) {
    std::vector<RayHit> hits;
    CastToObstacles(window, {q}, hits, kernel);
    EXPECT_FALSE(hits[0].hit) << KernelName(kernel);
    EXPECT_EQ(hits[0].cells, 0) << KernelName(kernel);
    EXPECT_LE(hits[0].jumps, 1) << KernelName(kernel);
  }
}

// The wide kernels give the portable one's answers bit for bit (distances, cells and jumps
// counted) on batches of every size around their four and eight lanes, with rays from cell
// corners and edges, along the axes and diagonals, of tiny length, and leaving the window.
class WideKernel : public ::testing::TestWithParam<WindowKernel> {};

TEST_P(WideKernel, GivesThePortableAnswersBitForBit) {
  if (!WindowKernelAvailable(GetParam()))
    GTEST_SKIP() << "this processor cannot run the " << KernelName(GetParam()) << " kernel";
  OccupancyGrid grid = RandomMap(37, 0.01);
  grid.RefreshSummaries();
  const MatchWindow window(grid, 0, {-180, -220}, {209, 139});
  std::vector<RayQuery> all = RandomRays(38, 20000, 0.01);
  Rng rng(39);
  for (int i = 0; i < 2000; ++i) {
    // On cell corners and edges, exactly along axes and diagonals, tiny lengths.
    const Vec2 corner(std::round(rng.Uniform() * 300 - 150) * 0.01,
                      std::round(rng.Uniform() * 300 - 150) * 0.01);
    const double angle = std::round(rng.Uniform() * 8) * kPi / 4;
    const double range = i % 4 == 0 ? 1e-12 : rng.Uniform() * 1.5;
    all.push_back({corner, Vec2(std::cos(angle), std::sin(angle)), range});
    all.push_back(
        {corner + Vec2(0.005, 0.0), Vec2(std::cos(angle + 1e-13), std::sin(angle + 1e-13)), range});
  }
  size_t covered = 0;
  for (const RayQuery& q : all) covered += window.Covers(q) ? size_t{1} : size_t{0};
  EXPECT_GT(covered, all.size() / 4);
  EXPECT_LT(covered, all.size());
  // Batches of 0 to 17 rays (every way of filling and draining the lanes), then one of all.
  size_t begin = 0;
  std::vector<std::vector<RayQuery>> batches;
  for (size_t size = 0; begin + size <= all.size() && batches.size() < 600; ++size) {
    batches.emplace_back(all.begin() + static_cast<std::ptrdiff_t>(begin),
                         all.begin() + static_cast<std::ptrdiff_t>(begin + size % 18));
    begin += size % 18;
  }
  batches.push_back(all);
  for (const std::vector<RayQuery>& batch : batches) {
    std::vector<RayHit> portable, wide(5, RayHit{});  // resized by the call
    CastToObstacles(window, batch, portable, WindowKernel::kPortable);
    CastToObstacles(window, batch, wide, GetParam());
    ASSERT_EQ(wide.size(), batch.size());
    for (size_t i = 0; i < batch.size(); ++i) {
      ASSERT_EQ(wide[i].hit, portable[i].hit) << "ray " << i << " of " << batch.size();
      ASSERT_EQ(wide[i].distance_m, portable[i].distance_m)
          << "ray " << i << " of " << batch.size();
      ASSERT_EQ(wide[i].exit_m, portable[i].exit_m) << "ray " << i << " of " << batch.size();
      ASSERT_EQ(wide[i].cells, portable[i].cells) << "ray " << i << " of " << batch.size();
      ASSERT_EQ(wide[i].jumps, portable[i].jumps) << "ray " << i << " of " << batch.size();
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Kernels, WideKernel,
                         ::testing::Values(WindowKernel::kAvx2, WindowKernel::kAvx512),
                         [](const ::testing::TestParamInfo<WindowKernel>& kernel) {
                           return std::string(KernelName(kernel.param));
                         });

// kBest runs the fastest kernel this processor has, and says which.
TEST(WindowKernel, BestIsTheFastestAvailable) {
  if (std::getenv("SLAM_RAY_KERNEL") != nullptr)
    GTEST_SKIP() << "SLAM_RAY_KERNEL caps the kernel (replay_test checks it)";
  const std::string best = BestWindowKernelName();
  EXPECT_EQ(best, WindowKernelAvailable(WindowKernel::kAvx512) ? "avx512"
                  : WindowKernelAvailable(WindowKernel::kAvx2) ? "avx2"
                                                               : "portable");
  EXPECT_TRUE(WindowKernelAvailable(WindowKernel::kBest));
  EXPECT_TRUE(WindowKernelAvailable(WindowKernel::kPortable));
}

TEST(ApplyUpdateRay, AddsTheProfileByDistance) {
  OccupancyGrid grid(GridGeometry(0.01), 5000);
  UpdateProfile profile;
  profile.step_m = 0.005;
  profile.free_bins = 10;  // free up to 5 cm
  profile.free_delta = -100;
  profile.occupied_bins = 1;  // occupied from 5 to 5.5 cm
  profile.occupied_delta = 700;
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
