#include "engine/odometry.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace slam {

namespace {

// Difference of two wrapping 32-bit counters.
int64_t CounterDelta(int32_t now, int32_t before) {
  return static_cast<int32_t>(static_cast<uint32_t>(now) - static_cast<uint32_t>(before));
}

}  // namespace

double OdometryIntegrator::MaxTravelM(const BaseDescription& base, double dt_s, double slack_s) {
  return base.max_speed_m_s * (std::clamp(dt_s, 0.0, kMaxJumpWindowS) + slack_s);
}

bool OdometryIntegrator::Plausible(const OdometryReading& reading) const {
  if (!last_) return true;
  const double max_ticks = MaxTravelM(base_, reading.t - last_->t, kJumpSlackS) * base_.ticks_per_m;
  const auto left = static_cast<double>(CounterDelta(reading.left_ticks, last_->left_ticks));
  const auto right = static_cast<double>(CounterDelta(reading.right_ticks, last_->right_ticks));
  return std::abs(left) <= max_ticks && std::abs(right) <= max_ticks;
}

Pose2 OdometryIntegrator::Add(const OdometryReading& reading) {
  if (last_) {
    const double dt = reading.t - last_->t;
    const double left = static_cast<double>(CounterDelta(reading.left_ticks, last_->left_ticks));
    const double right = static_cast<double>(CounterDelta(reading.right_ticks, last_->right_ticks));
    const double trans = 0.5 * (left + right) / base_.ticks_per_m;
    // Trapezoidal integration of the gyro's rate; out-of-order readings add no rotation. Across
    // a gap (lost readings, or a log's clock jump, whose length is made up) two rates say nothing
    // of the turn between them: the treels' ticks do, slip included. A robot without a gyro
    // (BaseDescription::heading_from_gyro) always turns by its encoders.
    double dtheta = 0.0;
    if (!base_.heading_from_gyro || dt > kMaxGyroStepS) {
      dtheta = (right - left) / base_.ticks_per_m / base_.track_width_m;
    } else if (dt > 0) {
      const double rate_dps = 0.5 * (reading.gyro_raw + last_->gyro_raw) * base_.gyro_unit_dps;
      dtheta = DegToRad(rate_dps) * dt;
    }
    const double mid = pose_.theta + 0.5 * dtheta;
    pose_ = {pose_.x + trans * std::cos(mid), pose_.y + trans * std::sin(mid),
             NormalizeAngle(pose_.theta + dtheta)};
  }
  last_ = reading;
  return pose_;
}

}  // namespace slam
