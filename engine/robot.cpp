#include "engine/robot.hpp"

#include <cmath>
#include <cstddef>
#include <sstream>

namespace slam {
namespace {

constexpr int kMaxNode = 255;              // Aseba node ids fit the low 8 bits of the CAN id
constexpr double kMaxRobotSpeedMS = 20.0;  // far beyond any robot this SLAM is for
constexpr int kMaxEvent = 0x7FFF;          // Aseba user message types
constexpr int kMaxRaw = 1023;              // 10-bit ADC

// Plausible bounds: generous for any small robot and range sensor (laser scanners included),
// and tight enough that no description can make the engine's tables or the simulator allocate
// without bound (a calibration distance of 1e6 m once did).
constexpr double kMaxRangeM = 100.0;  // ranges, use windows, calibration distances
constexpr double kMaxSigmaM = 10.0;   // a reading's standard deviation anywhere in use
constexpr double kMaxTrackWidthM = 10.0;
constexpr double kMinTicksPerM = 1.0;
constexpr double kMaxTicksPerM = 1e9;
constexpr double kMaxGyroUnitDps = 100.0;
constexpr double kMaxSampleRateHz = 10000.0;
constexpr double kMaxMountRadiusM = 5.0;
constexpr double kMaxAngleDeg = 360.0;
constexpr int kMaxBeams = 100000;         // a sweep's readings
constexpr double kRangeRawMaxM = 65.535;  // RangeToRaw's largest (sensor_model.hpp)

// A double for messages (6 significant digits are enough to point at the culprit).
std::string Num(double value) {
  std::ostringstream out;
  out << value;
  return out.str();
}

// RFC 6901 escaping of one reference token ("~" -> "~0", "/" -> "~1").
std::string Token(const std::string& key) {
  std::string escaped;
  for (char c : key) {
    if (c == '~') {
      escaped += "~0";
    } else if (c == '/') {
      escaped += "~1";
    } else {
      escaped += c;
    }
  }
  return escaped;
}

class Checker {
 public:
  explicit Checker(ConfigErrors& errors) : errors_(errors) {}

  void Fail(std::string pointer, std::string detail) {
    errors_.push_back({std::move(pointer), std::move(detail)});
  }
  void IntIn(const std::string& pointer, int value, int lo, int hi) {
    if (value < lo || value > hi) {
      Fail(pointer, std::to_string(value) + " is outside [" + std::to_string(lo) + ", " +
                        std::to_string(hi) + "]");
    }
  }
  void Positive(const std::string& pointer, double value) {
    if (!std::isfinite(value) || !(value > 0.0)) Fail(pointer, Num(value) + " must be > 0");
  }
  void NonNegative(const std::string& pointer, double value) {
    if (!std::isfinite(value) || !(value >= 0.0)) Fail(pointer, Num(value) + " must be >= 0");
  }
  void Finite(const std::string& pointer, double value) {
    if (!std::isfinite(value)) Fail(pointer, "must be a finite number");
  }
  /// A value already checked for sign: at most `hi`.
  void AtMost(const std::string& pointer, double value, double hi, const char* unit) {
    if (std::isfinite(value) && value > hi) {
      Fail(pointer,
           Num(value) + unit + " is beyond any plausible value (at most " + Num(hi) + unit + ")");
    }
  }
  void Within(const std::string& pointer, double value, double lo, double hi, const char* unit) {
    if (std::isfinite(value) && (value < lo || value > hi)) {
      Fail(pointer, Num(value) + unit + " is outside the plausible [" + Num(lo) + ", " + Num(hi) +
                        "]" + unit);
    }
  }

