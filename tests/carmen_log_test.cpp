#include "offline/carmen_log.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

namespace slam::offline {
namespace {

namespace fs = std::filesystem;

TEST(CarmenLogTest, ParsesEveryRecordTypeThisProjectUses) {
  const auto parsed = ParseCarmenLog(
      "# a comment\n"
      "PARAM robot_front_laser_max 50.0 nohost 0\n"
      "ODOM 1.5 -2.25 0.5 0.3 -0.1 0 100.25 host 100.26\n"
      "FLASER 3 1.0 2.5 81.83 1.6 -2.2 0.55 1.5 -2.25 0.5 100.5 host 100.51\r\n"
      "RLASER 2 0.5 0.75 101 host 101\n"
      "RAWLASER2 2 -2.0 4.0 0.5 5.6 0.01 0 3 1 2 3 2 7 8 102.0 host 102.01\n"
      "ROBOTLASER1 0 -1.5708 3.1416 0.0175 81.9 0.01 0 2 4.5 5.5 0 "
      "1.1 2.2 0.3 1.0 2.0 0.3 0.1 0.2 0.5 0.4 0.6 103 host 103.1\n",
      "t.clf");
  ASSERT_TRUE(parsed.ok()) << parsed.Message();
  const CarmenLog& log = parsed.value();
  EXPECT_EQ(log.counters.lines, 7u);
  EXPECT_EQ(log.counters.comments, 1u);
  EXPECT_EQ(log.counters.bad_lines, 0u) << (log.problems.empty() ? "" : log.problems[0]);
  EXPECT_EQ(log.params.at("robot_front_laser_max"), "50.0");

  ASSERT_EQ(log.odometry.size(), 1u);
  EXPECT_EQ(log.odometry[0].line, 3u);
  EXPECT_DOUBLE_EQ(log.odometry[0].t, 100.25);
  EXPECT_DOUBLE_EQ(log.odometry[0].pose.x, 1.5);
  EXPECT_DOUBLE_EQ(log.odometry[0].pose.y, -2.25);
  EXPECT_DOUBLE_EQ(log.odometry[0].pose.theta, 0.5);
  EXPECT_DOUBLE_EQ(log.odometry[0].tv, 0.3);
  EXPECT_DOUBLE_EQ(log.odometry[0].rv, -0.1);

  ASSERT_EQ(log.lasers.size(), 4u);
  const CarmenLaser& front = log.lasers[0];
  EXPECT_EQ(front.message, "FLASER");
  EXPECT_EQ(front.line, 4u);
  EXPECT_DOUBLE_EQ(front.t, 100.5);
  EXPECT_EQ(front.ranges, (std::vector<float>{1.0f, 2.5f, 81.83f}));
  EXPECT_FALSE(front.beams.has_value());
  ASSERT_TRUE(front.robot_odometry && front.laser_pose);
  EXPECT_DOUBLE_EQ(front.laser_pose->x, 1.6);
  EXPECT_DOUBLE_EQ(front.robot_odometry->theta, 0.5);

  const CarmenLaser& rear = log.lasers[1];  // the old format without poses
  EXPECT_EQ(rear.message, "RLASER");
  EXPECT_EQ(rear.ranges.size(), 2u);
  EXPECT_FALSE(rear.robot_odometry.has_value());
  EXPECT_DOUBLE_EQ(rear.t, 101.0);

  const CarmenLaser& raw = log.lasers[2];
  EXPECT_EQ(raw.message, "RAWLASER2");
  ASSERT_TRUE(raw.beams.has_value());
  EXPECT_EQ(raw.beams->laser_type, 2);
  EXPECT_DOUBLE_EQ(raw.beams->start_angle_rad, -2.0);
  EXPECT_DOUBLE_EQ(raw.beams->fov_rad, 4.0);
  EXPECT_DOUBLE_EQ(raw.beams->resolution_rad, 0.5);
  EXPECT_DOUBLE_EQ(raw.beams->max_range_m, 5.6);
  EXPECT_EQ(raw.ranges, (std::vector<float>{1.0f, 2.0f, 3.0f}));  // the remissions skipped
  EXPECT_DOUBLE_EQ(raw.t, 102.0);

  const CarmenLaser& robot = log.lasers[3];
  EXPECT_EQ(robot.message, "ROBOTLASER1");
  ASSERT_TRUE(robot.beams && robot.laser_pose && robot.robot_odometry);
  EXPECT_EQ(robot.ranges, (std::vector<float>{4.5f, 5.5f}));
  EXPECT_DOUBLE_EQ(robot.laser_pose->x, 1.1);
  EXPECT_DOUBLE_EQ(robot.robot_odometry->y, 2.0);
  EXPECT_DOUBLE_EQ(robot.t, 103.0);
}

TEST(CarmenLogTest, MalformedLinesAreCountedSkippedAndNamedByLine) {
  const auto parsed = ParseCarmenLog(
      "FLASER 2 1.0 2.0 10 host 10\n"
      "FLASER 5 1.0 2.0 11 host 11\n"             // fewer readings than announced
      "FLASER 2 1.0 nan 12 host 12\n"             // not finite
      "FLASER 1e20 1.0 2.0 13 host 13\n"          // not a count (beyond any size_t)
      "ODOM 1 2 3 0 0 0 14\n"                     // truncated
      "ODOM 1 2 x 0 0 0 15 host 15\n"             // not a number
      "RAWLASER1 0 -1 2 0 5 0.01 0 2 1 2 0 16\n"  // no host name, no logger time
      "PARAM lonely\n"
      "TRUEPOS 1 2 3 4 5 6 17 host 17\n"  // not used: ignored, counted
      "SONAR 1 2 3 18 host 18\n"
      "FLASER 1 3.0 19 host 19\n",
      "bad.clf");
  ASSERT_TRUE(parsed.ok()) << parsed.Message();
  const CarmenLog& log = parsed.value();
  EXPECT_EQ(log.lasers.size(), 2u);
  EXPECT_EQ(log.lasers[1].line, 11u);
  EXPECT_EQ(log.odometry.size(), 0u);
  EXPECT_EQ(log.counters.bad_lines, 7u);
  EXPECT_EQ(log.counters.ignored_lines, 2u);
  EXPECT_EQ(log.counters.ignored_messages.at("TRUEPOS"), 1u);
  EXPECT_EQ(log.counters.ignored_messages.at("SONAR"), 1u);
  ASSERT_EQ(log.problems.size(), 7u);
  for (size_t i = 0; i < log.problems.size(); ++i) {
    EXPECT_EQ(log.problems[i].rfind("bad.clf:" + std::to_string(i + 2) + ": ", 0), 0u)
        << log.problems[i];
  }
  EXPECT_NE(log.problems[1].find("\"nan\" is not a finite number"), std::string::npos)
      << log.problems[1];
  EXPECT_NE(log.problems[2].find("1e20 is not a count"), std::string::npos) << log.problems[2];
  EXPECT_NE(log.problems[4].find("ODOM: the pose \"x\""), std::string::npos) << log.problems[4];
}

TEST(CarmenLogTest, AGarbledLogCountsEveryBadLineAndNamesTheFirstTwenty) {
  std::string text = "FLASER 3 1 2 3 10 host 10\n";
  for (int i = 0; i < 25; ++i) text += "ODOM 1 2 x 0 0 0 11 host 11\n";
  const auto parsed = ParseCarmenLog(text, "garbled.clf");
  ASSERT_TRUE(parsed.ok()) << parsed.Message();
  EXPECT_EQ(parsed.value().counters.bad_lines, 25u);
  ASSERT_EQ(parsed.value().problems.size(), 20u);
  EXPECT_EQ(parsed.value().problems.front().rfind("garbled.clf:2: ODOM: ", 0), 0u);
  EXPECT_EQ(parsed.value().problems.back().rfind("garbled.clf:21: ODOM: ", 0), 0u);
}

TEST(CarmenLogTest, ALogWithoutLaserIsAnErrorThatSaysWhy) {
  const auto parsed = ParseCarmenLog("ODOM 0 0 0 0 0 0 1 host 1\nFLASER 3 1 2\n", "empty.clf");
  ASSERT_FALSE(parsed.ok());
  const std::string message = parsed.Message();
  EXPECT_NE(message.find("empty.clf: no laser record"), std::string::npos) << message;
  EXPECT_NE(message.find("empty.clf:2: FLASER"), std::string::npos) << message;
  EXPECT_FALSE(LoadCarmenLog("/nonexistent/log.clf").ok());
}

TEST(CarmenLogTest, TellsALogFromAnExperimentDirectory) {
  const fs::path dir = fs::path(::testing::TempDir()) / "carmen_log_test";
  fs::create_directories(dir);
  std::ofstream(dir / "a.clf") << "# header\n\nODOM 0 0 0 0 0 0 1 host 1\n";
  std::ofstream(dir / "b.txt") << "hello\n";
  EXPECT_TRUE(LooksLikeCarmenLog((dir / "a.clf").string()));
  EXPECT_FALSE(LooksLikeCarmenLog((dir / "b.txt").string()));
  EXPECT_FALSE(LooksLikeCarmenLog(dir.string()));
  fs::remove_all(dir);
}

TEST(CarmenLogTest, ReadsTheIntelLabLogWhole) {
  const std::string path = std::string(SLAM_SOURCE_DIR) + "/../shared/data/intel/intel-raw.clf";
  if (!fs::exists(path)) GTEST_SKIP() << path << " is not here (../shared beside the clone)";
  const auto parsed = LoadCarmenLog(path);
  ASSERT_TRUE(parsed.ok()) << parsed.Message();
  const CarmenLog& log = parsed.value();
  EXPECT_EQ(log.counters.bad_lines, 0u);
  EXPECT_EQ(log.lasers.size(), 2725u);  // shared/data/intel/README.md
  EXPECT_EQ(log.odometry.size(), 2725u);
  for (const CarmenLaser& laser : log.lasers) {
    ASSERT_EQ(laser.ranges.size(), 180u) << laser.line;
    ASSERT_TRUE(laser.robot_odometry.has_value()) << laser.line;
  }
}

}  // namespace
}  // namespace slam::offline
