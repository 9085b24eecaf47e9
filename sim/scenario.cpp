#include "sim/scenario.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <memory>
#include <optional>
#include <utility>

#include "engine/odometry.hpp"
#include "engine/quality.hpp"
#include "engine/random.hpp"
#include "engine/scan_assembler.hpp"
#include "engine/sensor_model.hpp"

namespace slam::sim {
namespace {

// Independent random streams, so that changing one noise source leaves the others unchanged.
enum Stream : uint64_t {
  kStreamStart = 1,
  kStreamWander = 2,
  kStreamSlip = 3,
  kStreamGyro = 4,
  kStreamSensors = 5,
  kStreamTracker = 6,
  kStreamTicks = 7,
  kStreamRectifier = 8,
  kStreamSystematic = 9,  // the per-run scale errors
  kStreamTurnDrift = 10,
  kStreamPeople = 11,
};

constexpr double kControlDt = 0.01;       // the motion is a constant twist over each step
constexpr double kSafetyMarginM = 0.005;  // the robot's edge never gets closer than this
constexpr double kMaxAccel = 0.6;         // m/s^2
constexpr double kMaxAngularAccel = 8.0;  // rad/s^2
constexpr double kWanderSigma = 0.35;     // rad/s, gentle random turns while cruising
constexpr double kWanderCorrelationS = 2.0;
constexpr int kProximitySensors = 24;  // the base's infrared proximity ring
constexpr double kProximityRangeM = 0.15;
constexpr double kProximityNoiseM = 0.003;
constexpr double kStopGapM = 0.05;  // start turning when the free gap ahead is below this
constexpr double kGoGapM = 0.14;    // resume cruising when the gap ahead exceeds this
constexpr int kRawMax = 1023;
constexpr double kRectifierMv = 6500.0;  // the scanner's supply after its rectifier
constexpr double kRectifierNoiseMv = 15.0;
constexpr int64_t kFullTurnRaw = 65536;

/// A zero-mean Gauss-Markov process with stationary deviation `sigma` and correlation time `tau`.
class GaussMarkov {
 public:
  GaussMarkov(double sigma, double tau_s, double dt, Rng& rng)
      : sigma_(sigma), a_(std::exp(-dt / tau_s)), value_(rng.Gaussian(sigma)) {}
  double value() const { return value_; }
  void Step(Rng& rng) { value_ = a_ * value_ + rng.Gaussian(sigma_ * std::sqrt(1.0 - a_ * a_)); }

 private:
  double sigma_;
  double a_;
  double value_;
};

/// Pose after moving with constant speed v and turn rate w for dt (exact arc); theta unwrapped.
Pose2 Advance(const Pose2& p, double v, double w, double dt) {
  const double dtheta = w * dt;
  double dx = 0.0, dy = 0.0;
  if (std::abs(dtheta) < 1e-9) {
    dx = v * dt * std::cos(p.theta + dtheta / 2.0);
    dy = v * dt * std::sin(p.theta + dtheta / 2.0);
  } else {
    const double r = v / w;
    dx = r * (std::sin(p.theta + dtheta) - std::sin(p.theta));
    dy = -r * (std::cos(p.theta + dtheta) - std::cos(p.theta));
  }
  return {p.x + dx, p.y + dy, p.theta + dtheta};
}

/// Advance, plus a body-frame velocity (ex, ey) that the encoders do not see (skid, drift),
/// applied along the heading at mid-step.
Pose2 Move(const Pose2& p, double v, double w, const Vec2& extra, double dt) {
  Pose2 next = Advance(p, v, w, dt);
  if (extra.x() == 0.0 && extra.y() == 0.0) return next;
  const double mid = p.theta + w * dt / 2.0;
  next.x += (std::cos(mid) * extra.x() - std::sin(mid) * extra.y()) * dt;
  next.y += (std::sin(mid) * extra.x() + std::cos(mid) * extra.y()) * dt;
  return next;
}

Pose2 Normalized(Pose2 p) {
  p.theta = NormalizeAngle(p.theta);
  return p;
}

/// The world plus its bounds as walls: what the robot's body must stay clear of.
World MotionWorld(const World& world) {
  World out = world;
  const auto& b = world.bounds;
  const Vec2 p00(b[0], b[1]), p10(b[2], b[1]), p11(b[2], b[3]), p01(b[0], b[3]);
  out.segments.push_back({p00, p10});
  out.segments.push_back({p10, p11});
  out.segments.push_back({p11, p01});
  out.segments.push_back({p01, p00});
  return out;
}

/// The 24 infrared proximity sensors around the base: distance from the body's edge to the
/// first obstacle along each sensor's direction (every 15 degrees, the first straight ahead),
/// capped at their range, with a little noise.
std::array<double, kProximitySensors> Proximity(const World& world, const Pose2& pose,
                                                double radius, Rng& rng) {
  std::array<double, kProximitySensors> out{};
  for (int i = 0; i < kProximitySensors; ++i) {
    const double angle = pose.theta + 2.0 * kPi * i / kProximitySensors;
    const Vec2 from = pose.translation() + radius * Vec2(std::cos(angle), std::sin(angle));
    const double d = RayDistance(world, from, angle, kProximityRangeM).value_or(kProximityRangeM);
    out[static_cast<size_t>(i)] =
        std::clamp(d + rng.Gaussian(kProximityNoiseM), 0.0, kProximityRangeM);
  }
  return out;
}

/// The obstacle-avoiding wander behaviour, driven by the proximity sensors only: cruise with
/// gentle random turns, steer away from obstacles at the sides, turn in place away from
/// obstacles ahead. Produces the commanded twist for each control step.
class Wanderer {
 public:
  Wanderer(const ScenarioConfig& config, Rng rng)
      : config_(config), rng_(rng), wander_(kWanderSigma, kWanderCorrelationS, kControlDt, rng_) {}

