#include "offline/relations.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

namespace slam::offline {
namespace {

// A trajectory that turns left a quarter turn, then drives 1 m "forward", which is +y in the
// world: relations are in the first pose's frame, so that motion is (1, 0, 0) there.
const std::vector<TimedPose> kTrajectory{
    {10.0, {0.0, 0.0, 0.0}},
    {11.0, {0.0, 0.0, kPi / 2}},
    {12.0, {0.0, 1.0, kPi / 2}},
    {13.0, {0.0, 1.0, -kPi + 0.01}},
};

TEST(RelationsTest, TheTrajectoryOwnMotionsScoreZero) {
  const std::vector<Relation> relations{
      {11.0, 12.0, {1.0, 0.0, 0.0}},      // forward in the first pose's frame
      {10.0, 12.0, {0.0, 1.0, kPi / 2}},  // left, turned
      {12.0, 13.0, {0.0, 0.0, kPi / 2 + 0.01}},
  };
  const RelationsScore score = ScoreRelations(kTrajectory, relations);
  EXPECT_EQ(score.relations, 3u);
  EXPECT_EQ(score.used, 3u);
  EXPECT_NEAR(score.translation_m.mean, 0.0, 1e-12);
  EXPECT_NEAR(score.rotation_deg.mean, 0.0, 1e-9);
}

TEST(RelationsTest, ErrorsAreInTheFirstPoseFrameWithMeansAndPopulationDeviations) {
  // The trajectory moved (1, 0) in the frame of its pose at 11 s. Relations that say it moved
  // (1.1, 0) and (1, 0.3): translational errors 0.1 and 0.3 m; rotations 3 and 1 degrees off.
  const std::vector<Relation> relations{
      {11.0, 12.0, {1.1, 0.0, DegToRad(3.0)}},
      {11.0, 12.0, {1.0, 0.3, DegToRad(-1.0)}},
  };
  const RelationsScore score = ScoreRelations(kTrajectory, relations);
  ASSERT_EQ(score.used, 2u);
  EXPECT_NEAR(score.translation_m.mean, 0.2, 1e-12);
  EXPECT_NEAR(score.translation_m.std_dev, 0.1, 1e-12);
  EXPECT_NEAR(score.translation_m.squared_mean, (0.01 + 0.09) / 2, 1e-12);
  EXPECT_NEAR(score.translation_m.squared_std_dev, 0.04, 1e-12);
  EXPECT_NEAR(score.rotation_deg.mean, 2.0, 1e-9);
  EXPECT_NEAR(score.rotation_deg.std_dev, 1.0, 1e-9);
  EXPECT_NEAR(score.rotation_deg.squared_mean, 5.0, 1e-9);
  EXPECT_NEAR(score.rotation_deg.squared_std_dev, 4.0, 1e-9);
}

TEST(RelationsTest, RotationErrorsWrapAroundTheHalfTurn) {
  // From 12 s to 13 s the robot turned by pi/2 + 0.01 counter-clockwise; a relation saying
  // -(3 pi / 2 - 0.01) - 1 degree is the same turn less one degree.
  const std::vector<Relation> relations{
      {12.0, 13.0, {0.0, 0.0, -(3 * kPi / 2 - 0.01) - DegToRad(1.0)}}};
  const RelationsScore score = ScoreRelations(kTrajectory, relations);
  ASSERT_EQ(score.used, 1u);
  EXPECT_NEAR(score.rotation_deg.mean, 1.0, 1e-9);
}

TEST(RelationsTest, PosesAreTheNearestInTimeWithinTheTolerance) {
  // 11.45 is nearest to 11 (0.45 s): beyond the 0.1 s tolerance, left out. 11.93 takes 12.
  const std::vector<Relation> relations{
      {11.45, 12.0, {0.0, 0.0, 0.0}},
      {11.05, 11.93, {1.0, 0.0, 0.0}},
      {9.0, 12.0, {0.0, 0.0, 0.0}},   // before the trajectory
      {12.0, 14.2, {0.0, 0.0, 0.0}},  // after it
  };
  const RelationsScore score = ScoreRelations(kTrajectory, relations);
  EXPECT_EQ(score.relations, 4u);
  EXPECT_EQ(score.used, 1u);
  EXPECT_NEAR(score.translation_m.mean, 0.0, 1e-12);
  // A wider tolerance takes the nearest, whichever side: 11.45 -> 11, 9.0 -> 10 (within 1 s).
  const RelationsScore wide = ScoreRelations(kTrajectory, relations, 1.0);
  EXPECT_EQ(wide.used, 3u);
  // Between two poses equally near, the earlier.
  const RelationsScore tie = ScoreRelations(kTrajectory, {{11.5, 12.0, {1.0, 0.0, 0.0}}}, 0.5);
  ASSERT_EQ(tie.used, 1u);
  EXPECT_NEAR(tie.translation_m.mean, 0.0, 1e-12);
}

TEST(RelationsTest, EachRelationUsedIsListedWithItsPosesAndErrorsBesideOdometrys) {
  // Relation 0 is scored by both; relation 1 (its t1 11.45 s beyond the tolerance of the
  // trajectory's 11 s) by neither; relation 2 only by "odometry", whose poses are 0.05 s later.
  const std::vector<Relation> relations{
      {11.0, 12.0, {1.1, 0.0, DegToRad(3.0)}},
      {11.45, 12.0, {0.0, 0.0, 0.0}},
      {12.12, 12.13, {0.0, 0.0, 0.0}},
  };
  std::vector<TimedPose> odometry = kTrajectory;
  for (TimedPose& pose : odometry) pose.t += 0.05;
  odometry[1].pose = {0.0, 0.0, kPi / 2 + DegToRad(2.0)};  // 2 degrees more turned at 11 s
  const RelationsScore score = ScoreRelations(kTrajectory, relations);
  const RelationsScore odom = ScoreRelations(odometry, relations);
  ASSERT_EQ(score.errors.size(), 1u);
  EXPECT_EQ(score.errors[0].index, 0u);
  EXPECT_EQ(score.errors[0].t1_pose, 11.0);
  EXPECT_EQ(score.errors[0].t2_pose, 12.0);
  EXPECT_NEAR(score.errors[0].estimate.x, 1.0, 1e-12);
  EXPECT_NEAR(score.errors[0].estimate.y, 0.0, 1e-12);
  EXPECT_NEAR(score.errors[0].translation_m, 0.1, 1e-12);
  EXPECT_NEAR(score.errors[0].rotation_deg, 3.0, 1e-9);
  ASSERT_EQ(odom.errors.size(), 2u);
  EXPECT_EQ(odom.errors[1].index, 2u);

  const std::string text = RelationErrorsText(relations, score, odom);
  std::vector<std::string> lines;
  for (size_t from = 0; from < text.size();) {
    const size_t end = text.find('\n', from);
    ASSERT_NE(end, std::string::npos) << "every line ends with a newline";
    lines.push_back(text.substr(from, end - from));
    from = end + 1;
  }
  ASSERT_EQ(lines.size(), 2u);  // the header and relation 0 (odometry's relation 2 is not listed)
  EXPECT_EQ(lines[0].rfind("# t1\tt2\tx\ty\tyaw_deg\tpose_t1\tpose_t2\test_x", 0), 0u) << lines[0];
  std::vector<std::string> fields;
  for (size_t from = 0;;) {
    const size_t tab = lines[1].find('\t', from);
    fields.push_back(lines[1].substr(from, tab - from));
    if (tab == std::string::npos) break;
    from = tab + 1;
  }
  ASSERT_EQ(fields.size(), 17u) << lines[1];
  EXPECT_EQ(fields[0], "11.000000");
  EXPECT_EQ(fields[2], "1.1000");     // the relation's x
  EXPECT_EQ(fields[4], "3.000");      // its yaw, degrees
  EXPECT_EQ(fields[5], "11.000000");  // the poses' times
  EXPECT_EQ(fields[7], "1.0000");     // the trajectory's x
  EXPECT_EQ(fields[10], "0.1000");    // translational error
  EXPECT_EQ(fields[11], "3.000");     // rotational error
  // Odometry turned 2 degrees more by 11 s: its forward metre lies 2 degrees to the right.
  EXPECT_EQ(fields[12], "0.9994");
  EXPECT_EQ(fields[13], "-0.0349");
  EXPECT_EQ(fields[14], "-2.000");
  EXPECT_EQ(fields[16], "5.000");
  // A relation of huge (finite) numbers keeps its whole line.
  const std::vector<Relation> huge{{11.0, 12.0, {1e300, -1e300, 0.0}}};
  const std::string wide = RelationErrorsText(huge, ScoreRelations(kTrajectory, huge), odom);
  EXPECT_EQ(std::count(wide.begin(), wide.end(), '\n'), 2) << wide.size();
  EXPECT_EQ(wide.back(), '\n');
  EXPECT_EQ(std::count(wide.begin(), wide.end(), '\t'), 2 * 16);
  EXPECT_GT(wide.size(), 600u);  // two numbers of ~300 digits each, at least
  // A relation that odometry left out gets "nan" in its columns.
  const std::string without = RelationErrorsText(relations, score, RelationsScore{});
  EXPECT_NE(without.find("\tnan\tnan\tnan\tnan\tnan\n"), std::string::npos) << without;
}

TEST(RelationsTest, NoRelationUsedGivesZeroStatistics) {
  const RelationsScore score = ScoreRelations({}, {{1.0, 2.0, {1.0, 0.0, 0.0}}});
  EXPECT_EQ(score.used, 0u);
  EXPECT_EQ(score.translation_m.mean, 0.0);
}

TEST(RelationsTest, ParsesTheFreiburgFormatUsingXYAndYaw) {
  const auto parsed = ParseRelations(
      "# t1 t2 x y z roll pitch yaw\n\n"
      "976052905.167303 976052911.885496 -0.056990 -0.128430 0.000000 0.000000 0.000000 "
      "-1.682210\r\n"
      "1 2\t0.5 0.25 0 0 0 4\n",
      "intel.relations");
  ASSERT_TRUE(parsed.ok()) << parsed.Message();
  ASSERT_EQ(parsed.value().size(), 2u);
  EXPECT_DOUBLE_EQ(parsed.value()[0].t1, 976052905.167303);
  EXPECT_DOUBLE_EQ(parsed.value()[0].t2, 976052911.885496);
  EXPECT_DOUBLE_EQ(parsed.value()[0].motion.x, -0.056990);
  EXPECT_DOUBLE_EQ(parsed.value()[0].motion.y, -0.128430);
  EXPECT_DOUBLE_EQ(parsed.value()[0].motion.theta, -1.682210);
  EXPECT_NEAR(parsed.value()[1].motion.theta, 4.0 - 2 * kPi, 1e-12);  // wrapped
}

TEST(RelationsTest, ErrorsNameTheFileAndLine) {
  const auto parsed = ParseRelations(
      "1 2 0 0 0 0 0 0\n"
      "1 2 0 0 0 0 0\n"    // 7 fields
      "1 2 x 0 0 0 0 0\n"  // not a number
      "1 2 0 0 0 0 0 inf\n",
      "r.relations");
  ASSERT_FALSE(parsed.ok());
  const std::string message = parsed.Message();
  for (const char* expected : {"r.relations:2: expected 8 fields", "r.relations:3: field 3 \"x\"",
                               "r.relations:4: field 8 \"inf\""}) {
    EXPECT_NE(message.find(expected), std::string::npos) << expected << "\n" << message;
  }
  EXPECT_FALSE(ParseRelations("# nothing\n", "empty.relations").ok());
  const auto missing = LoadRelations("/nonexistent/intel.relations");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.Message().find("/nonexistent/intel.relations"), std::string::npos);
}

}  // namespace
}  // namespace slam::offline
