#include "engine/params.hpp"

#include <cmath>
#include <sstream>
#include <string>

namespace slam {
namespace {

template <typename T>
void CheckIn(ConfigErrors& errors, const char* key, T value, T lo, T hi) {
  // Written so that NaN fails too.
  if (std::isfinite(static_cast<double>(value)) && value >= lo && value <= hi) return;
  std::ostringstream detail;
  detail << value << " is outside [" << lo << ", " << hi << "]";
  errors.push_back({std::string("/") + key, detail.str()});
}

}  // namespace

ConfigErrors Validate(const SlamParams& params) {
  ConfigErrors errors;
  CheckIn(errors, "dist_error_ratio", params.dist_error_ratio, 0.0, 1.0);
  CheckIn(errors, "dist_error_const_m", params.dist_error_const_m, 0.0, 0.5);
  CheckIn(errors, "angle_error_ratio", params.angle_error_ratio, 0.0, 1.0);
  CheckIn(errors, "angle_error_const_deg", params.angle_error_const_deg, 0.0, 45.0);
  CheckIn(errors, "min_pos_uncertainty_m", params.min_pos_uncertainty_m, 0.0, 0.5);
  CheckIn(errors, "min_angle_uncertainty_deg", params.min_angle_uncertainty_deg, 0.0, 90.0);
  CheckIn(errors, "resampling_period_scans", params.resampling_period_scans, 1, 10000);
  CheckIn(errors, "angle_between_scans_deg", params.angle_between_scans_deg, 0.0, 180.0);
  CheckIn(errors, "particles", params.particles, 1, 1000);
  return errors;
}

}  // namespace slam