  /// The twist (v, w) to apply over the next control step from `pose`.
  std::pair<double, double> Command(const World& world, const Pose2& pose) {
    wander_.Step(rng_);
    mode_time_ += kControlDt;
    const auto prox = Proximity(world, pose, config_.robot_radius_m, rng_);
    // Sensors 22, 23, 0, 1, 2 look ahead (within 30 degrees); 3..6 left, 18..21 right.
    const double ahead = std::min({prox[22], prox[23], prox[0], prox[1], prox[2]});
    const double left = std::min({prox[3], prox[4], prox[5], prox[6]});
    const double right = std::min({prox[18], prox[19], prox[20], prox[21]});
    if (!turning_ && ahead < kStopGapM) StartTurn(left, right);
    if (turning_ && mode_time_ >= turn_min_s_ && ahead > kGoGapM) {
      turning_ = false;
      mode_time_ = 0.0;
    }
    double target_v = 0.0, target_w = 0.0;
    if (turning_) {
      target_w = turn_dir_ * config_.turn_rate_rad_s;
    } else {
      target_v =
          config_.speed_m_s * std::clamp((ahead - kStopGapM) / (kGoGapM - kStopGapM), 0.3, 1.0);
      target_w = wander_.value() + std::clamp(8.0 * (left - right), -0.8, 0.8);
    }
    v_ += std::clamp(target_v - v_, -kMaxAccel * kControlDt, kMaxAccel * kControlDt);
    w_ += std::clamp(target_w - w_, -kMaxAngularAccel * kControlDt, kMaxAngularAccel * kControlDt);
    return {v_, w_};
  }

  /// The robot bumped into the safety limit: stop translating and turn away.
  void Blocked(const World& world, const Pose2& pose) {
    v_ = 0.0;
    if (!turning_) {
      const auto prox = Proximity(world, pose, config_.robot_radius_m, rng_);
      StartTurn(prox[3] + prox[4] + prox[5], prox[19] + prox[20] + prox[21]);
    }
  }

 private:
  void StartTurn(double left, double right) {
    turning_ = true;
    mode_time_ = 0.0;
    turn_dir_ = std::abs(left - right) > 0.01 ? (left > right ? 1.0 : -1.0)
                                              : (rng_.Uniform() < 0.5 ? 1.0 : -1.0);
    turn_min_s_ = 0.3 + 1.2 * rng_.Uniform();
  }

