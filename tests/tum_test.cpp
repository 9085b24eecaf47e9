#include "engine/io/tum.hpp"

#include <gtest/gtest.h>

namespace slam::io {
namespace {

TEST(TumTest, RoundTripsToMicrosecondsAndMicrometres) {
  const std::vector<TimedPose> path{{1700000000.000001, {1.25, -0.5, 3.0}},
                                    {1700000000.033334, {1.2500004, -0.5, -3.1}}};
  const auto parsed = ParseTum(FormatTum(path), "t.tum");
  ASSERT_TRUE(parsed.ok()) << parsed.Message();
  ASSERT_EQ(parsed.value().size(), 2u);
  for (size_t i = 0; i < 2; ++i) {
    EXPECT_NEAR(parsed.value()[i].t, path[i].t, 1e-6);
    EXPECT_NEAR(parsed.value()[i].pose.x, path[i].pose.x, 1e-6);
    EXPECT_NEAR(parsed.value()[i].pose.y, path[i].pose.y, 1e-6);
    EXPECT_NEAR(parsed.value()[i].pose.theta, path[i].pose.theta, 1e-8);
  }
}

TEST(TumTest, SkipsCommentsAndBlankLinesAndToleratesBlanks) {
  const auto parsed =
      ParseTum("# t x y z qx qy qz qw\n\n1 2 3 0 0 0 0 1\r\n  2\t2 3 0 0 0 1 0\n", "t.tum");
  ASSERT_TRUE(parsed.ok()) << parsed.Message();
  ASSERT_EQ(parsed.value().size(), 2u);
  EXPECT_NEAR(std::abs(parsed.value()[1].pose.theta), kPi, 1e-12);
}

TEST(TumTest, ErrorsNameTheFileAndLine) {
  const auto parsed = ParseTum(
      "1 0 0 0 0 0 0 1\n"
      "2 0 0 0 0 0 0\n"        // 7 fields
      "3 0 zero 0 0 0 0 1\n"   // not a number
      "4 0 0 0 0 0 0.5 0.5\n"  // not a unit quaternion
      "0.5 0 0 0 0 0 0 1\n"    // back in time
      "6 nan 0 0 0 0 0 1\n",   // not finite
      "groundtruth.tum");
  ASSERT_FALSE(parsed.ok());
  const std::string message = parsed.Message();
  for (const char* expected :
       {"groundtruth.tum:2: expected 8 fields", "groundtruth.tum:3: not a finite number",
        "groundtruth.tum:4: quaternion", "groundtruth.tum:5: time 0.5 is not after",
        "groundtruth.tum:6: not a finite number"}) {
    EXPECT_NE(message.find(expected), std::string::npos) << expected << "\n" << message;
  }
}

TEST(TumTest, MissingFile) {
  const auto loaded = LoadTum("/nonexistent/groundtruth.tum");
  ASSERT_FALSE(loaded.ok());
  EXPECT_NE(loaded.Message().find("/nonexistent/groundtruth.tum"), std::string::npos);
}

}  // namespace
}  // namespace slam::io
