#include "engine/motion_model.hpp"

#include <cmath>

namespace slam {

MotionDelta Decompose(const Pose2& delta) {
  MotionDelta m;
  m.trans = std::hypot(delta.x, delta.y);
  if (m.trans > 1e-9) {
    m.rot1 = std::atan2(delta.y, delta.x);
    if (std::abs(m.rot1) > kPi / 2) {
      m.rot1 = NormalizeAngle(m.rot1 - kPi);
      m.trans = -m.trans;
    }
  }
  m.rot2 = NormalizeAngle(delta.theta - m.rot1);
  return m;
}

Pose2 Recompose(const MotionDelta& m) {
  return {m.trans * std::cos(m.rot1), m.trans * std::sin(m.rot1), NormalizeAngle(m.rot1 + m.rot2)};
}

MotionNoise OdometryNoise(const SlamParams& params, const MotionDelta& motion) {
  const double angle_const = DegToRad(params.angle_error_const_deg);
  return {params.dist_error_ratio * std::abs(motion.trans) + params.dist_error_const_m,
          params.angle_error_ratio * std::abs(motion.rot1) + angle_const,
          params.angle_error_ratio * std::abs(motion.rot2) + angle_const};
}

Pose2 SampleMotion(const Pose2& start, const MotionDelta& motion, const MotionNoise& noise,
                   Rng& rng) {
  MotionDelta noisy = motion;
  noisy.rot1 += rng.Normal(noise.rot1);
  noisy.trans += rng.Normal(noise.trans);
  noisy.rot2 += rng.Normal(noise.rot2);
  return Compose(start, Recompose(noisy));
}

}  // namespace slam