  ScenarioConfig config_;
  Rng rng_;
  GaussMarkov wander_;
  bool turning_ = false;
  double turn_dir_ = 1.0;
  double turn_min_s_ = 0.0;
  double mode_time_ = 0.0;
  double v_ = 0.0;
  double w_ = 0.0;
};

/// A random start pose well clear of obstacles (the clearest of many tries if none is).
Pose2 StartPose(const World& motion_world, const ScenarioConfig& config, Rng rng) {
  const auto& b = motion_world.bounds;
  const double wanted = config.robot_radius_m + 0.15;
  Pose2 best;
  double best_clearance = -1.0;
  for (int i = 0; i < 10000 && best_clearance < wanted; ++i) {
    const Pose2 p{b[0] + (b[2] - b[0]) * rng.Uniform(), b[1] + (b[3] - b[1]) * rng.Uniform(),
                  NormalizeAngle(2.0 * kPi * rng.Uniform())};
    const double c = ClearanceAt(motion_world, p.translation());
    if (c > best_clearance) {
      best = p;
      best_clearance = c;
    }
  }
  return best;
}

int32_t WrapTicks(int64_t ticks) {
  return static_cast<int32_t>(static_cast<uint32_t>(static_cast<uint64_t>(ticks)));
}

uint16_t ClampRaw(double raw) {
  return static_cast<uint16_t>(std::clamp(std::lround(raw), 0L, long{kRawMax}));
}

/// Simulates the raw value of one Sharp sensor whose beam starts at `origin` along `angle`.
uint16_t SenseRaw(const World& world, const std::vector<Vec2>& corners,
                  const SensorTypeDescription& type, const ScenarioConfig& config,
                  const Vec2& origin, double angle, Rng& rng) {
  const auto& table = type.calibration;
  const auto floor_raw = [&] {
    return ClampRaw(table.back().raw - config.floor_offset_raw +
                    rng.Gaussian(config.floor_noise_raw));
  };
  // The sensor responds where it is calibrated; beyond, its output sits near the floor.
  const double calibrated_min = table.front().distance_m;
  const double calibrated_max = table.back().distance_m;
  const std::optional<double> d = RayDistance(world, origin, angle, calibrated_max);
  if (!d) return floor_raw();
  const Vec2 hit = origin + *d * Vec2(std::cos(angle), std::sin(angle));
  const bool near_corner = std::any_of(corners.begin(), corners.end(), [&](const Vec2& c) {
    return (c - hit).norm() <= config.corner_radius_m;
  });
  // Draw the corner coin for every beam so that the stream does not depend on the geometry.
  const bool hole = rng.Uniform() < config.corner_hole_probability;
  const double noise = rng.Gaussian();
  if (near_corner && hole) return floor_raw();
  if (*d < calibrated_min) {
    // Non-injective zone: the output falls again as the obstacle gets closer, reading far.
    const double f = config.near_floor_fraction;
    const double raw = table.front().raw * (f + (1.0 - f) * *d / calibrated_min);
    return ClampRaw(raw + config.floor_noise_raw * noise);
  }
  const double sigma = type.sigma_m[0] + type.sigma_m[1] * *d + type.sigma_m[2] * *d * *d;
  const double measured = *d + config.sensor_noise_scale * sigma * noise;
  return ClampRaw(CalibratedRaw(table, std::max(measured, 0.0)));
}

/// Simulates one sweep of a range scanner on a robot at `pose`: each beam reads the distance to
/// the first surface plus Gaussian noise of the type's sigma; no echo (the type's no-return
/// value) beyond its range, and, as for the Sharp sensors, sometimes near a corner.
LaserSweep SenseSweep(const World& world, const std::vector<Vec2>& corners,
                      const RobotDescription& robot, const SensorTypeDescription& type,
                      const ScenarioConfig& config, const Pose2& pose, double t, Rng& rng) {
  const ScannerSensor& sensor = robot.scanner.sensors.front();
  const Vec2 origin = pose.Transform({robot.scanner.offset_x_m, robot.scanner.offset_y_m});
  LaserSweep sweep;
  sweep.t = t;
  sweep.ranges.resize(static_cast<size_t>(type.beams.count));
  const auto no_echo = static_cast<float>(type.no_return_m);
  for (int b = 0; b < type.beams.count; ++b) {
    const double angle = pose.theta + DegToRad(sensor.angle_deg + type.beams.AngleDeg(b));
    const std::optional<double> d = RayDistance(world, origin, angle, type.range_max_m);
    // Draw every beam's coins so that the stream does not depend on the geometry.
    const bool hole = rng.Uniform() < config.corner_hole_probability;
    const double noise = rng.Gaussian();
    float& range = sweep.ranges[static_cast<size_t>(b)];
    if (!d) {
      range = no_echo;
      continue;
    }
    const Vec2 hit = origin + *d * Vec2(std::cos(angle), std::sin(angle));
    const bool near_corner = std::any_of(corners.begin(), corners.end(), [&](const Vec2& c) {
      return (c - hit).norm() <= config.corner_radius_m;
    });
    if (near_corner && hole) {
      range = no_echo;
      continue;
    }
    const double sigma = type.sigma_m[0] + type.sigma_m[1] * *d + type.sigma_m[2] * *d * *d;
    range = static_cast<float>(std::max(0.0, *d + config.sensor_noise_scale * sigma * noise));
  }
  return sweep;
}

// People (ScenarioConfig::people): legs of kLegRadiusM, kLegSpreadM apart across the walking
// direction; a walker keeps kWalkerClearanceM from walls and kWalkerRobotM from the robot,
// and wanders by kWalkerTurnSigma (rad per square root of a second).
constexpr int kMaxPeople = 50;
constexpr double kLegRadiusM = 0.06;
constexpr double kLegSpreadM = 0.25;
constexpr double kWalkerClearanceM = 0.3;
constexpr double kWalkerRobotM = 0.5;
constexpr double kWalkerTurnSigma = 0.5;

struct Walker {
  Vec2 at = Vec2::Zero();
  double heading = 0.0;
};

/// A walker somewhere the robot at `start` sees in a straight line, at least a metre away and
/// clear of walls (nullopt when the robot stands where no such place is found).
std::optional<Walker> PlaceWalker(const World& world, const Vec2& start, Rng& rng) {
  for (int i = 0; i < 1000; ++i) {
    const double angle = 2.0 * kPi * rng.Uniform();
    const std::optional<double> free = RayDistance(world, start, angle, 20.0);
    const double along = rng.Uniform(), heading = 2.0 * kPi * rng.Uniform();
    if (!free || *free < 1.0 + kWalkerClearanceM) continue;  // none within 20 m: open edge
    const double distance = 1.0 + (*free - 1.0 - kWalkerClearanceM) * along;
    const Vec2 at = start + distance * Vec2(std::cos(angle), std::sin(angle));
    if (ClearanceAt(world, at) >= kWalkerClearanceM) return Walker{at, heading};
  }
  return std::nullopt;
}

/// One control step of a walker: on along its heading, or, where that would take it too close to
/// a wall or towards the robot within kWalkerRobotM, standing while it turns to a heading that
/// does not (a walker the robot came up to walks away from it).
void Walk(const World& world, const Vec2& robot, double speed, Walker& walker, Rng& rng) {
  walker.heading += rng.Gaussian(kWalkerTurnSigma * std::sqrt(kControlDt));
  const auto open = [&](const Vec2& to) {
    const double near = (to - robot).norm();
    return ClearanceAt(world, to) >= kWalkerClearanceM &&
           (near >= kWalkerRobotM || near > (walker.at - robot).norm());
  };
  const auto step = [&](double heading, double length) -> Vec2 {
    return walker.at + length * Vec2(std::cos(heading), std::sin(heading));
  };
  if (open(step(walker.heading, speed * kControlDt))) {
    walker.at = step(walker.heading, speed * kControlDt);
    return;
  }
  for (int i = 0; i < 16; ++i) {
    const double heading = 2.0 * kPi * rng.Uniform();
    if (open(step(heading, 0.5))) {
      walker.heading = heading;
      return;
    }
  }
}

/// The walkers' legs, as the circles after the world's own in `sensed`.
void PlaceLegs(const std::vector<Walker>& walkers, size_t first, World& sensed) {
  sensed.circles.resize(first + 2 * walkers.size());
  for (size_t i = 0; i < walkers.size(); ++i) {
    const Vec2 side =
        0.5 * kLegSpreadM * Vec2(-std::sin(walkers[i].heading), std::cos(walkers[i].heading));
    sensed.circles[first + 2 * i] = {walkers[i].at + side, kLegRadiusM};
    sensed.circles[first + 2 * i + 1] = {walkers[i].at - side, kLegRadiusM};
  }
}

}  // namespace

std::vector<std::string> ScenarioConfig::Validate() const {
  std::vector<std::string> errors;
  const auto positive = [&](double v, const char* key) {
    if (!(v > 0.0) || !std::isfinite(v)) errors.push_back(std::string("/") + key + ": must be > 0");
  };
  const auto non_negative = [&](double v, const char* key) {
    if (!(v >= 0.0) || !std::isfinite(v)) {
      errors.push_back(std::string("/") + key + ": must be >= 0");
    }
  };
  positive(duration_s, "duration_s");
  positive(scans_per_s, "scans_per_s");
  positive(odometry_rate_hz, "odometry_rate_hz");
  positive(tracker_rate_hz, "tracker_rate_hz");
  positive(speed_m_s, "speed_m_s");
  positive(turn_rate_rad_s, "turn_rate_rad_s");
  positive(robot_radius_m, "robot_radius_m");
  non_negative(odometry.translation_slip_ratio, "odometry/translation_slip_ratio");
  non_negative(odometry.rotation_slip_ratio, "odometry/rotation_slip_ratio");
  positive(odometry.slip_correlation_s, "odometry/slip_correlation_s");
  non_negative(odometry.accel_slip_s, "odometry/accel_slip_s");
  non_negative(odometry.gyro_noise_dps, "odometry/gyro_noise_dps");
  non_negative(odometry.gyro_bias_dps, "odometry/gyro_bias_dps");
  positive(odometry.gyro_bias_walk_s, "odometry/gyro_bias_walk_s");
  non_negative(odometry.translation_scale_sigma, "odometry/translation_scale_sigma");
  non_negative(odometry.gyro_scale_sigma, "odometry/gyro_scale_sigma");
  non_negative(odometry.wheel_diameter_sigma, "odometry/wheel_diameter_sigma");
  non_negative(odometry.track_scale_sigma, "odometry/track_scale_sigma");
  non_negative(odometry.skid_s, "odometry/skid_s");
  non_negative(odometry.turn_drift_m_per_rad, "odometry/turn_drift_m_per_rad");
  non_negative(sensor_noise_scale, "sensor_noise_scale");
  non_negative(corner_radius_m, "corner_radius_m");
  non_negative(floor_offset_raw, "floor_offset_raw");
  non_negative(floor_noise_raw, "floor_noise_raw");
  non_negative(tracker_noise_m, "tracker_noise_m");
  non_negative(tracker_noise_rad, "tracker_noise_rad");
  if (people < 0 || people > kMaxPeople) {
    errors.push_back("/people: must be in [0, " + std::to_string(kMaxPeople) + "]");
  }
  positive(person_speed_m_s, "person_speed_m_s");
  if (!(corner_hole_probability >= 0.0 && corner_hole_probability <= 1.0)) {
    errors.push_back("/corner_hole_probability: must be in [0, 1]");
  }
  if (!(near_floor_fraction >= 0.0 && near_floor_fraction <= 1.0)) {
    errors.push_back("/near_floor_fraction: must be in [0, 1]");
  }
  if (kidnap_t_s && !(*kidnap_t_s > 0.0 && *kidnap_t_s < duration_s)) {
    errors.push_back("/kidnap_t_s: must be in (0, duration_s)");
  }
  if (kidnap_to) {
    if (!std::isfinite(kidnap_to->x) || !std::isfinite(kidnap_to->y) ||
        !std::isfinite(kidnap_to->theta)) {
      errors.push_back("/kidnap_to: must be finite");
    }
    if (!kidnap_t_s) errors.push_back("/kidnap_to: needs kidnap_t_s");
  }
  return errors;
}

Result<void> CheckFreePose(const World& world, double robot_radius_m, const Pose2& pose) {
  if (!std::isfinite(pose.x) || !std::isfinite(pose.y) || !std::isfinite(pose.theta)) {
    return Error("the pose is not finite");
  }
  const auto& b = world.bounds;
  if (!(pose.x >= b[0] && pose.x <= b[2] && pose.y >= b[1] && pose.y <= b[3])) {
    return Error("the pose is outside the world's bounds");
  }
  if (!(ClearanceAt(MotionWorld(world), pose.translation()) >= robot_radius_m)) {
    return Error("the robot's disc overlaps a wall, a circle or the edge of the world's bounds");
  }
  return {};
}

std::optional<OdometryProfile> OdometryProfileFromName(std::string_view name) {
  if (name == "gentle") return OdometryProfile::kGentle;
  if (name == "tracked") return OdometryProfile::kTracked;
  return std::nullopt;
}

std::string_view OdometryProfileName(OdometryProfile profile) {
  return profile == OdometryProfile::kTracked ? "tracked" : "gentle";
}

ScenarioConfig WithOdometryProfile(ScenarioConfig config, OdometryProfile profile) {
  config.odometry = OdometryErrors{};  // the gentle profile
  config.odometry.profile = OdometryProfileName(profile);
  if (profile == OdometryProfile::kTracked) {
    // Chosen so that dead reckoning drifts as the outside experiments and the paper's
    // Fig. 9 show for tracked robots (tens of centimetres to over a metre in 300 s), with
    // values plausible for a consumer MEMS gyro calibrated at rest; not fitted to a recording.
    OdometryErrors& e = config.odometry;
    e.gyro_noise_dps = 0.5;
    e.gyro_bias_dps = 0.25;
    e.gyro_bias_walk_s = 120.0;
    e.translation_scale_sigma = 0.03;
    e.gyro_scale_sigma = 0.02;
    // An uncalibrated differential drive: a 1 % difference of the wheels turns a robot with a
    // 33 cm track by 1.7 degrees a metre (UMBmark's vehicles measured tenths of a percent to
    // percents before calibration).
    e.wheel_diameter_sigma = 0.01;
    e.track_scale_sigma = 0.03;
    e.skid_s = 0.08;
    e.turn_drift_m_per_rad = 0.02;
  }
  return config;
}

/// Everything the simulation carries from one control step to the next.
struct Simulator::State {
  State(const World& world_in, const RobotDescription& r, const ScenarioConfig& c)
      : world(world_in),
        robot(r),
        config(c),
        motion_world(MotionWorld(world_in)),
        corners(Corners(world_in)),
        slip_rng(Rng::ForStream(c.seed, kStreamSlip)),
        gyro_rng(Rng::ForStream(c.seed, kStreamGyro)),
        sensor_rng(Rng::ForStream(c.seed, kStreamSensors)),
        tracker_rng(Rng::ForStream(c.seed, kStreamTracker)),
        ticks_rng(Rng::ForStream(c.seed, kStreamTicks)),
        rectifier_rng(Rng::ForStream(c.seed, kStreamRectifier)),
        drift_rng(Rng::ForStream(c.seed, kStreamTurnDrift)),
        wanderer(c, Rng::ForStream(c.seed, kStreamWander)),
        slip_t(c.odometry.translation_slip_ratio, c.odometry.slip_correlation_s, kControlDt,
               slip_rng),
        slip_turn(c.odometry.translation_slip_ratio, c.odometry.slip_correlation_s, kControlDt,
                  slip_rng),
        slip_r(c.odometry.rotation_slip_ratio, c.odometry.slip_correlation_s, kControlDt, slip_rng),
        drift_x(1.0, 1.0, kControlDt, drift_rng),
        drift_y(1.0, 1.0, kControlDt, drift_rng),
        bias(gyro_rng.Gaussian(DegToRad(c.odometry.gyro_bias_dps))),
        bias_step(DegToRad(c.odometry.gyro_bias_dps) *
                  std::sqrt(kControlDt / c.odometry.gyro_bias_walk_s)),
        left_offset(static_cast<int32_t>(static_cast<uint32_t>(ticks_rng.Next()))),
        right_offset(static_cast<int32_t>(static_cast<uint32_t>(ticks_rng.Next()))),
        pose(StartPose(motion_world, c, Rng::ForStream(c.seed, kStreamStart))),
        last_gyro_theta(pose.theta),
        people_rng(Rng::ForStream(c.seed, kStreamPeople)),
        sensed(world_in) {
    for (int i = 0; i < c.people; ++i) {
      const std::optional<Walker> placed = PlaceWalker(world, pose.translation(), people_rng);
      if (placed) walkers.push_back(*placed);
    }
    PlaceLegs(walkers, world.circles.size(), sensed);
    Rng systematic = Rng::ForStream(c.seed, kStreamSystematic);
    translation_scale = systematic.Gaussian(c.odometry.translation_scale_sigma);
    gyro_scale = systematic.Gaussian(c.odometry.gyro_scale_sigma);
    wheel_difference = systematic.Gaussian(c.odometry.wheel_diameter_sigma);
    track_scale = systematic.Gaussian(c.odometry.track_scale_sigma);
    if (r.base.heading_from_gyro) {
      // Its dead reckoning reads the encoders for distance only, which these errors leave as it
      // is to first order; left out, its datasets stay what they were before they were modelled.
      wheel_difference = track_scale = 0.0;
    }
  }

