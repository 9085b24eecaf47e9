#pragma once
// One SLAM time step: the samples of half a turn of the scanner with the dead-reckoned pose at
// each sample's time (paper section V: a time step is a full 360 degree scan).

#include <array>
#include <cstdint>
#include <vector>

#include "engine/pose.hpp"
#include "engine/robot.hpp"

namespace slam {

struct ScanSample {
  double t = 0.0;
  Pose2 odom;                       // dead-reckoned robot pose at t
  double platform_angle_rad = 0.0;  // counter-clockwise from the robot's forward axis
  std::array<uint16_t, kScannerSensors> raw{};
};

struct Scan {
  int64_t index = 0;
  double t_begin = 0.0;  // time of the previous scan's end
  double t_end = 0.0;
  Pose2 odom_begin;                 // dead-reckoned pose at t_begin
  Pose2 odom_end;                   // dead-reckoned pose at t_end
  std::vector<ScanSample> samples;  // time-ordered, within (t_begin, t_end]
};

}  // namespace slam
