#include "sim/scenario.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <optional>

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
};

constexpr double kControlDt = 0.01;       // the motion is a constant twist over each step
constexpr double kSafetyMarginM = 0.005;  // the robot's edge never gets closer than this
constexpr double kMaxAccel = 0.6;         // m/s^2
constexpr double kMaxAngularAccel = 8.0;  // rad/s^2
constexpr double kWanderSigma = 0.35;     // rad/s, gentle random turns while cruising
constexpr double kWanderCorrelationS = 2.0;
constexpr double kStopGapM = 0.06;   // start turning when the free gap ahead is below this
constexpr double kGoGapM = 0.25;     // resume cruising when the gap ahead exceeds this
constexpr double kLookAheadM = 1.0;  // rays of the avoidance behaviour
constexpr int kRawMax = 1023;
constexpr int64_t kFullTurnRaw = 65536;
constexpr int64_t kHalfTurnRaw = 32768;

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

/// Free gap between the robot's disc and the first obstacle straight ahead (rays from five
/// points across the robot's width, parallel to its heading).
double FreeGapAhead(const World& world, const Pose2& pose, double radius) {
  double gap = kLookAheadM;
  for (const double f : {-1.0, -0.5, 0.0, 0.5, 1.0}) {
    const double offset = 0.98 * f * radius;
    const Vec2 from = pose.Transform({0.0, offset});
    const double body = std::sqrt(radius * radius - offset * offset);
    if (const auto d = RayDistance(world, from, pose.theta, kLookAheadM + radius)) {
      gap = std::min(gap, *d - body);
    }
  }
  return gap;
}

/// Free distance from the robot's centre along a direction relative to its heading.
double SpaceToward(const World& world, const Pose2& pose, double relative_angle) {
  return RayDistance(world, pose.translation(), pose.theta + relative_angle, kLookAheadM)
      .value_or(kLookAheadM);
}

/// The obstacle-avoiding wander behaviour: cruise with gentle random turns, turn in place away
/// from obstacles ahead. Produces the commanded twist for each control step.
class Wanderer {
 public:
  Wanderer(const ScenarioConfig& config, Rng rng)
      : config_(config), rng_(rng), wander_(kWanderSigma, kWanderCorrelationS, kControlDt, rng_) {}

  /// The twist (v, w) to apply over the next control step from `pose`.
  std::pair<double, double> Command(const World& world, const Pose2& pose) {
    wander_.Step(rng_);
    mode_time_ += kControlDt;
    const double gap = FreeGapAhead(world, pose, config_.robot_radius_m);
    const double left = SpaceToward(world, pose, DegToRad(60.0));
    const double right = SpaceToward(world, pose, DegToRad(-60.0));
    if (!turning_ && gap < kStopGapM) StartTurn(left, right);
    if (turning_ && mode_time_ >= turn_min_s_ && gap > kGoGapM) {
      turning_ = false;
      mode_time_ = 0.0;
    }
    double target_v = 0.0, target_w = 0.0;
    if (turning_) {
      target_w = turn_dir_ * config_.turn_rate_rad_s;
    } else {
      target_v = config_.speed_m_s * std::clamp((gap - kStopGapM) / 0.25, 0.3, 1.0);
      target_w = wander_.value();
      if (std::min(left, right) < 0.35) target_w += std::clamp(1.5 * (left - right), -0.8, 0.8);
    }
    v_ += std::clamp(target_v - v_, -kMaxAccel * kControlDt, kMaxAccel * kControlDt);
    w_ += std::clamp(target_w - w_, -kMaxAngularAccel * kControlDt, kMaxAngularAccel * kControlDt);
    return {v_, w_};
  }

  /// The robot bumped into the safety limit: stop translating and turn away.
  void Blocked(const World& world, const Pose2& pose) {
    v_ = 0.0;
    if (!turning_) {
      StartTurn(SpaceToward(world, pose, DegToRad(60.0)),
                SpaceToward(world, pose, DegToRad(-60.0)));
    }
  }

