#pragma once
// A deterministic simulation of the marXbot wandering in a World: the robot events the engine
// consumes (odometry + gyro, scanner samples), the overhead tracker's ground truth, and the
// grouping of scanner samples into scans (one per half turn of the platform).

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "engine/pose.hpp"
#include "engine/result.hpp"
#include "engine/robot.hpp"
#include "engine/scan.hpp"
#include "sim/world.hpp"

namespace slam::sim {

/// How the simulated odometry errs: kGentle is the small zero-mean slip and gyro bias of the
/// original reference set (dead reckoning ends a 300 s run about 10 cm off in a 2 m arena);
/// kTracked adds what a tracked robot with a MEMS gyro shows: per-run scale errors of the
/// encoders and the gyro, a larger drifting gyro bias, sideways skid in turns and a wandering
/// centre of rotation, so that dead reckoning drifts tens of centimetres to metres in 300 s.
enum class OdometryProfile { kGentle, kTracked };

/// How the simulated odometry errs. The defaults are the gentle profile's.
struct OdometryErrors {
  // Slip ratios are the standard deviations of slowly varying
  // (Gauss-Markov, `slip_correlation_s`) relative errors of what the encoders report.
  double translation_slip_ratio = 0.03;
  double rotation_slip_ratio = 0.15;  // encoder-derived rotation (the engine uses the gyro)
  double slip_correlation_s = 2.0;
  // While accelerating or braking the treels spin or drag: the encoders run ahead of the true
  // motion by this many seconds times the (angular) acceleration.
  double accel_slip_s = 0.02;
  double gyro_noise_dps = 0.3;  // white noise per gyro reading
  // The gyro's bias starts with this deviation and wanders as a random walk whose deviation
  // grows by as much every `gyro_bias_walk_s` (with 0.05 deg/s, dead reckoning typically ends
  // a 300 s run a few to 40 degrees off).
  double gyro_bias_dps = 0.05;
  double gyro_bias_walk_s = 60.0;

  // A tracked robot's systematic errors, each run drawing its own (0: none; the kTracked profile
  // sets them). Floors (world.json "floors") scale the slip and skid and bias the encoders.
  double translation_scale_sigma = 0.0;  // relative error of the encoders' distance scale
  double gyro_scale_sigma = 0.0;         // relative error of the gyro's scale factor
  // A differential drive's systematic errors of rotation (Borenstein and Feng's UMBmark), which
  // matter where the heading comes from the encoders: wheels of unequal diameters turn the
  // encoders' heading by this relative difference over the track width per metre driven, and an
  // effective track unlike the nominal one scales every turn they measure. The gyro sees
  // neither; the mean distance the encoders report is unchanged (to first order).
  double wheel_diameter_sigma = 0.0;  // relative difference of the two wheels' diameters
  double track_scale_sigma = 0.0;     // relative error of the effective track width
  // In turns the treels skid sideways: the body moves outwards at skid_s x v x w (m/s), which
  // the encoders do not see.
  double skid_s = 0.0;
  // Turning, the centre of rotation wanders: the body drifts about this far per radian turned,
  // in a direction that changes slowly (Gauss-Markov, 1 s).
  double turn_drift_m_per_rad = 0.0;
  // The OdometryProfile these values came from, written into meta.json.
  std::string profile = "gentle";
};

/// What to simulate and how noisy it is. Every draw comes from slam::Rng streams of `seed`, so a
/// (world, robot, config) triple always gives the same output.
struct ScenarioConfig {
  double duration_s = 60.0;
  double scans_per_s = 1.5;        // half turns of the scanner platform (or sweeps) per second
  double odometry_rate_hz = 50.0;  // base events; the scanner rate comes from the robot
  double tracker_rate_hz = 30.0;
  double speed_m_s = 0.12;        // cruising speed
  double turn_rate_rad_s = 1.0;   // turning in place to avoid an obstacle
  double robot_radius_m = 0.085;  // the base is 17 cm across
  uint64_t seed = 1;

  // How the odometry errs (a profile's values: WithOdometryProfile).
  OdometryErrors odometry;

  // Sensor artefacts.
  double sensor_noise_scale = 1.0;       // times the robot's sigma_m of each sensor type
  double corner_hole_probability = 0.3;  // a beam hitting near a corner reads as nothing
  double corner_radius_m = 0.03;
  double floor_offset_raw = 15.0;    // out of range: table's last raw minus this ...
  double floor_noise_raw = 2.0;      // ... plus Gaussian noise of this many ADC units
  double near_floor_fraction = 0.4;  // below the minimum range the raw falls linearly
                                     // to this fraction of the table's first raw at 0 m

  // People walking about (0: none): each a pair of legs, discs a range scanner or a Sharp
  // sensor sees where they cross its beam, walking at person_speed_m_s and turning away from
  // walls and from the robot. They are in no map: what a recorded lab has and a drawn world
  // lacks.
  int people = 0;
  double person_speed_m_s = 1.0;

  double tracker_noise_m = 0.001;
  double tracker_noise_rad = 0.005;

