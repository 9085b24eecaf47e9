#pragma once
// Quality of a SLAM occupancy grid against the true simulated world: precision and recall of the
// occupied cells with respect to the world's surfaces (walls and the boundaries of round
// obstacles), within a distance tolerance.
//
// Precision: of the map's occupied cells (p >= occupied_probability), the fraction whose centre,
// mapped into the world by `map_to_world`, lies within tolerance_m of a world surface. A cell deep
// inside a solid obstacle counts as wrong: distances are to the obstacle's boundary. Low
// precision means phantom or misplaced walls.
//
// Recall: of the world's surfaces that the robot could have seen, the fraction the map shows.
// Surfaces are sampled every surface_step_m; a sample is observable when some ground-truth
// position (at least pose_step_s apart in time) lies within visible_range_m of it with a clear
// line of sight, whatever the robot's heading. Recall is the fraction of observable samples with
// an occupied cell within tolerance_m. Low recall means walls the robot passed are missing.
//
// The tolerance should be at least half a cell diagonal, or exact walls would miss it.

#include <cstdint>
#include <vector>

#include "engine/config_error.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"
#include "engine/quality.hpp"
#include "sim/world.hpp"

namespace slam::sim {

struct MapQualityConfig {
  double tolerance_m = 0.05;           // a cell is right when this close to a surface
  double occupied_probability = 0.65;  // cells at or above are occupied (ROS map_server default)
  double visible_range_m = 1.0;        // a surface farther from every pose was never observable
  double surface_step_m = 0.01;        // spacing of the samples along the surfaces
  double pose_step_s = 0.5;            // ground-truth poses used at least this far apart in time

  /// Out-of-range or non-finite values, as JSON pointers ("/tolerance_m"); empty when valid.
  ConfigErrors Validate() const;
};

struct MapQuality {
  int64_t occupied_cells = 0;        // cells with p >= occupied_probability
  int64_t true_occupied_cells = 0;   // occupied cells within tolerance of a world surface
  double precision = 0.0;            // true_occupied_cells / occupied_cells, 0 for an empty map
  int64_t surface_points = 0;        // observable surface samples
  int64_t surface_points_found = 0;  // observable samples with an occupied cell within tolerance
  double recall = 0.0;               // surface_points_found / surface_points, 0 when none
  double f1 = 0.0;                   // harmonic mean of precision and recall, 0 when both are 0
  double tolerance_m = 0.0;          // the tolerance used
};

/// Scores `map` against `world`; `map_to_world` maps map coordinates into the world frame and
/// `ground_truth` is the robot's true, time-ordered trajectory in the world frame.
/// Deterministic. Precondition: config.Validate() is empty (otherwise an all-zero result).
MapQuality EvaluateMap(const OccupancyGrid& map, const RigidTransform2& map_to_world,
                       const World& world, const std::vector<TimedPose>& ground_truth,
                       const MapQualityConfig& config = {});

}  // namespace slam::sim
