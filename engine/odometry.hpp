#pragma once
// Dead reckoning from the base's odometry events: translation from the mean of both treels'
// encoders, rotation from the gyroscope (paper section V-A).

#include <optional>

#include "engine/pose.hpp"
#include "engine/robot.hpp"

namespace slam {

class OdometryIntegrator {
 public:
  /// Readings further apart than this (the base sends 50 a second) are a gap: the rotation
  /// between them comes from the encoders instead of the gyro.
  static constexpr double kMaxGyroStepS = 0.25;

  explicit OdometryIntegrator(const BaseDescription& base) : base_(base) {}

  /// Integrates one reading (in time order) and returns the dead-reckoned pose at its time.
  /// The first reading only sets the reference. Encoder counters may wrap. Translation comes
  /// from the encoders, rotation from the gyro (from the encoders across a gap, or always for a
  /// robot without a gyro).
  Pose2 Add(const OdometryReading& reading);

  /// Whether `reading` (after the last one in time) moves each treel no further than the
  /// robot can (BaseDescription::max_speed_m_s) in the time since the last reading, counted
  /// at most kMaxJumpWindowS (a log's clock jump makes time up) plus kJumpSlackS (readings of
  /// one batch get times closer together than they were sent). True before any reading.
  bool Plausible(const OdometryReading& reading) const;
  static constexpr double kMaxJumpWindowS = 10.0;
  static constexpr double kJumpSlackS = 0.25;
  /// The furthest `base` drives between two readings `dt_s` apart: max_speed_m_s over `dt_s`,
  /// counted at most kMaxJumpWindowS, plus `slack_s`. A longer step is a jump (Plausible; a
  /// CARMEN log's odometry, whose records are stamped on arrival, with a slack of its own).
  static double MaxTravelM(const BaseDescription& base, double dt_s, double slack_s);

  /// Takes `reading` as the new reference without moving: the pose stays where it was. For a
  /// reading that is not Plausible (the counters restarted, or were corrupted): what happened
  /// since the last reading is unknown, and no motion is better than an impossible one.
  void Rebase(const OdometryReading& reading) { last_ = reading; }

  /// The pose after the last reading (the origin before any).
  const Pose2& pose() const { return pose_; }
  /// Time of the last reading, if any.
  std::optional<double> time() const {
    return last_ ? std::optional<double>(last_->t) : std::nullopt;
  }

 private:
  BaseDescription base_;
  std::optional<OdometryReading> last_;
  Pose2 pose_;
};

}  // namespace slam
