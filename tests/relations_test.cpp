#include "offline/relations.hpp"

#include <gtest/gtest.h>

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
