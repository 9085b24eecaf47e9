#include "engine/update_ray.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "engine/cell_encoding.hpp"
#include "engine/grid_traversal.hpp"

namespace slam {

int ApplyUpdateRay(OccupancyGrid& grid, const Vec2& origin, double angle,
                   const UpdateProfile& profile) {
  if (profile.bins() <= 0 || profile.step_m <= 0) return 0;
  const Vec2 direction(std::cos(angle), std::sin(angle));
  const double inv_step = 1.0 / profile.step_m;
  const int limit = grid.limit();
  TileIndex cached_index{std::numeric_limits<int32_t>::min(), 0};
  Tile* cached = nullptr;
  int changed = 0;
  TraverseCells(grid.geometry(), origin, direction, profile.length_m(),
                [&](CellIndex c, double enter_m, double exit_m) {
                  const auto size = static_cast<size_t>(profile.bins());
                  if (static_cast<size_t>(enter_m * inv_step) >= size) return false;
                  const int delta =
                      profile.Delta(std::min(static_cast<size_t>(exit_m * inv_step), size - 1));
                  if (delta == 0) return true;
                  const TileIndex t = GridGeometry::TileOf(c);
                  if (cached == nullptr || !(t == cached_index)) {
                    if (!InMapBound(t)) return true;  // never written: the map is bounded
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
