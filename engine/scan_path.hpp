#pragma once
// One scan as the filter sees it: its usable readings with their geometry in the robot's frame
// (Measurement), and a particle's path through it (ScanPath), which places every reading's ray
// under a correction of the scan's end pose.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

#include "engine/fast_math.hpp"
#include "engine/pose.hpp"
#include "engine/scan.hpp"

namespace slam {

/// A usable reading of one sensor at one sample, with its geometry in the robot's frame.
struct Measurement {
  size_t sample = 0;
  int sensor = 0;
  uint16_t raw = 0;
  double distance_m = 0.0;
  double sigma_m = 0.0;
  double local_angle = 0.0;  // sensor direction relative to the robot's heading
  Vec2 local_origin = Vec2::Zero();
  Vec2 local_direction = Vec2::UnitX();  // (cos, sin) of local_angle
  double match_range_m = 0.0;            // how far its matching ray looks
};

/// The robot's path through one scan for one particle: the odometry path anchored at the
/// particle's start pose, plus a correction that moves the end onto a chosen pose. The correction
/// is shared between the start and the drift over the scan: `start_share` of it applies from the
/// first sample on, the rest grows linearly in time. The start is the previous scan's match, off
/// by about as much as the odometry drifts over a scan; a correction that grows from zero (the
/// paper's, start_share 0) holds the start where the previous match put it, and leaves the end
/// to absorb both errors (docs/design.md, phase B).
class ScanPath {
 public:
  ScanPath(const Scan& scan, const Pose2& start, double start_share) {
    const double span = scan.t_end - scan.t_begin;
    nominal_.reserve(scan.samples.size());
    cos_.reserve(scan.samples.size());
    sin_.reserve(scan.samples.size());
    fraction_.reserve(scan.samples.size());
    for (const ScanSample& s : scan.samples) {
      nominal_.push_back(Compose(start, Between(scan.odom_begin, s.odom)));
      cos_.push_back(std::cos(nominal_.back().theta));
      sin_.push_back(std::sin(nominal_.back().theta));
      const double f = span > 0 ? std::clamp((s.t - scan.t_begin) / span, 0.0, 1.0) : 1.0;
      fraction_.push_back(start_share + (1.0 - start_share) * f);
    }
    nominal_end_ = Compose(start, Between(scan.odom_begin, scan.odom_end));
  }

  const Pose2& nominal_end() const { return nominal_end_; }

  /// Correction that moves the nominal end onto `end`.
  Pose2 CorrectionTo(const Pose2& end) const {
    return {end.x - nominal_end_.x, end.y - nominal_end_.y,
            NormalizeAngle(end.theta - nominal_end_.theta)};
  }

  /// Pose at sample i under a correction.
  Pose2 SamplePose(size_t i, const Pose2& correction) const {
    const double s = fraction_[i];
    const Pose2& n = nominal_[i];
    return {n.x + s * correction.x, n.y + s * correction.y,
            NormalizeAngle(n.theta + s * correction.theta)};
  }

  /// The same pose as a position and the cosine and sine of its heading (what rays need).
  struct Frame {
    double x, y, cos, sin;
    /// Maps a point of the robot's frame to the map.
    Vec2 Point(const Vec2& p) const {
      return {x + cos * p.x() - sin * p.y(), y + sin * p.x() + cos * p.y()};
    }
    /// Rotates a direction of the robot's frame into the map.
    Vec2 Direction(const Vec2& d) const {
      return {cos * d.x() - sin * d.y(), sin * d.x() + cos * d.y()};
    }
  };

  /// The bounding box of the sample positions under a correction (min x, min y, max x, max y).
  std::array<double, 4> Extent(const Pose2& correction) const {
    std::array<double, 4> box{
        std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
        -std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
    for (size_t i = 0; i < nominal_.size(); ++i) {
      const double x = nominal_[i].x + fraction_[i] * correction.x,
                   y = nominal_[i].y + fraction_[i] * correction.y;
      box = {std::min(box[0], x), std::min(box[1], y), std::max(box[2], x), std::max(box[3], y)};
    }
    return box;
  }

  Frame SampleFrame(size_t i, const Pose2& correction) const {
    const double s = fraction_[i];
    const Pose2& n = nominal_[i];
    const double turn = s * correction.theta;
    if (std::abs(turn) > kSmallTurnRad) {
      const double theta = n.theta + turn;
      return {n.x + s * correction.x, n.y + s * correction.y, std::cos(theta), std::sin(theta)};
    }
    // The nominal heading's cosine and sine, turned by the correction's share: a candidate's
    // frames without a libm call each (they cost as much as casting the ray).
    const auto [c, sn] = SmallTurn(turn);
    return {n.x + s * correction.x, n.y + s * correction.y, cos_[i] * c - sin_[i] * sn,
            sin_[i] * c + cos_[i] * sn};
  }

 private:
  std::vector<Pose2> nominal_;
  std::vector<double> cos_, sin_;  // of the nominal headings
  std::vector<double> fraction_;
  Pose2 nominal_end_;
};

}  // namespace slam
