#pragma once
// Rooms drawn as point outlines for the global matcher's and the relocaliser's tests: a map of
// them drawn cell by cell, and what a robot standing in them sees.

#include <cmath>
#include <cstddef>
#include <vector>

#include "engine/cell_encoding.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"

namespace slam::testing {

/// Points every `step` metres along a closed polyline.
inline std::vector<Vec2> Outline(const std::vector<Vec2>& corners, double step) {
  std::vector<Vec2> points;
  for (size_t k = 0; k + 1 < corners.size(); ++k) {
    const Vec2 a = corners[k], b = corners[k + 1];
    const int steps = static_cast<int>(std::ceil((b - a).norm() / step));
    for (int i = 0; i < steps; ++i) points.push_back(a + (b - a) * (double(i) / steps));
  }
  return points;
}

/// An L-shaped room (no symmetry): the outline from (-1, -1) to (1.4, 1) with the corner
/// (0.6..1.4, 0.3..1) cut out, and a 20 cm box at (-0.5..-0.3, 0.3..0.5).
inline std::vector<Vec2> LRoom() {
  std::vector<Vec2> points = Outline(
      {{-1.0, -1.0}, {1.4, -1.0}, {1.4, 0.3}, {0.6, 0.3}, {0.6, 1.0}, {-1.0, 1.0}, {-1.0, -1.0}},
      0.005);
  const std::vector<Vec2> box =
      Outline({{-0.5, 0.3}, {-0.3, 0.3}, {-0.3, 0.5}, {-0.5, 0.5}, {-0.5, 0.3}}, 0.005);
  points.insert(points.end(), box.begin(), box.end());
  return points;
}

/// A grid of `cell_m` cells where every cell holding an outline point is occupied.
inline OccupancyGrid Draw(const std::vector<Vec2>& outline, double cell_m) {
  OccupancyGrid map(GridGeometry(cell_m), EncodeLogOdds(5.0));
  map.BeginWrite();
  for (const Vec2& p : outline) {
    const CellIndex c = map.geometry().CellOf(p);
    if (map.At(c) <= 0) map.Add(c, EncodeLogOdds(3.0));
  }
  map.RefreshSummaries();
  return map;
}

/// What a robot at `pose` sees of an outline: its points within `range`, every `every`-th, in
/// the robot's frame.
inline std::vector<Vec2> SeenFrom(const std::vector<Vec2>& outline, const Pose2& pose, double range,
                                  size_t every) {
  std::vector<Vec2> seen;
  const Pose2 inverse = Inverse(pose);
  for (size_t i = 0; i < outline.size(); i += every) {
    const Vec2 local = inverse.Transform(outline[i]);
    if (local.norm() <= range) seen.push_back(local);
  }
  return seen;
}

}  // namespace slam::testing
