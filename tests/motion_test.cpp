#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "engine/fast_math.hpp"
#include "engine/odometry.hpp"
#include "engine/slam.hpp"
#include "test_support.hpp"

namespace slam {
namespace {

TEST(OdometryIntegrator, TranslationFromEncodersRotationFromGyro) {
  BaseDescription base;
  base.ticks_per_m = 10000;
  base.gyro_unit_dps = 0.01;
  OdometryIntegrator odo(base);
  odo.Add({0.0, 0, 1000, 1000, 0});
  // 0.1 m straight: both treels advance 1000 ticks.
  Pose2 p = odo.Add({0.5, 1, 2000, 2000, 0});
  EXPECT_NEAR(p.x, 0.1, 1e-12);
  EXPECT_NEAR(p.y, 0.0, 1e-12);
  // Turning in place at 90 deg/s for 0.2 s: the encoders disagree, the gyro decides.
  odo.Add({0.6, 2, 2000, 2000, 9000});
  p = odo.Add({0.8, 3, 1500, 2500, 9000});
  EXPECT_NEAR(p.x, 0.1, 1e-12);
  EXPECT_NEAR(RadToDeg(p.theta), 90.0 * 0.2 + 0.5 * 90.0 * 0.1, 1e-9);  // trapezoid from 0.5 s
}

TEST(OdometryIntegrator, AcrossAGapTheEncodersGiveTheRotation) {
  // Readings 2 s apart (lost, or a log's clock jump made up the time): the two gyro rates say
  // nothing of the turn between them; the treels' ticks do.
  BaseDescription base;
  base.ticks_per_m = 10000;
  base.track_width_m = 0.15;
  base.gyro_unit_dps = 0.01;
  OdometryIntegrator odo(base);
  odo.Add({0.0, 0, 0, 0, 9000});
  // The left treel back 0.05 m, the right forward 0.05 m: a turn of 0.1 / 0.15 rad in place.
  const Pose2 p = odo.Add({2.0, 1, -500, 500, 9000});
  EXPECT_NEAR(p.x, 0.0, 1e-12);
  EXPECT_NEAR(p.y, 0.0, 1e-12);
  EXPECT_NEAR(p.theta, 0.1 / 0.15, 1e-12);
  // Just within the step, the gyro still decides.
  OdometryIntegrator near(base);
  near.Add({0.0, 0, 0, 0, 9000});
  const Pose2 q = near.Add({OdometryIntegrator::kMaxGyroStepS, 1, -500, 500, 9000});
  EXPECT_NEAR(RadToDeg(q.theta), 90.0 * OdometryIntegrator::kMaxGyroStepS, 1e-9);
}

TEST(OdometryIntegrator, EncoderCountersWrapAround) {
  BaseDescription base;
  base.ticks_per_m = 10000;
  OdometryIntegrator odo(base);
  const int32_t near_max = std::numeric_limits<int32_t>::max() - 500;
  odo.Add({0.0, 0, near_max, near_max, 0});
  const auto wrapped = static_cast<int32_t>(static_cast<uint32_t>(near_max) + 1000u);
  ASSERT_LT(wrapped, 0);
  const Pose2 p = odo.Add({0.1, 1, near_max, wrapped, 0});
  // Left did not move; right wrapped past INT32_MAX by 500 and moved 1000 ticks: 0.05 m mean.
  EXPECT_NEAR(p.x, 0.05, 1e-12);
}

// A scan with odometry only (no readings), from odom_begin to odom_end.
Scan MotionOnlyScan(const Pose2& from, const Pose2& to) {
  Scan scan;
  scan.t_begin = 0.0;
  scan.t_end = 1.0;
  scan.odom_begin = from;
  scan.odom_end = to;
  return scan;
}

TEST(MotionModel, ZeroNoiseReproducesOdometryExactly) {
  SlamParams params;
  params.dist_error_ratio = params.dist_error_const_m = 0;
  params.angle_error_ratio = params.angle_error_const_deg = 0;
  Slam slam(testing::ShippedRobot(), params, SlamConfig{});
  const Pose2 start{1.0, 2.0, 0.5};  // the odometry frame differs from the map frame
  Pose2 odom = start, expected{};
  for (int i = 0; i < 20; ++i) {
    const Pose2 step{0.03, 0.004 * (i % 3), 0.1 * std::sin(i)};
    const Pose2 next = Compose(odom, step);
    expected = Compose(expected, step);
    slam.ProcessScan(MotionOnlyScan(odom, next), ScanPlan{});
    odom = next;
  }
  EXPECT_NEAR(slam.Best().pose.x, expected.x, 1e-9);
  EXPECT_NEAR(slam.Best().pose.y, expected.y, 1e-9);
  EXPECT_NEAR(slam.Best().pose.theta, expected.theta, 1e-9);
}

TEST(MotionModel, SeededNoiseHasTheConfiguredSpread) {
  SlamParams params;
  params.dist_error_ratio = 0.1;
  params.dist_error_const_m = 0.01;
  params.angle_error_ratio = 0.2;
  params.angle_error_const_deg = 1.0;
  params.particles = 4000;
  params.resampling_period_scans = 1000;  // keep the particles as drawn
  Slam slam(testing::ShippedRobot(), params, SlamConfig{});
  ScanPlan plan;
  plan.particles = params.particles;
  // Straight ahead 0.5 m: rot1 = rot2 = 0, so the spread is sigma_trans = 0.1 * 0.5 + 0.01 = 0.06
  // along x, and sigma_rot = 1 deg per rotation, so heading spread sqrt(2) deg.
  slam.ProcessScan(MotionOnlyScan({}, {0.5, 0, 0}), plan);
  double sx = 0, sxx = 0, st = 0, stt = 0;
  for (const Particle& p : slam.particles()) {
    sx += p.pose.x;
    sxx += p.pose.x * p.pose.x;
    st += p.pose.theta;
    stt += p.pose.theta * p.pose.theta;
  }
  const double n = static_cast<double>(slam.particles().size());
  const double mean_x = sx / n, sd_x = std::sqrt(sxx / n - mean_x * mean_x);
  const double mean_t = st / n, sd_t = std::sqrt(stt / n - mean_t * mean_t);
  EXPECT_NEAR(mean_x, 0.5, 0.004);
  EXPECT_NEAR(sd_x, 0.06, 0.003);
  EXPECT_NEAR(RadToDeg(sd_t), std::sqrt(2.0), 0.07);

  // Same seed, same draws; another seed, other draws.
  Slam again(testing::ShippedRobot(), params, SlamConfig{});
  again.ProcessScan(MotionOnlyScan({}, {0.5, 0, 0}), plan);
  EXPECT_EQ(again.particles()[17].pose.x, slam.particles()[17].pose.x);
  SlamConfig other;
  other.seed = 2;
  Slam different(testing::ShippedRobot(), params, other);
  different.ProcessScan(MotionOnlyScan({}, {0.5, 0, 0}), plan);
  EXPECT_NE(different.particles()[17].pose.x, slam.particles()[17].pose.x);
}

TEST(MotionModel, ReversingIsANegativeTranslationNotAHalfTurn) {
  SlamParams params;
  params.dist_error_ratio = params.dist_error_const_m = 0;
  params.angle_error_ratio = 0.5;
  params.angle_error_const_deg = 0;
  Slam slam(testing::ShippedRobot(), params, SlamConfig{});
  slam.ProcessScan(MotionOnlyScan({}, {-0.1, 0, 0}), ScanPlan{});
  // Angle noise is proportional to the rotations, which are zero when backing up straight.
  EXPECT_NEAR(slam.Best().pose.x, -0.1, 1e-12);
  EXPECT_NEAR(slam.Best().pose.theta, 0.0, 1e-12);
}

TEST(SmallTurn, AgreesWithLibmToTheLastBitsOverItsDomain) {
  // Every turn a candidate's correction gives a sample, up to kSmallTurnRad either way.
  int exact = 0, n = 0;
  for (double a = -kSmallTurnRad; a <= kSmallTurnRad; a += 1e-4, ++n) {
    const auto [c, s] = SmallTurn(a);
    EXPECT_NEAR(c, std::cos(a), 2.3e-16) << a;
    EXPECT_NEAR(s, std::sin(a), 2.3e-16) << a;
    exact += (c == std::cos(a) && s == std::sin(a)) ? 1 : 0;
  }
  EXPECT_GT(exact, n / 4);  // mostly bit for bit
  EXPECT_EQ(SmallTurn(0.0), (std::pair<double, double>{1.0, 0.0}));
  EXPECT_EQ(SmallTurn(-0.3).second, -SmallTurn(0.3).second);  // odd and even as they should be
  EXPECT_EQ(SmallTurn(-0.3).first, SmallTurn(0.3).first);
}

TEST(NormalizeAngle, GivesStdRemaindersAnswersBitForBit) {
  // The fast paths (in range, one turn out) against the formula they replace, at the boundaries
  // (pi, 3 pi and their neighbours) and over many turns either way.
  const auto reference = [](double a) {
    a = std::remainder(a, 2.0 * kPi);
    return a <= -kPi ? a + 2.0 * kPi : a;
  };
  std::vector<double> angles = {0.0,       -0.0,       kPi, -kPi, 2.0 * kPi, -2.0 * kPi,
                                3.0 * kPi, -3.0 * kPi, 8.0, -8.0, 1e6,       -1e6};
  for (const double edge : std::vector<double>(angles)) {
    angles.push_back(std::nextafter(edge, 1e9));
    angles.push_back(std::nextafter(edge, -1e9));
  }
  for (double a = -30.0; a <= 30.0; a += 1e-3) angles.push_back(a);
  for (const double a : angles) {
    const double got = NormalizeAngle(a), want = reference(a);
    EXPECT_EQ(std::signbit(got), std::signbit(want)) << a;
    EXPECT_EQ(got, want) << a;
    EXPECT_GT(got, -kPi) << a;
    EXPECT_LE(got, kPi) << a;
  }
  EXPECT_TRUE(std::isnan(NormalizeAngle(std::numeric_limits<double>::quiet_NaN())));
}

}  // namespace
}  // namespace slam
