#include "engine/grid_traversal.hpp"

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

}  // namespace slam
