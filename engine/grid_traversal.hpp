#pragma once
// Exact traversal of the grid along a ray, the ground of every ray the engine casts.
//
// Traversal is exact (Amanatides & Woo): a ray visits, in order, every cell whose interior it
// crosses. Conventions, relied upon by the tests:
//  - a ray passing exactly through a cell corner steps diagonally (neither side cell is visited);
//  - a ray running exactly along a grid line belongs to the cells above / right of that line
//    (cells are half-open, [i*r, (i+1)*r));
//  - cells crossed over zero length (a ray starting on a boundary and leaving it) are not visited.

#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "engine/grid_geometry.hpp"

namespace slam {

/// Amanatides & Woo traversal state, in cell units along the ray: the current cell and the
/// times of the next x and y boundary crossings. The matching rays' fast path (fast_ray.hpp)
/// starts in the same cell and uses the same crossing expressions and corner tolerance.
struct GridWalk {
  static constexpr double kInf = std::numeric_limits<double>::infinity();
  static constexpr double kCornerEpsilon = 1e-9;

  Vec2 p;  // origin in grid coordinates
  int step_x = 0, step_y = 0;
  double delta_x = kInf, delta_y = kInf;  // time to cross one cell along x / y
  int32_t cx = 0, cy = 0;
  double next_x = kInf, next_y = kInf;
  double t = 0.0;  // when the ray entered the current cell

  /// Starts in the cell holding `grid_origin`. Precondition: direction has unit length.
  GridWalk(const Vec2& grid_origin, const Vec2& direction) : p(grid_origin) {
    const double dx = direction.x(), dy = direction.y();
    step_x = dx > 0 ? 1 : (dx < 0 ? -1 : 0);
    step_y = dy > 0 ? 1 : (dy < 0 ? -1 : 0);
    delta_x = step_x != 0 ? 1.0 / std::abs(dx) : kInf;
    delta_y = step_y != 0 ? 1.0 / std::abs(dy) : kInf;
    Enter(static_cast<int32_t>(std::floor(p.x())), static_cast<int32_t>(std::floor(p.y())), 0.0);
  }

  /// Moves to cell (x, y), entered at time `time`; the next crossings in closed form.
  void Enter(int32_t x, int32_t y, double time) {
    cx = x;
    cy = y;
    t = time;
    next_x = step_x > 0 ? (cx + 1 - p.x()) * delta_x : step_x < 0 ? (p.x() - cx) * delta_x : kInf;
    next_y = step_y > 0 ? (cy + 1 - p.y()) * delta_y : step_y < 0 ? (p.y() - cy) * delta_y : kInf;
  }

  /// When the ray leaves the current cell.
  double NextCrossing() const { return std::min(next_x, next_y); }

  /// Into the next cell: diagonally when both crossings coincide (a corner), else across the
  /// nearer boundary.
  void Step() {
    const double t_next = NextCrossing();
    if (std::abs(next_x - next_y) <= kCornerEpsilon * (1.0 + t_next)) {
      cx += step_x;
      cy += step_y;
      t = t_next;
      next_x += delta_x;
      next_y += delta_y;
    } else if (next_x < next_y) {
      cx += step_x;
      t = next_x;
      next_x += delta_x;
    } else {
      cy += step_y;
      t = next_y;
      next_y += delta_y;
    }
  }
};

/// Visits the cells crossed by the segment from `origin` (metres) along the unit vector
/// `direction` over `length_m`, calling visit(CellIndex, double enter_m, double exit_m) -> bool
/// in order; visiting stops when it returns false. Returns the number of cells visited.
/// Preconditions: direction has unit length; length_m >= 0 and finite.
template <typename Visitor>
int TraverseCells(const GridGeometry& geometry, const Vec2& origin, const Vec2& direction,
                  double length_m, Visitor&& visit) {
  const double res = geometry.resolution();
  const double length = length_m / res;
  GridWalk walk(geometry.ToGrid(origin), direction);
  int visited = 0;
  while (true) {
    const double t_next = walk.NextCrossing();
    const double t_exit = std::min(t_next, length);
    if (t_exit > walk.t || (length == 0.0 && visited == 0)) {
      ++visited;
      if (!visit(CellIndex{walk.cx, walk.cy}, walk.t * res, t_exit * res)) break;
    }
    if (t_next >= length) break;
    walk.Step();
  }
  return visited;
}

/// The cells a segment crosses, in order (for tests and tools; the hot paths use TraverseCells).
std::vector<CellIndex> CellsOnRay(const GridGeometry& geometry, const Vec2& from, const Vec2& to);

}  // namespace slam
