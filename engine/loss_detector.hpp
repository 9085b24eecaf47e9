#pragma once
// Is the tracker lost? After a robot is lifted and set down elsewhere (or a track breaks), the
// odometry carries the pose on from where it was, and the readings, placed there, land where
// the map knows there is nothing: in free space it has seen through many times. While tracking,
// readings land on or next to the walls they see, or in unknown space (a room not yet mapped
// says nothing either way). The detector places each scan's readings by the tracker's
// prediction, before the scan changes the map, and counts those that land in known free space
// against those next to an occupied cell; over a window of scans, a share of contradictions
// above `lost_share` is a loss (docs/design.md, relocalisation).
//
// A reading that lands in unknown space contradicts the map too when its ray passes through a
// wall the map is sure of: seen through it. A robot set down in the middle of a room sees
// little at first, and what it sees, placed where it wrongly is, lands beyond the room's walls,
// where the map knows nothing; such readings said nothing, and the tracker mapped a second,
// turned copy of the room outside the first unchallenged. A reading that ends next to an
// occupied cell agrees whatever its ray crossed (a ray grazing the wall it ends on).

#include <cstdint>
#include <deque>
#include <vector>

#include "engine/config_error.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"

namespace slam {

struct LossDetectorConfig {
  int max_points = 100;  // readings checked per scan, evenly spaced (the check's cost)
  /// A reading agrees with the map when an occupied cell lies within this radius of its end
  /// (the tracker's own error and the sensor's noise: a few centimetres).
  double agree_radius_m = 0.03;
  /// It contradicts the map when every cell within agree_radius_m is known free, below this
  /// (natural log-odds): seen free several times.
  double free_below_logodds = -2.0;
  double occupied_above_logodds = 0.0;  // as the matching rays' obstacles
  /// A reading in unknown space was seen through a wall when a cell above this log odds (seen
  /// occupied several times) lies on its ray, from the robot's centre to `through_margin_m`
  /// before its end, within the last `through_reach_m` of that (the check's cost).
  double through_above_logodds = 2.0;
  double through_margin_m = 0.10;
  double through_reach_m = 1.0;
  int window_scans = 6;     // the scans a verdict is drawn over (about 4 s at 1.5 scans/s)
  int min_known = 60;       // readings on known cells over the window for a verdict
  double lost_share = 0.5;  // contradicting share of those that is a loss
  /// The map the readings are checked against is the one before this many scans (window
  /// and one: about 5 s): a lost tracker maps what it sees where it wrongly is, and its next
  /// scans would agree with that. A loss takes back what was mapped since then.
  int history_scans = 7;

  /// Out-of-range values as JSON pointers; empty when valid.
  ConfigErrors Validate() const;
};

/// One scan's check.
struct LossCheck {
  int agree = 0;              // readings next to an occupied cell
  int contradict = 0;         // readings in known free space, or seen through a wall
  int through = 0;            // of those, seen through a wall
  int unknown = 0;            // neither
  int64_t lookups = 0;        // cells read (the check's cost)
  double window_share = 0.0;  // contradicting share over the window (0 without a verdict)
  bool lost = false;          // the window's verdict after this scan
};

class LossDetector {
 public:
  explicit LossDetector(const LossDetectorConfig& config = {});

  /// Checks one scan's readings (robot frame at its end, Slam::ReadingPoints) placed at `pose`
  /// (the tracker's prediction of the scan's end) against `map`, and draws the verdict over the
  /// window. Readings that are not finite are skipped.
  LossCheck Check(const OccupancyGrid& map, const Pose2& pose, const std::vector<Vec2>& points);
  /// Forgets the window (after a relocalisation, a reset).
  void Reset() { window_.clear(); }
  /// A check's lookups (cells read, a wall's neighbourhood or a ray's traversal, each a tile
  /// lookup, with each reading's placing) per quota ray: a lookup costs 2.5 to 4 of the
  /// global matcher's byte reads, a ray 8 to 22 of them (bench: BM_LossCheck against BM_Scan,
  /// docs/performance.md); the rate errs low, so that a check is never charged less than it
  /// costs.
  static constexpr int64_t kLookupsPerRay = 8;
  /// The quota rays a check of `lookups` is charged.
  static int64_t RaysOf(int64_t lookups) { return (lookups + kLookupsPerRay - 1) / kLookupsPerRay; }
  /// Upper bound of one Check's lookups (a plan is charged what a check spent: LossCheck).
  int64_t MaxLookups() const;
  int window_scans() const { return config_.window_scans; }
  const LossDetectorConfig& config() const { return config_; }

 private:
  struct Counts {
    int agree = 0, contradict = 0;
  };
  LossDetectorConfig config_;
  std::deque<Counts> window_;
};

}  // namespace slam