  // Kidnapping: the robot lifted and set down elsewhere, which its odometry does not see (the
  // encoders and the gyro go on as if nothing happened) and the tracker does. At the first
  // control step starting at or after kidnap_t_s the true pose jumps to kidnap_to or, when that
  // is not given, to the true pose at kidnap_t_s / 2 (a place the robot has seen, with the
  // heading it had there); it drives on from there. None when kidnap_t_s is not given; else it
  // is within (0, duration_s), also for the live virtual marXbot. The target must be free in the
  // world (CheckFreePose); one that is not is not jumped to.
  std::optional<double> kidnap_t_s;
  std::optional<Pose2> kidnap_to;

  /// Problems with the configuration as "/key: detail" lines; empty when valid.
  std::vector<std::string> Validate() const;
};

/// Whether a robot of `robot_radius_m` may stand at `pose` in `world`: the pose finite, the centre
/// inside the bounds and the disc overlapping no wall, circle or edge of the bounds; else an
/// error saying why.
Result<void> CheckFreePose(const World& world, double robot_radius_m, const Pose2& pose);

/// "gentle", "tracked"; nullopt for anything else.
std::optional<OdometryProfile> OdometryProfileFromName(std::string_view name);
std::string_view OdometryProfileName(OdometryProfile profile);

/// `config` with the odometry error parameters of `profile` (the others unchanged).
ScenarioConfig WithOdometryProfile(ScenarioConfig config, OdometryProfile profile);

/// One sweep of a range scanner (laser, time-of-flight): a range per beam of its BeamPattern, in
/// metres (the sensor type's no_return_m, or 0 when it has none, where no echo came back).
struct LaserSweep {
  double t = 0.0;
  std::vector<float> ranges;
};

/// The robot lifted and set down elsewhere: its true pose jumped from `from` to `to` at time t
/// (the start of a control step), world frame, headings in (-pi, pi].
struct Kidnapping {
  double t = 0.0;
  Pose2 from;
  Pose2 to;
};

/// Everything a simulated run produces, time-ordered; times in seconds from the start.
struct ScenarioOutput {
  std::vector<OdometryReading> odometry;  // at odometry_rate_hz, the first at t = 0
  /// A robot with Sharp sensors: samples at the robot's sample rate, the first at t = 0.
  std::vector<ScannerReading> scanner;
  /// A robot whose scanner is a range sensor: sweeps at scans_per_s, the first at t = 0.
  std::vector<LaserSweep> sweeps;
  std::vector<TimedPose> ground_truth;  // tracker poses (with tracker noise) at tracker_rate_hz
  std::vector<TimedPose> true_path;     // exact poses at every scanner sample or sweep
  std::vector<Kidnapping> kidnaps;      // ScenarioConfig::kidnap_t_s, Simulator::Kidnap
};

/// The simulation advancing step by step (10 ms each), without an end: the live virtual
/// marXbot runs it for as long as it is wanted. Same (world, robot, config) -> same readings.
class Simulator {
 public:
  /// Preconditions as RunScenario's; config.duration_s is not used.
  Simulator(const World& world, const RobotDescription& robot, const ScenarioConfig& config);
  ~Simulator();
  Simulator(Simulator&&) noexcept;
  Simulator& operator=(Simulator&&) noexcept;

  /// Advances one control step, appending the readings made during it to `out` (in time order).
  void Step(ScenarioOutput& out);
  /// Simulated time at the start of the next step (seconds).
  double time() const;
  /// The robot's true pose now.
  Pose2 pose() const;

  /// Requests that the next step starts with the robot set down at `target` (heading included),
  /// driving on from there: the tracker and the true path jump, the odometry does not (encoder
  /// counts and gyro go on as if nothing happened); the step appends a Kidnapping to its output.
  /// A later request before that step replaces this one. An error, and nothing requested, when
  /// `target` is not free (CheckFreePose).
  Result<void> Kidnap(const Pose2& target);

 private:
  struct State;
  std::unique_ptr<State> state_;
};

/// Simulates the robot in `world` for config.duration_s (readings at t <= duration_s).
/// Preconditions: Validate(robot) and config.Validate() are empty, the world leaves room for
/// the robot inside its bounds, and config.kidnap_to, when given, is free (CheckFreePose).
ScenarioOutput RunScenario(const World& world, const RobotDescription& robot,
                           const ScenarioConfig& config);

/// Both streams as one, in time order (odometry first at equal times).
std::vector<RobotEvent> MergeEvents(const std::vector<OdometryReading>& odometry,
                                    const std::vector<ScannerReading>& scanner);

/// The scans a slam::ScanAssembler makes of these readings (fed in time order): half platform
/// turns counted from the first posed sample, every sample posed by dead reckoning. Samples
/// outside the odometry's time span and a trailing incomplete half turn are left out.
std::vector<Scan> BuildScans(const RobotDescription& robot,
                             const std::vector<OdometryReading>& odometry,
                             const std::vector<ScannerReading>& scanner);

/// The dead-reckoned trajectory of the odometry readings (one pose per reading).
std::vector<TimedPose> DeadReckoning(const RobotDescription& robot,
                                     const std::vector<OdometryReading>& odometry);

}  // namespace slam::sim