  /// One control step's motion: from `start` at t0 to `next` at t1 under the twist (v, w) and
  /// the untracked `extra` motion, and the rates the encoders report for it.
  struct Motion {
    double t0 = 0.0, t1 = 0.0;
    Pose2 start, next;
    double v = 0.0, w = 0.0;
    Vec2 extra = Vec2::Zero();
    double left_rate = 0.0, right_rate = 0.0;
    Pose2 At(double t) const { return Move(start, v, w, extra, t - t0); }
    /// Whether reading n of a stream at `rate` falls in this step.
    bool InStep(int64_t n, double rate) const { return static_cast<double>(n) / rate < t1; }
  };

  /// The people walk, the robot drives its wandering command (stopping short of obstacles),
  /// and the odometry's errors take their next values.
  Motion Drive() {
    const double min_clearance = config.robot_radius_m + kSafetyMarginM;
    const double half_track = robot.base.track_width_m / 2.0;
    Motion m;
    m.t0 = static_cast<double>(step) * kControlDt;
    m.t1 = static_cast<double>(step + 1) * kControlDt;
    m.start = pose;

    if (!walkers.empty()) {
      for (Walker& walker : walkers) {
        Walk(world, pose.translation(), config.person_speed_m_s, walker, people_rng);
      }
      PlaceLegs(walkers, world.circles.size(), sensed);
    }

    const std::pair<double, double> command = wanderer.Command(motion_world, pose);
    m.v = command.first;
    m.w = command.second;
    const double turn = m.w;
    const FloorTraction floor = TractionOf(FloorAt(world, pose.translation()));
    // What the treels do not report: sideways skid in turns (outwards) and the wandering centre
    // of rotation.
    const auto extra_motion = [&](double forward) -> Vec2 {
      if (config.odometry.skid_s == 0.0 && config.odometry.turn_drift_m_per_rad == 0.0)
        return Vec2::Zero();
      const double drift = config.odometry.turn_drift_m_per_rad * std::abs(turn);
      return {
          drift * drift_x.value(),
          -config.odometry.skid_s * floor.skid_factor * forward * turn + drift * drift_y.value()};
    };
    if (config.odometry.turn_drift_m_per_rad > 0.0) {
      drift_x.Step(drift_rng);
      drift_y.Step(drift_rng);
    }
    m.extra = extra_motion(m.v);
    m.next = Move(pose, m.v, turn, m.extra, kControlDt);
    const double clearance_now = ClearanceAt(motion_world, pose.translation());
    const double clearance_next = ClearanceAt(motion_world, m.next.translation());
    if (clearance_next < min_clearance && clearance_next < clearance_now) {
      wanderer.Blocked(motion_world, pose);
      m.v = 0.0;
      m.extra = extra_motion(m.v);
      m.next = Move(pose, m.v, turn, m.extra, kControlDt);
      const double clearance_still = ClearanceAt(motion_world, m.next.translation());
      if (clearance_still < min_clearance && clearance_still < clearance_now) {
        m.extra = Vec2::Zero();  // pressed against the obstacle: it stops the drift
        m.next = Move(pose, m.v, turn, m.extra, kControlDt);
      }
    }
    const double speed = m.v;
    slip_t.Step(slip_rng);
    slip_turn.Step(slip_rng);
    slip_r.Step(slip_rng);
    bias += gyro_rng.Gaussian(bias_step);
    // What the encoders see. Treels slip more when turning (the translation slip grows with the
    // turn rate, and they skid sideways, adding spurious translation) and when accelerating or
    // braking (they spin or drag: the encoders run ahead of the motion by accel_slip_s x a).
    const double accel = (speed - v) / kControlDt;
    const double angular_accel = (turn - w) / kControlDt;
    v = speed;
    w = turn;
    // A run's scale error and the floor's bias are systematic: the encoders read that much more
    // than the true distance, turn after turn.
    const double scale = 1.0 + (translation_scale + floor.scale_bias);
    const double v_enc =
        speed * (scale + slip_t.value() * (1.0 + std::abs(turn)) * floor.slip_factor) +
        slip_turn.value() * std::abs(turn) * half_track * floor.slip_factor +
        config.odometry.accel_slip_s * accel;
    // The right wheel larger by wheel_difference: per revolution it rolls farther than the
    // encoders count, the left one less, so they see the robot turn clockwise as it drives.
    const double w_enc = turn * (1.0 + track_scale + slip_r.value() * floor.slip_factor) -
                         speed * wheel_difference / robot.base.track_width_m +
                         config.odometry.accel_slip_s * angular_accel;
    m.left_rate = v_enc - w_enc * half_track;
    m.right_rate = v_enc + w_enc * half_track;
    return m;
  }

