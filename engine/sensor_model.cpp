#include "engine/sensor_model.hpp"

#include <algorithm>
#include <cmath>

#include "engine/cell_encoding.hpp"

namespace slam {

std::optional<double> CalibratedDistance(const std::vector<CalibrationPoint>& table, int raw) {
  if (table.size() < 2 || raw > table.front().raw || raw < table.back().raw) return std::nullopt;
  // First point whose raw is <= the reading (raw decreases along the table).
  const auto upper = std::find_if(table.begin(), table.end(),
                                  [raw](const CalibrationPoint& p) { return p.raw <= raw; });
  if (upper->raw == raw) return upper->distance_m;
  const auto lower = std::prev(upper);  // lower->raw > raw > upper->raw
  const double s = double(lower->raw - raw) / double(lower->raw - upper->raw);
  const double inv = (1.0 - s) / lower->distance_m + s / upper->distance_m;
  return 1.0 / inv;
}

int CalibratedRaw(const std::vector<CalibrationPoint>& table, double distance_m) {
  if (table.empty()) return 0;
  if (distance_m <= table.front().distance_m) return table.front().raw;
  if (distance_m >= table.back().distance_m) return table.back().raw;
  const auto upper =
      std::find_if(table.begin(), table.end(),
                   [distance_m](const CalibrationPoint& p) { return p.distance_m >= distance_m; });
  const auto lower = std::prev(upper);
  // Invert the 1/d interpolation of CalibratedDistance.
  const double s = (1.0 / distance_m - 1.0 / lower->distance_m) /
                   (1.0 / upper->distance_m - 1.0 / lower->distance_m);
  return static_cast<int>(std::lround(lower->raw - s * (lower->raw - upper->raw)));
}

SensorModel::SensorModel(const SensorTypeDescription& type, const UpdateModelConfig& update,
                         double resolution_m)
    : type_(type),
      update_config_(update),
      resolution_m_(resolution_m),
      use_min_m_(std::max(type.use_min_m, type.range_min_m)) {
  distance_.fill(-1.0);
  if (type.kind == SensorKind::kRange) return;  // the distance is the reading
  for (int raw = 0; raw < kRawValues; ++raw) {
    const std::optional<double> d = CalibratedDistance(type.calibration, raw);
    // Outside the table is the non-injective near zone or the floor beyond range: never used.
    if (!d || *d < use_min_m_ || *d > type.use_max_m) continue;
    distance_[static_cast<size_t>(raw)] = *d;
    update_[static_cast<size_t>(raw)] = ProfileAt(*d);
  }
}

UpdateProfile SensorModel::ProfileAt(double distance_m) const {
  // Fine bins: the free/occupied edge is exact to 1/16 cell. Occupied from the first bin whose
  // centre is at or beyond the reading, for the occupied depth (walls are closed behind it).
  const double step = resolution_m_ / 8.0;
  const double depth = std::max(update_config_.occupied_depth_cells * resolution_m_,
                                update_config_.occupied_sigma_factor * Sigma(distance_m));
  const auto bins = static_cast<int32_t>(std::ceil((distance_m + depth) / step));
  auto free = static_cast<int32_t>(std::max(0.0, std::ceil(distance_m / step - 0.5)));
  const auto centre = [&](int32_t i) { return (static_cast<double>(i) + 0.5) * step; };
  while (free > 0 && !(centre(free - 1) < distance_m)) --free;  // exact where rounding strays
  while (free < bins && centre(free) < distance_m) ++free;
  free = std::min(free, bins);
  UpdateProfile profile;
  profile.step_m = step;
  profile.free_bins = free;
  profile.occupied_bins = bins - free;
  profile.free_delta = static_cast<int16_t>(EncodeLogOdds(update_config_.free_logodds));
  profile.occupied_delta = static_cast<int16_t>(EncodeLogOdds(update_config_.occupied_logodds));
  return profile;
}

double SensorModel::Sigma(double distance_m) const {
  const auto& c = type_.sigma_m;
  return c[0] + c[1] * distance_m + c[2] * distance_m * distance_m;
}

}  // namespace slam
