#include <gtest/gtest.h>

#include <atomic>
#include <limits>
#include <stdexcept>
#include <thread>

#include "engine/cell_encoding.hpp"
#include "engine/grid_geometry.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/update_ray.hpp"

namespace slam {
namespace {

TEST(GridGeometry, CellsOfPointsIncludingNegativeCoordinates) {
  const GridGeometry g(0.01);
  EXPECT_EQ(g.CellOf({0.0, 0.0}), (CellIndex{0, 0}));
  EXPECT_EQ(g.CellOf({0.0099, 0.0101}), (CellIndex{0, 1}));
  EXPECT_EQ(g.CellOf({-0.0001, -0.0101}), (CellIndex{-1, -2}));
  EXPECT_EQ(g.CellOf({1.234, -5.678}), (CellIndex{123, -568}));
  const Vec2 c = g.CellCenter({-1, 2});
  EXPECT_NEAR(c.x(), -0.005, 1e-12);
  EXPECT_NEAR(c.y(), 0.025, 1e-12);
  EXPECT_EQ(g.CellOf(g.CellCenter({-37, 81})), (CellIndex{-37, 81}));
}

TEST(GridGeometry, TilesUseFloorDivision) {
  EXPECT_EQ(GridGeometry::TileOf({0, 63}), (TileIndex{0, 0}));
  EXPECT_EQ(GridGeometry::TileOf({64, -1}), (TileIndex{1, -1}));
  EXPECT_EQ(GridGeometry::TileOf({-64, -65}), (TileIndex{-1, -2}));
  EXPECT_EQ(GridGeometry::TileOrigin({-1, 2}), (CellIndex{-64, 128}));
  EXPECT_EQ(GridGeometry::OffsetInTile({-1, -1}), 63 * 64 + 63);
  EXPECT_EQ(GridGeometry::OffsetInTile({65, 130}), 2 * 64 + 1);
}

TEST(CellEncoding, RoundTripsAndClamps) {
  EXPECT_EQ(EncodeLogOdds(0.85), 850);
  EXPECT_NEAR(DecodeLogOdds(EncodeLogOdds(-0.4)), -0.4, 1e-12);
  EXPECT_EQ(EncodeLogOdds(100.0), kLogOddsLimit);
  EXPECT_EQ(AddLogOdds(4900, 850, 5000), 5000);
  EXPECT_EQ(AddLogOdds(-4900, -850, 5000), -5000);
  EXPECT_NEAR(OccupancyProbability(0), 0.5, 1e-12);
}

TEST(OccupancyGrid, UnknownUntilWrittenAndGrowsInEveryDirection) {
  OccupancyGrid grid(GridGeometry(0.01), 5000);
  EXPECT_EQ(grid.At({5, 5}), 0);
  EXPECT_EQ(grid.TileCount(), 0);
  const CellIndex cells[] = {{0, 0}, {-1, -1}, {1000, -2000}, {-8000, 3}, {63, 64}};
  int delta = 100;
  for (const CellIndex& c : cells) grid.Add(c, delta += 10);
  delta = 100;
  for (const CellIndex& c : cells) EXPECT_EQ(grid.At(c), delta += 10);
  EXPECT_EQ(grid.At({1, 0}), 0);
  EXPECT_EQ(grid.TileCount(), 5);
  EXPECT_EQ(grid.Tiles().size(), 5u);
}

TEST(OccupancyGrid, NothingIsWrittenBeyondTheMapsBound) {
  // Odometry gone wild or a crafted saved map once made the tile table cover both a cell near
  // the origin and one kilometres away (gigabytes): cells beyond the bound are not written.
  OccupancyGrid grid(GridGeometry(0.01), 5000);
  const int32_t edge = kMapTileBound * kTileSize;  // the first cell beyond the bound
  EXPECT_TRUE(grid.Add({edge - 1, -edge}, 100));
  EXPECT_FALSE(grid.Add({edge, 0}, 100));
  EXPECT_FALSE(grid.Add({0, -edge - 1}, 100));
  EXPECT_FALSE(
      grid.Add({std::numeric_limits<int32_t>::min(), std::numeric_limits<int32_t>::max()}, 100));
  EXPECT_EQ(grid.At({edge, 0}), 0);
  EXPECT_EQ(grid.TileCount(), 1);
  EXPECT_THROW(grid.MutableTile({kMapTileBound, 0}), std::out_of_range);
  EXPECT_THROW(grid.MutableTile({0, -kMapTileBound - 1}), std::out_of_range);
  EXPECT_EQ(grid.TileCount(), 1);
  // An update ray from inside to far beyond the bound writes only the cells inside it.
  OccupancyGrid rays(GridGeometry(0.01), 5000);
  UpdateProfile profile;
  profile.step_m = 0.01;
  profile.free_bins = 400;  // 4 m of free space
  profile.free_delta = -10;
  const double x0 = (edge - 100 + 0.5) * 0.01;  // 1 m before the bound, mid-cell
  const int changed = ApplyUpdateRay(rays, {x0, 0.005}, 0.0, profile);
  EXPECT_EQ(changed, 100);
  EXPECT_EQ(rays.At({edge - 1, 0}), -10);
  EXPECT_EQ(rays.At({edge, 0}), 0);
  for (const TileRef& ref : rays.Tiles()) EXPECT_TRUE(InMapBound(ref.index));
}

TEST(OccupancyGrid, ClampsToItsLimit) {
  OccupancyGrid grid(GridGeometry(0.01), 1000);
  for (int i = 0; i < 10; ++i) grid.Add({3, 4}, 400);
  EXPECT_EQ(grid.At({3, 4}), 1000);
  for (int i = 0; i < 10; ++i) grid.Add({3, 4}, -400);
  EXPECT_EQ(grid.At({3, 4}), -1000);
}

TEST(OccupancyGrid, CopiesShareTilesUntilWritten) {
  OccupancyGrid a(GridGeometry(0.01), 5000);
  a.Add({1, 1}, 500);
  a.Add({100, 1}, 500);
  const OccupancyGrid b = a;  // resampling copies pointers, not maps
  OccupancyGrid c = a;
  EXPECT_TRUE(b.SharesTileWith(a, {0, 0}));
  EXPECT_TRUE(c.SharesTileWith(a, {1, 0}));

  c.Add({2, 2}, -300);
  EXPECT_FALSE(c.SharesTileWith(a, {0, 0}));  // written: copied
  EXPECT_TRUE(c.SharesTileWith(a, {1, 0}));   // untouched: still shared
  EXPECT_EQ(c.At({2, 2}), -300);
  EXPECT_EQ(a.At({2, 2}), 0);  // the others are intact
  EXPECT_EQ(b.At({2, 2}), 0);
  EXPECT_EQ(c.At({1, 1}), 500);  // the copy kept the shared contents
}

// One particle's grid copies a shared tile on write in its own thread and lets go of it; the
// other grid, now its only owner, writes in place. The copy must happen before that write
// (ThreadSanitizer found that use_count() alone did not order them; scripts/sanitize tsan).
TEST(OccupancyGrid, CopyOnWriteInAnotherThreadHappensBeforeTheLastOwnerWrites) {
  for (int round = 0; round < 20; ++round) {
    OccupancyGrid a(GridGeometry(0.01), 5000);
    a.Add({1, 1}, 500);
    OccupancyGrid b = a;
    std::atomic<bool> copied{false};
    std::thread other([&] {
      b.Add({2, 2}, -300);  // copies the shared tile, then drops b's reference to it
      copied.store(true, std::memory_order_relaxed);  // orders nothing: the grid must
    });
    while (!copied.load(std::memory_order_relaxed)) std::this_thread::yield();
    a.Add({1, 1}, 100);  // a holds the tile alone now: written in place
    other.join();
    EXPECT_EQ(a.At({1, 1}), 600);
    EXPECT_EQ(b.At({1, 1}), 500);
    EXPECT_EQ(b.At({2, 2}), -300);
    EXPECT_EQ(a.At({2, 2}), 0);
    EXPECT_FALSE(b.SharesTileWith(a, {0, 0}));
  }
}

// The same between two grids refreshing a shared tile's summaries (ProcessScan refreshes its
// particles' grids in parallel): one copies the tile and lets go of it, the other, then its
// only owner, computes the clearance in place. ThreadSanitizer flagged the refresh, which
// lacked the acquire that writing has (CI, a replay under the adaptive policy).
TEST(OccupancyGrid, SummaryRefreshInAnotherThreadHappensBeforeTheLastOwnerRefreshes) {
  for (int round = 0; round < 20; ++round) {
    OccupancyGrid a(GridGeometry(0.01), 5000);
    a.Add({1, 1}, 4000);  // occupied: the refresh computes the tile's clearance
    OccupancyGrid b = a;  // shares the tile, its summaries still to be computed
    std::atomic<bool> copied{false};
    std::thread other([&] {
      b.RefreshSummaries();  // copies the shared tile, then drops b's reference to it
      copied.store(true, std::memory_order_relaxed);  // orders nothing: the grid must
    });
    while (!copied.load(std::memory_order_relaxed)) std::this_thread::yield();
    a.RefreshSummaries();  // a holds the tile alone now: refreshed in place
    other.join();
    EXPECT_FALSE(b.SharesTileWith(a, {0, 0}));
    EXPECT_EQ(a.At({1, 1}), 4000);
    EXPECT_EQ(b.At({1, 1}), 4000);
  }
}

TEST(OccupancyGrid, VersionsOnlyGrowAndIdentifyContents) {
  OccupancyGrid a(GridGeometry(0.01), 5000);
  a.BeginWrite();
  a.Add({1, 1}, 10);
  const uint64_t v1 = a.FindTile({0, 0})->version;
  EXPECT_GT(v1, 0u);
  a.Add({2, 1}, 10);  // same epoch, same version
  EXPECT_EQ(a.FindTile({0, 0})->version, v1);

  OccupancyGrid b = a;
  b.Add({3, 3}, 10);  // a copy writes in its own epoch
  const uint64_t vb = b.FindTile({0, 0})->version;
  EXPECT_GT(vb, v1);
  a.BeginWrite();
  a.Add({4, 4}, 10);
  const uint64_t v2 = a.FindTile({0, 0})->version;
  EXPECT_GT(v2, vb);  // distinct contents never share a version
  EXPECT_EQ(a.Version(), v2);
  EXPECT_EQ(b.Version(), vb);
}

}  // namespace
}  // namespace slam
