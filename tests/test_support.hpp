#pragma once
// Shared helpers of the test suites: the shipped robot description and scans built by hand.

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>
#include <system_error>

#include "engine/io/robot_json.hpp"
#include "engine/robot.hpp"

namespace slam::testing {

/// The marXbot description the project ships (config/marxbot.robot.json).
inline RobotDescription ShippedRobot() {
  const auto robot = io::LoadRobot(std::string(SLAM_SOURCE_DIR) + "/config/marxbot.robot.json");
  if (!robot.ok()) ADD_FAILURE() << robot.Message();
  return robot.ok() ? robot.value() : RobotDescription{};
}

/// A fresh directory for the files a test writes, removed by the destructor.
class TempDir {
 public:
  explicit TempDir(const std::string& name)
      : path_(std::filesystem::path(::testing::TempDir()) /
              ("slam_test_" + std::to_string(::getpid()) + "_" + name)) {
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;

  std::string File(const std::string& name) const { return (path_ / name).string(); }
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

}  // namespace slam::testing