  /// The odometry readings of the step: encoder ticks and the gyro's mean rate since the
  /// previous reading (plus bias and noise).
  void EmitOdometry(const Motion& m, ScenarioOutput& out) {
    while (m.InStep(next_odometry, config.odometry_rate_hz)) {
      const double t = static_cast<double>(next_odometry) / config.odometry_rate_hz;
      const Pose2 p = m.At(t);
      const double rate =
          next_odometry == 0 ? m.w : (p.theta - last_gyro_theta) / (t - last_gyro_t);
      const double measured = rate * (1.0 + gyro_scale) + bias +
                              gyro_rng.Gaussian(DegToRad(config.odometry.gyro_noise_dps));
      const double gyro_units = RadToDeg(measured) / robot.base.gyro_unit_dps;
      OdometryReading r;
      r.t = t;
      r.seq = static_cast<uint16_t>(next_odometry & 0xFFFF);
      r.left_ticks = WrapTicks(
          left_offset + std::llround((left_m + m.left_rate * (t - m.t0)) * robot.base.ticks_per_m));
      r.right_ticks = WrapTicks(right_offset + std::llround((right_m + m.right_rate * (t - m.t0)) *
                                                            robot.base.ticks_per_m));
      r.gyro_raw = static_cast<int16_t>(std::clamp(std::lround(gyro_units), -32768L, 32767L));
      out.odometry.push_back(r);
      last_gyro_t = t;
      last_gyro_theta = p.theta;
      ++next_odometry;
    }
  }

