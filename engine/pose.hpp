#pragma once
// 2D rigid poses (REP-103: x forward, y left, theta counter-clockwise, SI units).

#include <Eigen/Core>
#include <cmath>

namespace slam {

using Vec2 = Eigen::Vector2d;

inline constexpr double kPi = 3.14159265358979323846;

/// Converts degrees to radians.
constexpr double DegToRad(double deg) { return deg * kPi / 180.0; }
/// Converts radians to degrees.
constexpr double RadToDeg(double rad) { return rad * 180.0 / kPi; }

/// Wraps an angle to (-pi, pi].
inline double NormalizeAngle(double a) {
  // Most angles are in range or one turn out: there, std::remainder's answers without its call
  // (a -+ 2 pi is exact for |a| in [pi, 4 pi], Sterbenz's lemma, as remainder's answer is; 8
  // keeps clear of 3 pi, where remainder rounds the quotient 1.5 to even; -2 pi gives -0).
  if (a > -kPi && a <= kPi) return a;
  if (a > kPi && a < 8.0) return a - 2.0 * kPi;
  if (a <= -kPi && a > -8.0) return -(-a - 2.0 * kPi);
  a = std::remainder(a, 2.0 * kPi);
  return a <= -kPi ? a + 2.0 * kPi : a;
}

/// A pose of the robot (or of a sensor) in the plane.
struct Pose2 {
  double x = 0.0;
  double y = 0.0;
  double theta = 0.0;

  Vec2 translation() const { return {x, y}; }
  /// Maps a point from this pose's frame to the parent frame.
  Vec2 Transform(const Vec2& p) const {
    const double c = std::cos(theta), s = std::sin(theta);
    return {x + c * p.x() - s * p.y(), y + s * p.x() + c * p.y()};
  }
};

/// a (+) b: b expressed in a's frame, returned in a's parent frame.
inline Pose2 Compose(const Pose2& a, const Pose2& b) {
  const Vec2 t = a.Transform(b.translation());
  return {t.x(), t.y(), NormalizeAngle(a.theta + b.theta)};
}

/// The inverse transform of p.
inline Pose2 Inverse(const Pose2& p) {
  const double c = std::cos(p.theta), s = std::sin(p.theta);
  return {-c * p.x - s * p.y, s * p.x - c * p.y, NormalizeAngle(-p.theta)};
}

/// The pose of b seen from a: Inverse(a) (+) b.
inline Pose2 Between(const Pose2& a, const Pose2& b) { return Compose(Inverse(a), b); }

/// Linear interpolation of poses (shortest way round for the angle), s in [0, 1].
inline Pose2 Interpolate(const Pose2& a, const Pose2& b, double s) {
  return {a.x + s * (b.x - a.x), a.y + s * (b.y - a.y),
          NormalizeAngle(a.theta + s * NormalizeAngle(b.theta - a.theta))};
}

/// A pose with a time stamp in seconds.
struct TimedPose {
  double t = 0.0;
  Pose2 pose;
};

}  // namespace slam
