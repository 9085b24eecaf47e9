#pragma once
// Matching rays: from a pose to the first occupied cell, the unit of cost that the ray budget
// counts in phase B. One at a time or in batches over the grid; MatchWindow (match_window.hpp)
// casts them faster where many share a neighbourhood.

#include <cmath>
#include <cstdint>
#include <vector>

#include "engine/grid_geometry.hpp"
#include "engine/occupancy_grid.hpp"

namespace slam {

/// What a matching ray found.
struct RayHit {
  double distance_m = 0.0;  // to the entry of the first occupied cell, or the maximum range
  double exit_m = 0.0;      // where the ray leaves that cell (equals distance_m when no hit)
  bool hit = false;         // false: nothing occupied within the maximum range
  int cells = 0;            // cells visited (work done)
  int jumps = 0;            // jumps over empty space (work done by the fast path)
};

/// Matching ray: from `origin` along the unit vector `direction` to the first cell whose log
/// odds exceed `occupied_above`, up to `max_range_m`. Reads only; safe to call concurrently on
/// one grid. Jumps over missing tiles and tiles free of cells above kSummaryThreshold, and
/// inside other tiles moves by their clearance (chessboard distance to the nearest such cell)
/// whenever it exceeds one cell; so for occupied_above >= kSummaryThreshold (below it, and in
/// tiles written since the grid's last RefreshSummaries, this is the cell-by-cell traversal).
/// It finds the same first occupied cell as CastToObstaclePlain; distances agree to rounding
/// (after each jump the traversal restarts from closed-form crossing times).
RayHit CastToObstacle(const OccupancyGrid& grid, const Vec2& origin, const Vec2& direction,
                      double max_range_m, LogOdds occupied_above);

/// One matching ray of a batch.
struct RayQuery {
  Vec2 origin;
  Vec2 direction;  // unit length
  double max_range_m = 0.0;
};

/// CastToObstacle for every ray of `rays` (the same answers, into hits[i]), several rays in
/// flight at once: the processor overlaps their independent chains of loads. `hits` is resized.
void CastToObstacles(const OccupancyGrid& grid, const std::vector<RayQuery>& rays,
                     LogOdds occupied_above, std::vector<RayHit>& hits);

/// The same along `angle` (radians).
inline RayHit CastToObstacle(const OccupancyGrid& grid, const Vec2& origin, double angle,
                             double max_range_m, LogOdds occupied_above) {
  return CastToObstacle(grid, origin, Vec2(std::cos(angle), std::sin(angle)), max_range_m,
                        occupied_above);
}

/// The same, cell by cell through every cell the ray crosses (the oracle of the tests).
RayHit CastToObstaclePlain(const OccupancyGrid& grid, const Vec2& origin, const Vec2& direction,
                           double max_range_m, LogOdds occupied_above);

inline RayHit CastToObstaclePlain(const OccupancyGrid& grid, const Vec2& origin, double angle,
                                  double max_range_m, LogOdds occupied_above) {
  return CastToObstaclePlain(grid, origin, Vec2(std::cos(angle), std::sin(angle)), max_range_m,
                             occupied_above);
}

}  // namespace slam
