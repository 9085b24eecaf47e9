#pragma once
// Update rays: a reading's log-odds changes written along its ray (phase C), from the
// precomputed profile of its sensor model.

#include <cstdint>
#include <vector>

#include "engine/grid_geometry.hpp"
#include "engine/occupancy_grid.hpp"

namespace slam {

/// The log-odds change along an update ray, by distance from the sensor, in bins of step_m.
/// `delta` must be non-decreasing (free, then occupied). A crossed cell takes the value at the far
/// end of its crossing, which is the largest over the crossing: the cell holding the measured
/// point is always occupied, whatever the angle. The ray stops at the end of the table.
struct UpdateProfile {
  double step_m = 0.0;
  std::vector<int16_t> delta;
  double length_m() const { return step_m * static_cast<double>(delta.size()); }
};

/// Update ray: applies `profile` along the ray from `origin` in direction `angle`.
/// Returns the number of cells changed.
int ApplyUpdateRay(OccupancyGrid& grid, const Vec2& origin, double angle,
                   const UpdateProfile& profile);

}  // namespace slam
