#pragma once
// Phase A's motion model (paper section V-A): the odometry's motion over a scan as rotation,
// translation, rotation, each with a Gaussian error that grows with its size.

#include "engine/params.hpp"
#include "engine/pose.hpp"
#include "engine/random.hpp"

namespace slam {

/// The motion between two odometry poses as rotation, translation, rotation. Backward motion is
/// a negative translation, so that reversing does not look like a half-turn.
struct MotionDelta {
  double rot1 = 0.0;
  double trans = 0.0;
  double rot2 = 0.0;
};

MotionDelta Decompose(const Pose2& delta);
/// The relative pose of a motion (Decompose's inverse).
Pose2 Recompose(const MotionDelta& m);

/// Standard deviations of a motion's three parts: the parameters' ratio of each part's size plus
/// their constant per scan.
struct MotionNoise {
  double trans = 0.0, rot1 = 0.0, rot2 = 0.0;
};
MotionNoise OdometryNoise(const SlamParams& params, const MotionDelta& motion);

/// The end pose of `motion` from `start`, each part perturbed by a draw of its noise from `rng`
/// (rotation, translation, rotation, in that order).
Pose2 SampleMotion(const Pose2& start, const MotionDelta& motion, const MotionNoise& noise,
                   Rng& rng);

}  // namespace slam
