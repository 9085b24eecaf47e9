#pragma once
// Sharp sensor model: calibration (raw -> distance), the valid window, reading noise, and the
// precomputed grid-update tables per raw value (paper section V-C, Fig. 7).

#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include "engine/robot.hpp"
#include "engine/update_ray.hpp"

namespace slam {

inline constexpr int kRawValues = 1024;  // 10-bit ADC

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
    if (raw >= kRawValues || distance_[raw] < 0) return std::nullopt;
    return distance_[raw];
  }
  /// Standard deviation of a reading at `distance_m`.
  double Sigma(double distance_m) const;
  /// The grid update of a usable reading, or nullptr when the reading changes nothing.
  const UpdateProfile* Update(uint16_t raw) const {
    return raw < kRawValues && !update_[raw].delta.empty() ? &update_[raw] : nullptr;
  }
  const SensorTypeDescription& description() const { return type_; }

 private:
  SensorTypeDescription type_;
  std::array<double, kRawValues> distance_{};  // -1 when unusable
  std::vector<UpdateProfile> update_;          // kRawValues entries, empty when unusable
};

}  // namespace slam
