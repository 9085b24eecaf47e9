#pragma once
// Update rays: a reading's log-odds changes written along its ray (phase C), from the
// precomputed profile of its sensor model.

#include <cstddef>
#include <cstdint>
#include <vector>

#include "engine/grid_geometry.hpp"
#include "engine/occupancy_grid.hpp"

namespace slam {

/// The log-odds change along an update ray, by distance from the sensor, in bins of step_m:
/// `free_delta` over the first `free_bins`, then `occupied_delta` over `occupied_bins` (paper
/// Fig. 7: free before the measured point, occupied at it and a little behind). A crossed cell
/// takes the value at the far end of its crossing, which is the largest over the crossing: the
/// cell holding the measured point is always occupied, whatever the angle. The ray stops at the
/// end of the profile. Two numbers instead of a table per reading: a laser's 25 m at 5 mm bins
/// would be 5000 entries per distance.
struct UpdateProfile {
  double step_m = 0.0;
  int32_t free_bins = 0;
  int32_t occupied_bins = 0;
  int16_t free_delta = 0;
  int16_t occupied_delta = 0;

  int32_t bins() const { return free_bins + occupied_bins; }
  double length_m() const { return step_m * static_cast<double>(bins()); }
  /// The change of bin `i` (in [0, bins())).
  int Delta(size_t i) const {
    return i < static_cast<size_t>(free_bins) ? free_delta : occupied_delta;
  }
};

/// Update ray: applies `profile` along the ray from `origin` in direction `angle`.
/// Returns the number of cells changed.
int ApplyUpdateRay(OccupancyGrid& grid, const Vec2& origin, double angle,
                   const UpdateProfile& profile);

}  // namespace slam