  /// The scanner's readings of the step: a laser's whole sweeps at the scan rate (every beam from
  /// the pose at the sweep's time), or the infrared sensors' samples on the turning platform.
  void EmitScanner(const Motion& m, ScenarioOutput& out) {
    const SensorTypeDescription& first_type =
        robot.sensor_types.at(robot.scanner.sensors.front().type);
    if (first_type.kind == SensorKind::kRange) {
      while (m.InStep(next_sample, config.scans_per_s)) {
        const double t = static_cast<double>(next_sample) / config.scans_per_s;
        const Pose2 p = m.At(t);
        out.sweeps.push_back(
            SenseSweep(sensed, corners, robot, first_type, config, p, t, sensor_rng));
        out.true_path.push_back({t, Normalized(p)});
        ++next_sample;
      }
    }
    const double sample_rate = robot.scanner.sample_rate_hz;
    while (first_type.kind == SensorKind::kInfrared && m.InStep(next_sample, sample_rate)) {
      const double t = static_cast<double>(next_sample) / sample_rate;
      const Pose2 p = m.At(t);
      const double platform = kPi * config.scans_per_s * t;
      ScannerReading r;
      r.t = t;
      r.seq = static_cast<uint16_t>(next_sample & 0xFFFF);
      const int64_t angle_raw = std::llround(platform / (2.0 * kPi) * kFullTurnRaw);
      r.angle_raw = static_cast<uint16_t>(angle_raw & (kFullTurnRaw - 1));
      for (size_t s = 0; s < robot.scanner.sensors.size() && s < kScannerSensors; ++s) {
        const ScannerSensor& sensor = robot.scanner.sensors[s];
        const double angle = p.theta + platform + DegToRad(sensor.angle_deg);
        const Vec2 origin =
            p.translation() + robot.scanner.mount_radius_m * Vec2(std::cos(angle), std::sin(angle));
        r.raw[s] = SenseRaw(sensed, corners, robot.sensor_types.at(sensor.type), config, origin,
                            angle, sensor_rng);
      }
      r.rectifier_mv = static_cast<uint16_t>(
          std::lround(kRectifierMv + rectifier_rng.Gaussian(kRectifierNoiseMv)));
      out.scanner.push_back(r);
      out.true_path.push_back({t, Normalized(p)});
      ++next_sample;
    }
  }

