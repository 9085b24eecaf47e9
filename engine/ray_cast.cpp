#include "engine/ray_cast.hpp"

#include <algorithm>

namespace slam {

std::vector<CellIndex> CellsOnRay(const GridGeometry& geometry, const Vec2& from, const Vec2& to) {
  std::vector<CellIndex> cells;
  const Vec2 d = to - from;
  const double length = d.norm();
  const Vec2 direction = length > 0 ? Vec2(d / length) : Vec2(1.0, 0.0);
  TraverseCells(geometry, from, direction, length, [&](CellIndex c, double, double) {
    cells.push_back(c);
    return true;
  });
  return cells;
}

RayHit CastToObstaclePlain(const OccupancyGrid& grid, const Vec2& origin, double angle,
                           double max_range_m, LogOdds occupied_above) {
  RayHit result{max_range_m, max_range_m, false, 0};
  const Vec2 direction(std::cos(angle), std::sin(angle));
  // Cache the current tile: consecutive cells of a ray almost always share it.
  TileIndex cached_index{std::numeric_limits<int32_t>::min(), 0};
  const Tile* cached = nullptr;
  result.cells = TraverseCells(grid.geometry(), origin, direction, max_range_m,
                               [&](CellIndex c, double enter_m, double exit_m) {
                                 const TileIndex t = GridGeometry::TileOf(c);
                                 if (!(t == cached_index)) {
                                   cached_index = t;
                                   cached = grid.FindTile(t);
                                 }
                                 if (cached != nullptr &&
                                     cached->cells[static_cast<size_t>(GridGeometry::OffsetInTile(c))] >
                                         occupied_above) {
                                   result.distance_m = enter_m;
                                   result.exit_m = exit_m;
                                   result.hit = true;
                                   return false;
                                 }
                                 return true;
                               });
  return result;
}

RayHit CastToObstacle(const OccupancyGrid& grid, const Vec2& origin, double angle,
                      double max_range_m, LogOdds occupied_above) {
  if (occupied_above < kSummaryThreshold) {
    return CastToObstaclePlain(grid, origin, angle, max_range_m, occupied_above);
  }
  RayHit result{max_range_m, max_range_m, false, 0};
  const double res = grid.geometry().resolution();
  const Vec2 direction(std::cos(angle), std::sin(angle));
  const double length = max_range_m / res;
  GridWalk walk(grid.geometry().ToGrid(origin), direction);
  const Vec2& p = walk.p;
  bool first = true;
  TileIndex cached_index{std::numeric_limits<int32_t>::min(), 0};
  const Tile* tile = nullptr;
  uint64_t mask = 0;
  while (true) {
    const TileIndex ti = GridGeometry::TileOf({walk.cx, walk.cy});
    if (!(ti == cached_index)) {
      cached_index = ti;
      tile = grid.FindTile(ti);
      // A missing tile holds nothing: all of it can be jumped over.
      mask = tile != nullptr ? tile->occupied_blocks.load(std::memory_order_relaxed) : 0;
    }
    const int lx = walk.cx & (kTileSize - 1), ly = walk.cy & (kTileSize - 1);
    const int block = (ly >> kBlockSizeLog2) * kBlocksPerSide + (lx >> kBlockSizeLog2);
    if (((mask >> block) & 1) == 0) {
      // Nothing above the threshold in this block (or the whole tile): jump to where the ray
      // leaves it, and enter the cell beyond.
      const int size = mask == 0 ? kTileSize : kBlockSize;
      const int32_t x_lo = walk.cx & ~(size - 1), y_lo = walk.cy & ~(size - 1);
      const double exit_x = walk.step_x > 0   ? (x_lo + size - p.x()) * walk.delta_x
                            : walk.step_x < 0 ? (p.x() - x_lo) * walk.delta_x
                                              : GridWalk::kInf;
      const double exit_y = walk.step_y > 0   ? (y_lo + size - p.y()) * walk.delta_y
                            : walk.step_y < 0 ? (p.y() - y_lo) * walk.delta_y
                                              : GridWalk::kInf;
      const double t_exit = std::min(exit_x, exit_y);
      if (t_exit >= length) return result;
      const bool corner = std::abs(exit_x - exit_y) <= GridWalk::kCornerEpsilon * (1.0 + t_exit);
      const int32_t x = corner || exit_x < exit_y
                            ? (walk.step_x > 0 ? x_lo + size : x_lo - 1)
                            : std::clamp(static_cast<int32_t>(std::floor(p.x() + direction.x() * t_exit)),
                                         x_lo, x_lo + size - 1);
      const int32_t y = corner || exit_y < exit_x
                            ? (walk.step_y > 0 ? y_lo + size : y_lo - 1)
                            : std::clamp(static_cast<int32_t>(std::floor(p.y() + direction.y() * t_exit)),
                                         y_lo, y_lo + size - 1);
      walk.Enter(x, y, std::max(walk.t, t_exit));
      first = false;
      continue;
    }
    const double t_next = walk.NextCrossing();
    const double t_leave = std::min(t_next, length);
    if (t_leave > walk.t || (length == 0.0 && first)) {
      ++result.cells;
      if (tile->cells[static_cast<size_t>((ly << kTileSizeLog2) | lx)] > occupied_above) {
        result.distance_m = walk.t * res;
        result.exit_m = t_leave * res;
        result.hit = true;
        return result;
      }
    }
    first = false;
    if (t_next >= length) return result;
    walk.Step();
  }
}

int ApplyUpdateRay(OccupancyGrid& grid, const Vec2& origin, double angle, const UpdateProfile& profile) {
  if (profile.delta.empty() || profile.step_m <= 0) return 0;
  const Vec2 direction(std::cos(angle), std::sin(angle));
  const double inv_step = 1.0 / profile.step_m;
  const int limit = grid.limit();
  TileIndex cached_index{std::numeric_limits<int32_t>::min(), 0};
  Tile* cached = nullptr;
  int changed = 0;
  TraverseCells(grid.geometry(), origin, direction, profile.length_m(),
                [&](CellIndex c, double enter_m, double exit_m) {
                  const size_t size = profile.delta.size();
                  if (static_cast<size_t>(enter_m * inv_step) >= size) return false;
                  const int delta = profile.delta[std::min(static_cast<size_t>(exit_m * inv_step), size - 1)];
                  if (delta == 0) return true;
                  const TileIndex t = GridGeometry::TileOf(c);
                  if (cached == nullptr || !(t == cached_index)) {
                    cached_index = t;
                    cached = &grid.MutableTile(t);
                  }
                  LogOdds& cell = cached->cells[static_cast<size_t>(GridGeometry::OffsetInTile(c))];
                  cell = AddLogOdds(cell, delta, limit);
                  ++changed;
                  return true;
                });
  return changed;
}

}  // namespace slam
