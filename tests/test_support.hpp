#pragma once
// Shared helpers of the test suites: the shipped robot description and scans built by hand.

#include <gtest/gtest.h>

#include <string>

#include "engine/io/robot_json.hpp"
#include "engine/robot.hpp"

namespace slam::testing {

/// The marXbot description the project ships (config/marxbot.robot.json).
inline RobotDescription ShippedRobot() {
  const auto robot = io::LoadRobot(std::string(SLAM_SOURCE_DIR) + "/config/marxbot.robot.json");
  if (!robot.ok()) ADD_FAILURE() << robot.Message();
  return robot.ok() ? robot.value() : RobotDescription{};
}

}  // namespace slam::testing