  /// The kidnapping due at the start of this step, if any: a request (Simulator::Kidnap), else
  /// the config's once its time has come (a request in that step takes its place).
  std::optional<Pose2> DueKidnap() {
    std::optional<Pose2> due;
    std::swap(due, requested_kidnap);
    if (config.kidnap_t_s && !config_kidnap_done &&
        static_cast<double>(step) * kControlDt >= *config.kidnap_t_s - 1e-9) {
      config_kidnap_done = true;
      if (!due) {
        if (config.kidnap_to) {
          if (CheckFreePose(world, config.robot_radius_m, *config.kidnap_to).ok())
            due = config.kidnap_to;
        } else {
          due = half_kidnap_pose;
        }
      }
    }
    return due;
  }

  /// Sets the robot down at `target` before the step: the true pose jumps, and the heading the
  /// gyro last saw turns with it, so that its next rate is the robot's own; the encoders' counts
  /// and the commanded twist are untouched (the wanderer reacts to what its proximity sensors
  /// see from the new pose, and Drive keeps it clear of obstacles there).
  void SetDown(const Pose2& target, ScenarioOutput& out) {
    const Pose2 from = Normalized(pose);
    const double turn = NormalizeAngle(target.theta - pose.theta);
    pose = {target.x, target.y, pose.theta + turn};
    last_gyro_theta += turn;
    out.kidnaps.push_back({static_cast<double>(step) * kControlDt, from, Normalized(target)});
  }

  /// Remembers the true pose at half the config's kidnapping time, the default target.
  void NoteHalfKidnapPose(const Motion& m) {
    if (!config.kidnap_t_s || config.kidnap_to || half_kidnap_pose) return;
    const double half = *config.kidnap_t_s / 2.0;
    if (m.t1 > half) half_kidnap_pose = Normalized(m.At(std::max(half, m.t0)));
  }

