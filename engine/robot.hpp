#pragma once
// The plain description of a robot (robot.json, docs/design.md section 5) and the robot-event
// types. The engine uses the description it is given; reading it from JSON is engine/io's job.

#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <variant>
#include <vector>

#include "engine/config_error.hpp"

namespace slam {

/// Most distance sensors on the scanner (the scanner event carries s0..s3; a laser is one).
inline constexpr int kScannerSensors = 4;

struct BaseDescription {
  int node = 1;
  int event = 0x10;
  double track_width_m = 0.15;
  double ticks_per_m = 11375.0;
  double gyro_unit_dps = 0.01;  // degrees per second per gyro unit
  /// Where dead reckoning takes its heading from: the gyro (the marXbot's), or the encoders alone
  /// (a robot without one, such as the Pioneers of many recorded logs; the event's gyro word is
  /// then ignored).
  bool heading_from_gyro = true;
  /// The fastest either treel can move. Odometry implying more (a spoofed or corrupted
  /// message, encoder counters that restarted) is refused by the scan assembler; generous by
  /// default, since it only has to tell the impossible from the possible.
  double max_speed_m_s = 2.0;
};

struct ScannerSensor {
  std::string type;        // key into RobotDescription::sensor_types
  double angle_deg = 0.0;  // on the platform, counter-clockwise from the platform's zero
};

struct ScannerDescription {
  int node = 2;
  int event = 0x20;
  double sample_rate_hz = 60.0;
  double mount_radius_m = 0.05;
  /// Where the scanner's centre is on the robot (robot frame, x forward): 0 for the marXbot's
  /// turret; a laser mounted ahead of the wheel axis, for one.
  double offset_x_m = 0.0;
  double offset_y_m = 0.0;
  std::vector<ScannerSensor> sensors;  // 1 to kScannerSensors, in event word order
};

/// One point of a sensor's calibration: raw 10-bit ADC value and the distance it means.
struct CalibrationPoint {
  int raw = 0;
  double distance_m = 0.0;
};

/// How a sensor reports a distance.
enum class SensorKind {
  kInfrared,  // a raw 10-bit reading that the calibration table turns into a distance (Sharp)
  kRange,     // the distance itself (laser and time-of-flight scanners): ScanSample::raw holds
              // it in millimetres (RangeToRaw)
};

/// The beams of one sweep of a range scanner, counter-clockwise from the sensor's forward axis.
struct BeamPattern {
  double first_deg = 0.0;
  double increment_deg = 0.0;
  int count = 0;

  double AngleDeg(int beam) const { return first_deg + increment_deg * beam; }
};

struct SensorTypeDescription {
  std::string model;
  SensorKind kind = SensorKind::kInfrared;
  double range_min_m = 0.0;  // datasheet range; below the minimum the response is not injective
  double range_max_m = 0.0;
  double use_min_m = 0.0;  // readings outside [use_min, use_max] are not used
  double use_max_m = 0.0;
  std::vector<CalibrationPoint>
      calibration;           // infrared: raw strictly decreasing, distance increasing
  BeamPattern beams;         // range: the sweep's beams
  double no_return_m = 0.0;  // range: the value a beam reports without an echo (0: none)
  /// Standard deviation of a reading at distance d: sigma[0] + sigma[1] d + sigma[2] d^2.
  std::array<double, 3> sigma_m{0.003, 0.0, 0.02};
};

struct RobotDescription {
  std::string name;
  BaseDescription base;
  ScannerDescription scanner;
  std::map<std::string, SensorTypeDescription> sensor_types;
};

/// Checks a description for consistency; empty when valid.
ConfigErrors Validate(const RobotDescription& robot);

/// Whether the robot's scanner reports ranges (a laser or time-of-flight scanner) rather than
/// the marXbot's infrared readings. Precondition: Validate(robot) is empty.
bool HasRangeScanner(const RobotDescription& robot);

/// The grid cell size that suits the robot's scanner when none is given: 1 cm for the
/// marXbot's infrared scanner (its readings end within 1.5 m), 5 cm for a range scanner (tens of
/// metres in a building, as laser SLAM maps usually are).
double DefaultResolution(const RobotDescription& robot);

/// Odometry event of the base: cumulative treel encoder counts (wrapping int32) and gyro rate.
struct OdometryReading {
  double t = 0.0;  // seconds
  uint16_t seq = 0;
  int32_t left_ticks = 0;
  int32_t right_ticks = 0;
  int16_t gyro_raw = 0;  // z rate, counter-clockwise positive, in gyro units

  friend bool operator==(const OdometryReading&, const OdometryReading&) = default;
};

/// Scanner event: platform angle and the raw readings of the four sensors.
struct ScannerReading {
  double t = 0.0;  // seconds
  uint16_t seq = 0;
  uint16_t angle_raw = 0;  // 65536 = 360 degrees, counter-clockwise from the robot's forward axis
  std::array<uint16_t, kScannerSensors> raw{};
  uint16_t rectifier_mv = 0;

  friend bool operator==(const ScannerReading&, const ScannerReading&) = default;
};

/// One event from the robot, as the link decodes it.
using RobotEvent = std::variant<OdometryReading, ScannerReading>;

/// The event's time (seconds).
inline double EventTime(const RobotEvent& event) {
  return std::visit([](const auto& reading) { return reading.t; }, event);
}

}  // namespace slam
