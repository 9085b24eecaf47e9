#pragma once
// Trajectories in the TUM RGB-D format: one pose per line, "t x y z qx qy qz qw" (planar: z = 0,
// rotation about z). Used for trajectory.tum (our output) and groundtruth.tum (the tracker's).

#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include "engine/pose.hpp"
#include "engine/result.hpp"

namespace slam::io {

/// The trajectory as TUM text (times with microseconds, positions with micrometres).
std::string FormatTum(const std::vector<TimedPose>& trajectory);

/// A square every position must lie in: lo_m <= x < hi_m and lo_m <= y < hi_m; `name` says what
/// it is in errors ("the map's bound"). The default admits every finite position.
struct PositionBound {
  double lo_m = -std::numeric_limits<double>::infinity();
  double hi_m = std::numeric_limits<double>::infinity();
  std::string name = "the allowed square";
};

/// Parses TUM text; `source` names the input in errors ("groundtruth.tum:12: ..."). Blank lines
/// and lines starting with '#' are skipped. Errors: wrong field count, non-numbers, non-finite
/// values, a position outside `bound`, a quaternion far from unit length, times not strictly
/// increasing.
Result<std::vector<TimedPose>> ParseTum(std::string_view text, const std::string& source,
                                        const PositionBound& bound = {});

/// Reads and parses a TUM file.
Result<std::vector<TimedPose>> LoadTum(const std::string& path);

}  // namespace slam::io
