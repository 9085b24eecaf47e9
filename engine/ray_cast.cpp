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

RayHit CastToObstacle(const OccupancyGrid& grid, const Vec2& origin, double angle,
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