 private:
  void StartTurn(double left, double right) {
    turning_ = true;
    mode_time_ = 0.0;
    turn_dir_ = std::abs(left - right) > 0.02 ? (left > right ? 1.0 : -1.0)
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
  non_negative(translation_slip_ratio, "translation_slip_ratio");
  non_negative(rotation_slip_ratio, "rotation_slip_ratio");
  positive(slip_correlation_s, "slip_correlation_s");
  non_negative(gyro_noise_dps, "gyro_noise_dps");
  non_negative(gyro_bias_dps, "gyro_bias_dps");
  positive(gyro_bias_walk_s, "gyro_bias_walk_s");
  non_negative(sensor_noise_scale, "sensor_noise_scale");
  non_negative(corner_radius_m, "corner_radius_m");
  non_negative(floor_offset_raw, "floor_offset_raw");
  non_negative(floor_noise_raw, "floor_noise_raw");
  non_negative(tracker_noise_m, "tracker_noise_m");
  non_negative(tracker_noise_rad, "tracker_noise_rad");
  if (!(corner_hole_probability >= 0.0 && corner_hole_probability <= 1.0)) {
    errors.push_back("/corner_hole_probability: must be in [0, 1]");
  }
  if (!(near_floor_fraction >= 0.0 && near_floor_fraction <= 1.0)) {
    errors.push_back("/near_floor_fraction: must be in [0, 1]");
  }
  return errors;
}

ScenarioOutput RunScenario(const World& world, const RobotDescription& robot,
                           const ScenarioConfig& config) {
  const World motion_world = MotionWorld(world);
  const std::vector<Vec2> corners = Corners(world);
  const double min_clearance = config.robot_radius_m + kSafetyMarginM;
  const double half_track = robot.base.track_width_m / 2.0;
  const double sample_rate = robot.scanner.sample_rate_hz;

  Rng slip_rng = Rng::ForStream(config.seed, kStreamSlip);
  Rng gyro_rng = Rng::ForStream(config.seed, kStreamGyro);
  Rng sensor_rng = Rng::ForStream(config.seed, kStreamSensors);
  Rng tracker_rng = Rng::ForStream(config.seed, kStreamTracker);
  Rng ticks_rng = Rng::ForStream(config.seed, kStreamTicks);
  Wanderer wanderer(config, Rng::ForStream(config.seed, kStreamWander));
  GaussMarkov slip_t(config.translation_slip_ratio, config.slip_correlation_s, kControlDt,
                     slip_rng);
  GaussMarkov slip_turn(config.translation_slip_ratio, config.slip_correlation_s, kControlDt,
                        slip_rng);
  GaussMarkov slip_r(config.rotation_slip_ratio, config.slip_correlation_s, kControlDt, slip_rng);
  double bias = gyro_rng.Gaussian(DegToRad(config.gyro_bias_dps));
  const double bias_step =
      DegToRad(config.gyro_bias_dps) * std::sqrt(kControlDt / config.gyro_bias_walk_s);
  const int64_t left_offset = static_cast<int32_t>(static_cast<uint32_t>(ticks_rng.Next()));
  const int64_t right_offset = static_cast<int32_t>(static_cast<uint32_t>(ticks_rng.Next()));

  // Motion state at the start of the current control step (theta unwrapped).
  Pose2 pose = StartPose(motion_world, config, Rng::ForStream(config.seed, kStreamStart));
  double left_m = 0.0, right_m = 0.0;  // distances the encoders report

  ScenarioOutput out;
  int64_t next_odometry = 0, next_sample = 0, next_tracker = 0;
  double last_gyro_t = 0.0, last_gyro_theta = pose.theta;
  const auto steps = static_cast<int64_t>(std::ceil(config.duration_s / kControlDt)) + 1;
  for (int64_t k = 0; k < steps; ++k) {
    const double t0 = static_cast<double>(k) * kControlDt;
    const double t1 = static_cast<double>(k + 1) * kControlDt;
    auto [v, w] = wanderer.Command(motion_world, pose);
    Pose2 next = Advance(pose, v, w, kControlDt);
    const double clearance_next = ClearanceAt(motion_world, next.translation());
    if (clearance_next < min_clearance &&
        clearance_next < ClearanceAt(motion_world, pose.translation())) {
      wanderer.Blocked(motion_world, pose);
      v = 0.0;
      next = Advance(pose, v, w, kControlDt);
    }
    slip_t.Step(slip_rng);
    slip_turn.Step(slip_rng);
    slip_r.Step(slip_rng);
    bias += gyro_rng.Gaussian(bias_step);
    // What the encoders see: translation and rotation with slip, plus spurious translation
    // when the treels skid while turning.
    const double v_enc = v * (1.0 + slip_t.value()) + slip_turn.value() * std::abs(w) * half_track;
    const double w_enc = w * (1.0 + slip_r.value());
    const double left_rate = v_enc - w_enc * half_track;
    const double right_rate = v_enc + w_enc * half_track;

    const auto in_step = [&](int64_t n, double rate) {
      const double t = static_cast<double>(n) / rate;
      return t < t1 && t <= config.duration_s + 1e-9;
    };
    while (in_step(next_odometry, config.odometry_rate_hz)) {
      const double t = static_cast<double>(next_odometry) / config.odometry_rate_hz;
      const Pose2 p = Advance(pose, v, w, t - t0);
      // The gyro reports its mean rate since the previous reading (plus bias and noise).
      const double rate = next_odometry == 0 ? w : (p.theta - last_gyro_theta) / (t - last_gyro_t);
      const double measured = rate + bias + gyro_rng.Gaussian(DegToRad(config.gyro_noise_dps));
      const double gyro_units = RadToDeg(measured) / robot.base.gyro_unit_dps;
      OdometryReading r;
      r.t = t;
      r.seq = static_cast<uint16_t>(next_odometry & 0xFFFF);
      r.left_ticks = WrapTicks(
          left_offset + std::llround((left_m + left_rate * (t - t0)) * robot.base.ticks_per_m));
      r.right_ticks = WrapTicks(
          right_offset + std::llround((right_m + right_rate * (t - t0)) * robot.base.ticks_per_m));
      r.gyro_raw = static_cast<int16_t>(std::clamp(std::lround(gyro_units), -32768L, 32767L));
      out.odometry.push_back(r);
      last_gyro_t = t;
      last_gyro_theta = p.theta;
      ++next_odometry;
    }
    while (in_step(next_sample, sample_rate)) {
      const double t = static_cast<double>(next_sample) / sample_rate;
      const Pose2 p = Advance(pose, v, w, t - t0);
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
        r.raw[s] = SenseRaw(world, corners, robot.sensor_types.at(sensor.type), config, origin,
                            angle, sensor_rng);
      }
      out.scanner.push_back(r);
      out.true_path.push_back({t, Normalized(p)});
      ++next_sample;
    }
    while (in_step(next_tracker, config.tracker_rate_hz)) {
      const double t = static_cast<double>(next_tracker) / config.tracker_rate_hz;
      Pose2 p = Normalized(Advance(pose, v, w, t - t0));
      p.x += tracker_rng.Gaussian(config.tracker_noise_m);
      p.y += tracker_rng.Gaussian(config.tracker_noise_m);
      p.theta = NormalizeAngle(p.theta + tracker_rng.Gaussian(config.tracker_noise_rad));
      out.ground_truth.push_back({t, p});
      ++next_tracker;
    }
    pose = next;
    left_m += left_rate * kControlDt;
    right_m += right_rate * kControlDt;
  }
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
