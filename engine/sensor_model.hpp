#pragma once
// Sensor models: the reading's distance (through the Sharp calibration, or the range itself for
// laser and time-of-flight scanners), the valid window, reading noise, and the grid update of a
// reading (paper section V-C, Fig. 7), precomputed per raw value for the 10-bit sensors.

#include <array>
#include <cmath>
#include <cstdint>
#include <optional>
#include <vector>

#include "engine/robot.hpp"
#include "engine/update_ray.hpp"

namespace slam {

inline constexpr int kRawValues = 1024;  // 10-bit ADC

/// Range sensors' readings travel in ScanSample::raw as millimetres: 1 to 65535 (65.5 m); 0 is
/// no reading.
inline constexpr double kRangeRawM = 0.001;
inline constexpr int kRangeRawMax = 65535;

/// A range in metres as a range sensor's raw value; 0 (no reading) when not finite, not
/// positive, or beyond kRangeRawMax.
inline uint16_t RangeToRaw(double range_m) {
  if (!(range_m > 0.0) || !(range_m <= kRangeRawMax * kRangeRawM)) return 0;
  return static_cast<uint16_t>(std::lround(range_m / kRangeRawM));
}

/// How a valid reading changes the grid (natural log odds, paper Fig. 7).
struct UpdateModelConfig {
  // Symmetric on purpose: a cell just in front of a surface is crossed by the long readings
  // and hit by the short ones. With |free| < occupied it ends occupied as soon as more than
  // |free| / (|free| + occupied) of the readings fall short, which thickens walls towards the
  // sensor by about half a reading's sigma and biases matching; symmetric weights put that
  // threshold at one half, where noise cancels.
  double free_logodds = -0.85;     // added to cells crossed before the measured distance
  double occupied_logodds = 0.85;  // added to the cell holding the measured point and behind it
  /// Depth of the occupied band behind the measured point:
  /// max(occupied_depth_cells * resolution, occupied_sigma_factor * sigma(d)).
  double occupied_depth_cells = 1.0;
  double occupied_sigma_factor = 0.5;
};

/// The distance a calibration table gives for a raw value (interpolated linearly in 1/d, which
/// is how triangulation sensors respond); nullopt outside the table.
std::optional<double> CalibratedDistance(const std::vector<CalibrationPoint>& table, int raw);

/// The raw value a calibration table gives for a distance, clamped to the table's ends
/// (the inverse of CalibratedDistance; used by simulators and tests).
int CalibratedRaw(const std::vector<CalibrationPoint>& table, double distance_m);

/// Precomputed model of one sensor type. Immutable after construction; shareable across threads.
class SensorModel {
 public:
  /// Precondition: `type` passed Validate(RobotDescription).
  SensorModel(const SensorTypeDescription& type, const UpdateModelConfig& update,
              double resolution_m);

  /// Distance of a reading when it is usable (calibrated and inside the use window), else nullopt.
  std::optional<double> Distance(uint16_t raw) const {
    if (type_.kind == SensorKind::kRange) {
      const double d = raw * kRangeRawM;
      if (raw == 0 || d < use_min_m_ || d > type_.use_max_m) return std::nullopt;
      return d;
    }
    if (raw >= kRawValues || distance_[raw] < 0) return std::nullopt;
    return distance_[raw];
  }
  /// Standard deviation of a reading at `distance_m`.
  double Sigma(double distance_m) const;
  /// The grid update of a usable reading, or nullopt when the reading changes nothing.
  std::optional<UpdateProfile> Update(uint16_t raw) const {
    if (type_.kind == SensorKind::kRange) {
      const std::optional<double> d = Distance(raw);
      if (!d) return std::nullopt;
      return ProfileAt(*d);
    }
    if (raw >= kRawValues || update_[raw].bins() == 0) return std::nullopt;
    return update_[raw];
  }
  const SensorTypeDescription& description() const { return type_; }

 private:
  /// Fig. 7 for a reading at `distance_m`: free before it, occupied at it and a little behind.
  UpdateProfile ProfileAt(double distance_m) const;

  SensorTypeDescription type_;
  UpdateModelConfig update_config_;
  double resolution_m_ = 0.0;
  double use_min_m_ = 0.0;
  std::array<double, kRawValues> distance_{};       // infrared: -1 when unusable
  std::array<UpdateProfile, kRawValues> update_{};  // infrared: empty when unusable
};

}  // namespace slam
