#pragma once
// Trajectory quality of paper section VI-A (eq. 6-9) and ATE RMSE.

#include <optional>
#include <vector>

#include "engine/pose.hpp"

namespace slam {

/// Rotation then translation: p -> R(rotation) p + translation.
struct RigidTransform2 {
  double rotation_rad = 0.0;
  Vec2 translation = Vec2::Zero();
  Vec2 Apply(const Vec2& p) const;
  /// The transform undoing this one.
  RigidTransform2 Inverse() const;
};

/// Every pose of `trajectory` moved by `transform` (positions and headings).
std::vector<TimedPose> TransformTrajectory(const RigidTransform2& transform,
                                           const std::vector<TimedPose>& trajectory);

/// The rigid transform minimising sum |A(source_i) - target_i|^2 (closed form, eq. 7).
/// Precondition: equal sizes, at least one point.
RigidTransform2 AlignRigid2D(const std::vector<Vec2>& source, const std::vector<Vec2>& target);

/// The pose of a time-ordered trajectory at time t (linear interpolation), nullopt outside it.
std::optional<Pose2> PoseAt(const std::vector<TimedPose>& trajectory, double t);

struct TrajectoryQuality {
  double q_cm2 = 0.0;         // eq. 8: minus the mean squared residual, positions in centimetres
  double e = 0.0;             // eq. 9: log(1 - q)
  double ate_rmse_m = 0.0;    // sqrt of the mean squared residual, metres
  int matched = 0;            // reference poses inside the estimate's time span
  RigidTransform2 alignment;  // maps the estimate onto the reference
};

/// Associates each reference pose with the estimate at the same time (interpolated), aligns,
/// and scores. nullopt when fewer than two reference poses fall within the estimate's span.
std::optional<TrajectoryQuality> EvaluateTrajectory(const std::vector<TimedPose>& estimate,
                                                    const std::vector<TimedPose>& reference);

/// The alignment the most of `estimate` agrees with, against `reference` (associated as
/// EvaluateTrajectory does): the least-squares fit, then fitted again on the poses it leaves
/// within max(floor_m, twice the median residual), until that set no longer changes (20 rounds
/// at most). The frame of the map a trajectory drew: one that was tracked off for a stretch (a
/// kidnap found late, then re-found where it was) drew the map in the frame of the rest, which
/// the least-squares fit of the whole misses by a share of the stretch's error. nullopt when
/// fewer than two reference poses fall within the estimate's span.
std::optional<RigidTransform2> AlignOnMajority(const std::vector<TimedPose>& estimate,
                                               const std::vector<TimedPose>& reference,
                                               double floor_m = 0.05);

/// A lower bound on the e (eq. 9) of every trajectory that begins with `prefix` (the same poses
/// up to its last, later poses after it), against `reference`: the later poses can only add
/// residuals, the final alignment fits the prefix's poses no better than their own best
/// alignment does, and the mean divides by every reference pose from the prefix's start on (the
/// most the final trajectory can match). 0 while fewer than two reference poses fall within it.
double ErrorLowerBound(const std::vector<TimedPose>& prefix,
                       const std::vector<TimedPose>& reference);

}  // namespace slam