 private:
  ConfigErrors& errors_;
};

void CheckCalibration(Checker& check, const std::string& pointer,
                      const std::vector<CalibrationPoint>& calibration) {
  if (calibration.size() < 2) {
    check.Fail(pointer, "needs at least 2 points, has " + std::to_string(calibration.size()));
  }
  for (std::size_t i = 0; i < calibration.size(); ++i) {
    const CalibrationPoint& point = calibration[i];
    const std::string at = pointer + "/" + std::to_string(i);
    if (point.raw < 0 || point.raw > kMaxRaw) {
      check.Fail(at, "raw " + std::to_string(point.raw) + " is outside [0, " +
                         std::to_string(kMaxRaw) + "]");
    }
    if (!std::isfinite(point.distance_m) || !(point.distance_m > 0.0)) {
      check.Fail(at, "distance " + Num(point.distance_m) + " m must be > 0");
    }
    check.AtMost(at + "/1", point.distance_m, kMaxRangeM, " m");
    if (i == 0) continue;
    const CalibrationPoint& previous = calibration[i - 1];
    if (!(point.raw < previous.raw)) {
      check.Fail(at, "raw " + std::to_string(point.raw) + " must be < the previous point's " +
                         std::to_string(previous.raw) + " (raw strictly decreasing)");
    }
    if (!(point.distance_m > previous.distance_m)) {
      check.Fail(at, "distance " + Num(point.distance_m) + " m must be > the previous point's " +
                         Num(previous.distance_m) + " m (distance strictly increasing)");
    }
  }
}

// A range sensor: its beams, and ranges its raw values can carry (millimetres in 16 bits).
void CheckRangeSensor(Checker& check, const std::string& pointer,
                      const SensorTypeDescription& type) {
  const BeamPattern& beams = type.beams;
  check.IntIn(pointer + "/beams/count", beams.count, 1, kMaxBeams);
  check.Finite(pointer + "/beams/first_deg", beams.first_deg);
  check.Finite(pointer + "/beams/increment_deg", beams.increment_deg);
  check.Within(pointer + "/beams/first_deg", beams.first_deg, -kMaxAngleDeg, kMaxAngleDeg, " deg");
  if (beams.count > 1 && !(std::abs(beams.increment_deg * (beams.count - 1)) <= kMaxAngleDeg)) {
    check.Fail(pointer + "/beams/increment_deg", Num(beams.increment_deg) + " deg between " +
                                                     std::to_string(beams.count) +
                                                     " beams spans more than a turn");
  }
  if (beams.count > 1 && !(beams.increment_deg != 0.0)) {
    check.Fail(pointer + "/beams/increment_deg", "must not be 0 with more than one beam");
  }
  const double raw_max_m = kRangeRawMaxM;
  check.AtMost(pointer + "/range_m/1", type.range_max_m, raw_max_m,
               " m (a range sensor's readings travel as millimetres in 16 bits)");
  if (!(type.use_min_m > 0.0)) {
    check.Fail(pointer + "/use_m/0", "must be > 0 for a range sensor (a zero range is no reading)");
  }
  if (!std::isfinite(type.no_return_m) || type.no_return_m < 0.0) {
    check.Fail(pointer + "/no_return_m", Num(type.no_return_m) + " must be >= 0");
  } else if (type.no_return_m > 0.0 && type.no_return_m <= type.use_max_m) {
    check.Fail(pointer + "/no_return_m",
               Num(type.no_return_m) +
                   " m lies inside the use window: a beam without echo would "
                   "be taken for a surface");
  }
  if (!type.calibration.empty()) {
    check.Fail(pointer + "/calibration", "a range sensor reports distances: no calibration table");
  }
}

void CheckSensorType(Checker& check, const std::string& pointer,
                     const SensorTypeDescription& type) {
  const bool range_ok = std::isfinite(type.range_min_m) && std::isfinite(type.range_max_m) &&
                        type.range_min_m >= 0.0 && type.range_min_m < type.range_max_m;
  if (!range_ok) {
    check.Fail(pointer + "/range_m", "[" + Num(type.range_min_m) + ", " + Num(type.range_max_m) +
                                         "] must satisfy 0 <= min < max");
  }
  const bool use_ok = std::isfinite(type.use_min_m) && std::isfinite(type.use_max_m) &&
                      type.use_min_m >= 0.0 && type.use_min_m < type.use_max_m;
  if (!use_ok) {
    check.Fail(pointer + "/use_m", "[" + Num(type.use_min_m) + ", " + Num(type.use_max_m) +
                                       "] must satisfy 0 <= min < max");
  }
  check.AtMost(pointer + "/range_m/1", type.range_max_m, kMaxRangeM, " m");
  check.AtMost(pointer + "/use_m/1", type.use_max_m, kMaxRangeM, " m");
  if (type.kind == SensorKind::kInfrared) {
    CheckCalibration(check, pointer + "/calibration", type.calibration);
  } else {
    CheckRangeSensor(check, pointer, type);
  }

  bool coefficients_ok = true;
  for (std::size_t k = 0; k < type.sigma_m.size(); ++k) {
    if (!std::isfinite(type.sigma_m[k]) || !(type.sigma_m[k] >= 0.0)) {
      check.Fail(pointer + "/sigma_m/" + std::to_string(k), Num(type.sigma_m[k]) + " must be >= 0");
      coefficients_ok = false;
    }
  }
  if (coefficients_ok && use_ok) {
    // With non-negative coefficients sigma(d) grows with d >= 0: its minimum is at use_min.
    const double d = type.use_min_m;
    const double sigma = type.sigma_m[0] + type.sigma_m[1] * d + type.sigma_m[2] * d * d;
    if (!(sigma > 0.0)) {
      check.Fail(pointer + "/sigma_m",
                 "sigma(" + Num(d) + " m) = " + Num(sigma) + " must be > 0 over the use window");
    }
    // ... and its maximum at use_max.
    const double far = type.use_max_m;
    const double widest = type.sigma_m[0] + type.sigma_m[1] * far + type.sigma_m[2] * far * far;
    if (!(widest <= kMaxSigmaM)) {
      check.Fail(pointer + "/sigma_m", "sigma(" + Num(far) + " m) = " + Num(widest) +
                                           " m is beyond any plausible noise (at most " +
                                           Num(kMaxSigmaM) + " m over the use window)");
    }
  }
}

}  // namespace

ConfigErrors Validate(const RobotDescription& robot) {
  ConfigErrors errors;
  Checker check(errors);

  const BaseDescription& base = robot.base;
  check.IntIn("/base/node", base.node, 0, kMaxNode);
  check.IntIn("/base/event", base.event, 0, kMaxEvent);
  check.Positive("/base/track_width_m", base.track_width_m);
  check.Positive("/base/ticks_per_m", base.ticks_per_m);
  check.Positive("/base/gyro_unit_dps", base.gyro_unit_dps);
  check.Positive("/base/max_speed_m_s", base.max_speed_m_s);
  check.AtMost("/base/track_width_m", base.track_width_m, kMaxTrackWidthM, " m");
  check.Within("/base/ticks_per_m", base.ticks_per_m, kMinTicksPerM, kMaxTicksPerM, "");
  check.AtMost("/base/gyro_unit_dps", base.gyro_unit_dps, kMaxGyroUnitDps, " deg/s");
  if (base.max_speed_m_s > kMaxRobotSpeedMS) {
    check.Fail("/base/max_speed_m_s", Num(base.max_speed_m_s) +
                                          " m/s is not a small robot's speed (at most " +
                                          Num(kMaxRobotSpeedMS) + ")");
  }

  const ScannerDescription& scanner = robot.scanner;
  check.IntIn("/scanner/node", scanner.node, 0, kMaxNode);
  check.IntIn("/scanner/event", scanner.event, 0, kMaxEvent);
  if (scanner.node == base.node && scanner.event == base.event) {
    check.Fail("/scanner/event", "the scanner and the base send the same event from the same node");
  }
  check.Positive("/scanner/sample_rate_hz", scanner.sample_rate_hz);
  check.NonNegative("/scanner/mount_radius_m", scanner.mount_radius_m);
  check.AtMost("/scanner/sample_rate_hz", scanner.sample_rate_hz, kMaxSampleRateHz, " Hz");
  check.AtMost("/scanner/mount_radius_m", scanner.mount_radius_m, kMaxMountRadiusM, " m");
  check.Finite("/scanner/offset_m/0", scanner.offset_x_m);
  check.Finite("/scanner/offset_m/1", scanner.offset_y_m);
  check.Within("/scanner/offset_m/0", scanner.offset_x_m, -kMaxMountRadiusM, kMaxMountRadiusM,
               " m");
  check.Within("/scanner/offset_m/1", scanner.offset_y_m, -kMaxMountRadiusM, kMaxMountRadiusM,
               " m");
  if (scanner.sensors.empty() ||
      scanner.sensors.size() > static_cast<std::size_t>(kScannerSensors)) {
    check.Fail("/scanner/sensors", "needs 1 to " + std::to_string(kScannerSensors) +
                                       " sensors, has " + std::to_string(scanner.sensors.size()));
  }
  for (std::size_t i = 0; i < scanner.sensors.size(); ++i) {
    const ScannerSensor& sensor = scanner.sensors[i];
    const std::string at = "/scanner/sensors/" + std::to_string(i);
    if (robot.sensor_types.find(sensor.type) == robot.sensor_types.end()) {
      check.Fail(at + "/type", "unknown sensor type \"" + sensor.type + "\"");
    }
    check.Finite(at + "/angle_deg", sensor.angle_deg);
    check.Within(at + "/angle_deg", sensor.angle_deg, -kMaxAngleDeg, kMaxAngleDeg, " deg");
  }

  for (const auto& [name, type] : robot.sensor_types) {
    CheckSensorType(check, "/sensor_types/" + Token(name), type);
  }
  return errors;
}

bool HasRangeScanner(const RobotDescription& robot) {
  for (const ScannerSensor& sensor : robot.scanner.sensors) {
    const auto type = robot.sensor_types.find(sensor.type);
    if (type != robot.sensor_types.end() && type->second.kind == SensorKind::kRange) return true;
  }
  return false;
}

double DefaultResolution(const RobotDescription& robot) {
  return HasRangeScanner(robot) ? 0.05 : 0.01;
}

}  // namespace slam
