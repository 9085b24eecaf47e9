#include "engine/matching_rays.hpp"

#include <limits>

#include "engine/fast_ray.hpp"
#include "engine/grid_traversal.hpp"

namespace slam {

RayHit CastToObstaclePlain(const OccupancyGrid& grid, const Vec2& origin, const Vec2& direction,
                           double max_range_m, LogOdds occupied_above) {
  RayHit result{max_range_m, max_range_m, false, 0, 0};
  // Cache the current tile: consecutive cells of a ray almost always share it.
  TileIndex cached_index{std::numeric_limits<int32_t>::min(), 0};
  const Tile* cached = nullptr;
  result.cells = TraverseCells(
      grid.geometry(), origin, direction, max_range_m,
      [&](CellIndex c, double enter_m, double exit_m) {
        const TileIndex t = GridGeometry::TileOf(c);
        if (!(t == cached_index)) {
          cached_index = t;
          cached = grid.FindTile(t);
        }
        if (cached != nullptr &&
            cached->cells[static_cast<size_t>(GridGeometry::OffsetInTile(c))] > occupied_above) {
          result.distance_m = enter_m;
          result.exit_m = exit_m;
          result.hit = true;
          return false;
        }
        return true;
      });
  return result;
}

RayHit CastToObstacle(const OccupancyGrid& grid, const Vec2& origin, const Vec2& direction,
                      double max_range_m, LogOdds occupied_above) {
  if (!UsesFastPath(grid.geometry(), origin, direction, max_range_m, occupied_above)) {
    return CastToObstaclePlain(grid, origin, direction, max_range_m, occupied_above);
  }
  if (!grid.HasTiles()) return RayHit{max_range_m, max_range_m, false, 0, 0};  // nothing to hit
  return CastOne(TileField(grid, occupied_above), grid.geometry(),
                 {origin, direction, max_range_m});
}

void CastToObstacles(const OccupancyGrid& grid, const std::vector<RayQuery>& rays,
                     LogOdds occupied_above, std::vector<RayHit>& hits) {
  CastInPairs(
      TileField(grid, occupied_above), grid.geometry(), rays, hits,
      [&](const RayQuery& q) {
        return grid.HasTiles() &&
               UsesFastPath(grid.geometry(), q.origin, q.direction, q.max_range_m, occupied_above);
      },
      [&](const RayQuery& q) {
        return CastToObstacle(grid, q.origin, q.direction, q.max_range_m, occupied_above);
      });
}

}  // namespace slam
