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
    : type_(type), update_(kRawValues) {
  const double step =
      resolution_m / 8.0;  // fine bins: the free/occupied edge is exact to 1/16 cell
  const int free_delta = EncodeLogOdds(update.free_logodds);
  const int occupied_delta = EncodeLogOdds(update.occupied_logodds);
  const double use_min = std::max(type.use_min_m, type.range_min_m);
  for (int raw = 0; raw < kRawValues; ++raw) {
    distance_[static_cast<size_t>(raw)] = -1.0;
    const std::optional<double> d = CalibratedDistance(type.calibration, raw);
    // Outside the table is the non-injective near zone or the floor beyond range: never used.
    if (!d || *d < use_min || *d > type.use_max_m) continue;
    distance_[static_cast<size_t>(raw)] = *d;
    // Fig. 7: free before the measured distance, occupied at it (and a little behind, so that
    // walls are closed), nothing beyond.
    const double depth = std::max(update.occupied_depth_cells * resolution_m,
                                  update.occupied_sigma_factor * Sigma(*d));
    UpdateProfile& profile = update_[static_cast<size_t>(raw)];
    profile.step_m = step;
    const auto bins = static_cast<size_t>(std::ceil((*d + depth) / step));
    profile.delta.resize(bins);
    for (size_t i = 0; i < bins; ++i) {
      const double r = (static_cast<double>(i) + 0.5) * step;  // bin centre
      profile.delta[i] = static_cast<int16_t>(r < *d ? free_delta : occupied_delta);
    }
  }
}

double SensorModel::Sigma(double distance_m) const {
  const auto& c = type_.sigma_m;
  return c[0] + c[1] * distance_m + c[2] * distance_m * distance_m;
}

}  // namespace slam
