#pragma once
// The tunable parameters of the SLAM (paper Table II) with the defaults of docs/design.md
// section 3.

#include "engine/config_error.hpp"

namespace slam {

struct SlamParams {
  double dist_error_ratio = 0.05;       // translation noise per metre travelled
  double dist_error_const_m = 0.01;     // translation noise per scan
  double angle_error_ratio = 0.05;      // rotation noise per radian turned
  double angle_error_const_deg = 0.01;  // rotation noise per scan
  double min_pos_uncertainty_m = 0.02;  // lower bound of the refinement's position spread
  double min_angle_uncertainty_deg = 5.0;
  int resampling_period_scans = 1;       // resample every N scans
  double angle_between_scans_deg = 0.0;  // thinning of matching measurements by platform angle
  int particles = 1;

  friend bool operator==(const SlamParams&, const SlamParams&) = default;
};

/// Bounds of every parameter; empty when valid. Pointers are the JSON keys ("/particles").
ConfigErrors Validate(const SlamParams& params);

}  // namespace slam
