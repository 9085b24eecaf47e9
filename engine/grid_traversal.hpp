#pragma once
// Exact traversal of the grid along a ray, the ground of every ray the engine casts.
//
// Traversal is exact (Amanatides & Woo): a ray visits, in order, every cell whose interior it
// crosses. Conventions, relied upon by the tests:
//  - a ray passing exactly through a cell corner steps diagonally (neither side cell is visited);
//  - a ray running exactly along a grid line belongs to the cells above / right of that line
//    (cells are half-open, [i*r, (i+1)*r));
//  - cells crossed over zero length (a ray starting on a boundary and leaving it) are not visited.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
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

  /// Starts in the cell holding `grid_origin`. Preconditions: direction has unit length;
  /// grid_origin inside the map's bound, where cells are exact (TraverseCells clips to it; the
  /// cell is clamped to GridGeometry::kCellSaturation, never an int32 overflow).
  GridWalk(const Vec2& grid_origin, const Vec2& direction) : p(grid_origin) {
    const double dx = direction.x(), dy = direction.y();
    step_x = dx > 0 ? 1 : (dx < 0 ? -1 : 0);
    step_y = dy > 0 ? 1 : (dy < 0 ? -1 : 0);
    delta_x = step_x != 0 ? 1.0 / std::abs(dx) : kInf;
    delta_y = step_y != 0 ? 1.0 / std::abs(dy) : kInf;
    constexpr double limit = GridGeometry::kCellSaturation;
    Enter(static_cast<int32_t>(std::fmax(std::fmin(std::floor(p.x()), limit), -limit)),
          static_cast<int32_t>(std::fmax(std::fmin(std::floor(p.y()), limit), -limit)), 0.0);
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

/// The part [begin, end] (times along the ray, in cells) of the segment from `grid_origin` along
/// the unit vector `direction` over [0, length] (grid coordinates) that lies inside the map's
/// bound, the square [-kMapCellBound, kMapCellBound]^2; nothing when it misses the square, or
/// when the origin or the direction is not finite, or the length NaN or negative. begin is 0
/// when the origin is inside.
struct MapSpan {
  double begin = 0.0;
  double end = 0.0;
};
inline std::optional<MapSpan> ClipToMapBound(const Vec2& grid_origin, const Vec2& direction,
                                             double length) {
  if (!std::isfinite(grid_origin.x()) || !std::isfinite(grid_origin.y()) ||
      !std::isfinite(direction.x()) || !std::isfinite(direction.y()) || !(length >= 0.0)) {
    return std::nullopt;  // an infinite length is fine: the bound ends the segment
  }
  constexpr double b = kMapCellBound;
  double begin = 0.0, end = length;
  for (int axis = 0; axis < 2; ++axis) {
    const double o = grid_origin[axis], v = direction[axis];
    if (v == 0.0) {
      if (!(o >= -b && o <= b)) return std::nullopt;
      continue;
    }
    // The slab's entry and exit times (Kay & Kajiya); finite, as o and v are.
    const double t0 = (-b - o) / v, t1 = (b - o) / v;
    begin = std::max(begin, std::min(t0, t1));
    end = std::min(end, std::max(t0, t1));
  }
  if (!(begin <= end)) return std::nullopt;
  return MapSpan{begin, end};
}

/// Visits the cells crossed by the segment from `origin` (metres) along the unit vector
/// `direction` over `length_m`, calling visit(CellIndex, double enter_m, double exit_m) -> bool
/// in order (distances from `origin`); visiting stops when it returns false. Returns the number
/// of cells visited. Only the part of the segment inside the map's bound is traversed (beyond
/// it nothing is ever written or hit): a segment that misses the bound, or that is not finite,
/// visits nothing. So the work is bounded by the bound's cells whatever the input: a segment
/// inside the bound is traversed as it always was; one from outside starts where it enters.
/// Preconditions: direction has unit length; length_m >= 0.
template <typename Visitor>
int TraverseCells(const GridGeometry& geometry, const Vec2& origin, const Vec2& direction,
                  double length_m, Visitor&& visit) {
  const double res = geometry.resolution();
  const Vec2 p = geometry.ToGrid(origin);
  // (A length beyond double's range in cells is infinite: the bound ends it all the same.)
  const std::optional<MapSpan> span = ClipToMapBound(p, direction, length_m / res);
  // A segment of positive length that only touches the bound crosses nothing inside it.
  if (!span || (span->end <= span->begin && length_m > 0.0)) return 0;
  constexpr double b = kMapCellBound;
  // From outside, the walk starts where the segment enters (clamped onto the bound: far away,
  // the entry point is only as exact as the origin's magnitude allows); from inside, at the
  // origin itself, so that such segments are walked exactly as before.
  const double t0 = span->begin;
  const Vec2 start = t0 > 0.0 ? Vec2(std::clamp(p.x() + direction.x() * t0, -b, b),
                                     std::clamp(p.y() + direction.y() * t0, -b, b))
                              : p;
  const double length = span->end - t0;
  GridWalk walk(start, direction);
  // Each step moves one cell along x or y (or both): the cells between the segment's ends, and
  // one beyond for the corner tolerance, bound the steps whatever the rounding.
  // (Not finite only for a zero direction over an infinite length, which never steps.)
  const Vec2 last = start + direction * length;
  const double span_cells =
      std::abs(std::floor(last.x()) - walk.cx) + std::abs(std::floor(last.y()) - walk.cy) + 2.0;
  const auto max_steps = static_cast<int64_t>(span_cells <= 8.0 * b ? span_cells : 8.0 * b);
  // Where the segment crosses the bound, the walk's crossing times and the clip's agree only to
  // rounding: a cell beyond the bound, crossed over a rounding's length, is not visited.
  const auto inside = [](int32_t c) {
    return static_cast<uint32_t>(c + kMapCellBound) < static_cast<uint32_t>(2 * kMapCellBound);
  };
  int visited = 0;
  for (int64_t steps = 0;; ++steps) {
    const double t_next = walk.NextCrossing();
    const double t_exit = std::min(t_next, length);
    if ((t_exit > walk.t || (length == 0.0 && visited == 0)) && inside(walk.cx) &&
        inside(walk.cy)) {
      ++visited;
      if (!visit(CellIndex{walk.cx, walk.cy}, (t0 + walk.t) * res, (t0 + t_exit) * res)) break;
    }
    if (t_next >= length || steps >= max_steps) break;
    walk.Step();
  }
  return visited;
}

/// The cells a segment crosses, in order (for tests and tools; the hot paths use TraverseCells).
std::vector<CellIndex> CellsOnRay(const GridGeometry& geometry, const Vec2& from, const Vec2& to);

}  // namespace slam