  /// The overhead tracker's noisy poses of the step (the ground truth).
  void EmitTracker(const Motion& m, ScenarioOutput& out) {
    while (m.InStep(next_tracker, config.tracker_rate_hz)) {
      const double t = static_cast<double>(next_tracker) / config.tracker_rate_hz;
      Pose2 p = Normalized(m.At(t));
      p.x += tracker_rng.Gaussian(config.tracker_noise_m);
      p.y += tracker_rng.Gaussian(config.tracker_noise_m);
      p.theta = NormalizeAngle(p.theta + tracker_rng.Gaussian(config.tracker_noise_rad));
      out.ground_truth.push_back({t, p});
      ++next_tracker;
    }
  }

  World world;
  RobotDescription robot;
  ScenarioConfig config;
  World motion_world;
  std::vector<Vec2> corners;
  Rng slip_rng, gyro_rng, sensor_rng, tracker_rng, ticks_rng, rectifier_rng, drift_rng;
  Wanderer wanderer;
  GaussMarkov slip_t, slip_turn, slip_r;
  GaussMarkov drift_x, drift_y;                      // direction of the turning drift (body frame)
  double translation_scale = 0.0, gyro_scale = 0.0;  // this run's systematic errors
  double wheel_difference = 0.0, track_scale = 0.0;
  double bias;
  double bias_step;
  int64_t left_offset, right_offset;
  Pose2 pose;                          // at the start of the current control step (theta unwrapped)
  double v = 0.0, w = 0.0;             // the previous step's twist, for the accelerations
  double left_m = 0.0, right_m = 0.0;  // distances the encoders report
  int64_t step = 0;
  int64_t next_odometry = 0, next_sample = 0, next_tracker = 0;
  double last_gyro_t = 0.0;
  double last_gyro_theta;
  Rng people_rng;
  std::vector<Walker> walkers;
  World sensed;  // the world with the walkers' legs, as the sensors see it

  std::optional<Pose2> requested_kidnap;  // Simulator::Kidnap, for the next step
  bool config_kidnap_done = false;        // config.kidnap_t_s has come
  std::optional<Pose2> half_kidnap_pose;  // the true pose at config.kidnap_t_s / 2
};

Simulator::Simulator(const World& world, const RobotDescription& robot,
                     const ScenarioConfig& config)
    : state_(std::make_unique<State>(world, robot, config)) {}

Simulator::~Simulator() = default;
Simulator::Simulator(Simulator&&) noexcept = default;
Simulator& Simulator::operator=(Simulator&&) noexcept = default;

double Simulator::time() const { return static_cast<double>(state_->step) * kControlDt; }

Pose2 Simulator::pose() const { return Normalized(state_->pose); }

Result<void> Simulator::Kidnap(const Pose2& target) {
  if (Result<void> free = CheckFreePose(state_->world, state_->config.robot_radius_m, target);
      !free.ok()) {
    return free;
  }
  state_->requested_kidnap = target;
  return {};
}

void Simulator::Step(ScenarioOutput& out) {
  State& st = *state_;
  if (const std::optional<Pose2> kidnap = st.DueKidnap()) st.SetDown(*kidnap, out);
  const State::Motion motion = st.Drive();
  st.NoteHalfKidnapPose(motion);
  st.EmitOdometry(motion, out);
  st.EmitScanner(motion, out);
  st.EmitTracker(motion, out);
  st.pose = motion.next;
  st.left_m += motion.left_rate * kControlDt;
  st.right_m += motion.right_rate * kControlDt;
  ++st.step;
}

ScenarioOutput RunScenario(const World& world, const RobotDescription& robot,
                           const ScenarioConfig& config) {
  Simulator simulator(world, robot, config);
  ScenarioOutput out;
  while (simulator.time() <= config.duration_s + 1e-9) simulator.Step(out);
  const auto after_end = [&](const auto& reading) { return reading.t > config.duration_s + 1e-9; };
  std::erase_if(out.odometry, after_end);
  std::erase_if(out.scanner, after_end);
  std::erase_if(out.ground_truth, after_end);
  std::erase_if(out.true_path, after_end);
  std::erase_if(out.kidnaps, after_end);
  return out;
}

std::vector<TimedPose> DeadReckoning(const RobotDescription& robot,
                                     const std::vector<OdometryReading>& odometry) {
  OdometryIntegrator integrator(robot.base);
  std::vector<TimedPose> path;
  path.reserve(odometry.size());
  for (const OdometryReading& r : odometry) path.push_back({r.t, integrator.Add(r)});
  return path;
}

std::vector<RobotEvent> MergeEvents(const std::vector<OdometryReading>& odometry,
                                    const std::vector<ScannerReading>& scanner) {
  std::vector<RobotEvent> events;
  events.reserve(odometry.size() + scanner.size());
  size_t o = 0, s = 0;
  while (o < odometry.size() || s < scanner.size()) {
    if (s == scanner.size() || (o < odometry.size() && odometry[o].t <= scanner[s].t)) {
      events.emplace_back(odometry[o++]);
    } else {
      events.emplace_back(scanner[s++]);
    }
  }
  return events;
}

std::vector<Scan> BuildScans(const RobotDescription& robot,
                             const std::vector<OdometryReading>& odometry,
                             const std::vector<ScannerReading>& scanner) {
  ScanAssembler assembler(robot);
  std::vector<Scan> scans;
  for (const RobotEvent& event : MergeEvents(odometry, scanner)) assembler.Add(event, scans);
  return scans;
}

}  // namespace slam::sim
