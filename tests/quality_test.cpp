#include "engine/quality.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "engine/random.hpp"

namespace slam {
namespace {

TEST(AlignRigid2D, RecoversARotationAndShift) {
  Rng rng(7);
  std::vector<Vec2> source, target;
  const RigidTransform2 truth{0.7, Vec2(1.5, -2.0)};
  for (int i = 0; i < 50; ++i) {
    source.emplace_back(rng.Uniform() * 3, rng.Uniform() * 2);
    target.push_back(truth.Apply(source.back()));
  }
  const RigidTransform2 found = AlignRigid2D(source, target);
  EXPECT_NEAR(found.rotation_rad, 0.7, 1e-12);
  EXPECT_NEAR(found.translation.x(), 1.5, 1e-12);
  EXPECT_NEAR(found.translation.y(), -2.0, 1e-12);
}

TEST(EvaluateTrajectory, ARotatedShiftedCopyScoresZero) {
  std::vector<TimedPose> reference, estimate;
  const Pose2 frame{0.3, -1.2, 2.5};  // the estimate lives in another frame
  for (int i = 0; i <= 100; ++i) {
    const double t = i * 0.1;
    const Pose2 p{std::cos(t), 0.5 * std::sin(2 * t), t};
    reference.push_back({t, p});
    estimate.push_back({t, Compose(frame, p)});
  }
  const auto q = EvaluateTrajectory(estimate, reference);
  ASSERT_TRUE(q);
  EXPECT_EQ(q->matched, 101);
  EXPECT_NEAR(q->q_cm2, 0.0, 1e-12);
  EXPECT_NEAR(q->e, 0.0, 1e-12);
  EXPECT_NEAR(q->ate_rmse_m, 0.0, 1e-7);
}

// Hand computation: residuals after the (identity) optimal alignment are 1, 2 and 1 cm, so
// q = -(1 + 4 + 1) / 3 = -2 cm^2, e = log(3), ATE = sqrt(2e-4) m.
TEST(EvaluateTrajectory, ThreePointsByHand) {
  const std::vector<TimedPose> estimate = {{0, {0, 0, 0}}, {1, {1, 0, 0}}, {2, {2, 0, 0}}};
  const std::vector<TimedPose> reference = {
      {0, {0, 0.01, 0}}, {1, {1, -0.02, 0}}, {2, {2, 0.01, 0}}};
  const auto q = EvaluateTrajectory(estimate, reference);
  ASSERT_TRUE(q);
  EXPECT_NEAR(q->alignment.rotation_rad, 0.0, 1e-12);
  EXPECT_NEAR(q->q_cm2, -2.0, 1e-9);
  EXPECT_NEAR(q->e, std::log(3.0), 1e-9);
  EXPECT_NEAR(q->ate_rmse_m, std::sqrt(2e-4), 1e-12);
}

TEST(EvaluateTrajectory, AssociatesByTimeWithInterpolation) {
  // The estimate is known at 1 Hz on a straight line; the reference at 10 Hz on the same line.
  std::vector<TimedPose> estimate, reference;
  for (int i = 0; i <= 5; ++i) estimate.push_back({double(i), {0.2 * i, 0, 0}});
  for (int i = -5; i <= 60; ++i) reference.push_back({i * 0.1, {0.02 * i, 0, 0}});
  const auto q = EvaluateTrajectory(estimate, reference);
  ASSERT_TRUE(q);
  EXPECT_EQ(q->matched, 51);  // only the reference poses inside [0, 5] s
  EXPECT_NEAR(q->ate_rmse_m, 0.0, 1e-9);
  EXPECT_FALSE(EvaluateTrajectory(estimate, {{10.0, {}}, {11.0, {}}}));
}

TEST(PoseAt, InterpolatesTheShortWayRound) {
  const std::vector<TimedPose> traj = {{0, {0, 0, DegToRad(170)}}, {2, {2, 4, DegToRad(-170)}}};
  const auto mid = PoseAt(traj, 1.0);
  ASSERT_TRUE(mid);
  EXPECT_NEAR(mid->x, 1.0, 1e-12);
  EXPECT_NEAR(mid->y, 2.0, 1e-12);
  EXPECT_NEAR(std::abs(mid->theta), kPi, 1e-9);
  EXPECT_FALSE(PoseAt(traj, -0.1));
  EXPECT_FALSE(PoseAt(traj, 2.1));
}

TEST(ErrorLowerBound, NoPrefixScoresBelowItAndTheWholeRunMeetsIt) {
  // An estimate that drifts away from the reference (a random walk of errors): every prefix's
  // bound is at most the whole run's e, grows with the prefix, and equals e on the whole run.
  Rng rng(11);
  std::vector<TimedPose> reference, estimate;
  Vec2 error = Vec2::Zero();
  for (int i = 0; i <= 400; ++i) {
    const double t = 0.05 * i;
    const Pose2 truth{std::cos(0.3 * t), std::sin(0.5 * t), 0.1 * t};
    reference.push_back({t, truth});
    error += Vec2(rng.Gaussian(0.003), rng.Gaussian(0.003));
    estimate.push_back({t, {truth.x + error.x(), truth.y + error.y(), truth.theta}});
  }
  const auto whole = EvaluateTrajectory(estimate, reference);
  ASSERT_TRUE(whole);
  ASSERT_GT(whole->e, 0.5);
  double last = 0.0;
  for (size_t end = 1; end <= estimate.size(); end += 7) {
    const std::vector<TimedPose> prefix(estimate.begin(),
                                        estimate.begin() + static_cast<std::ptrdiff_t>(end));
    const double bound = ErrorLowerBound(prefix, reference);
    EXPECT_LE(bound, whole->e * (1 + 1e-12)) << end;
    EXPECT_GE(bound, last - 1e-12) << end;
    last = bound;
  }
  EXPECT_GT(last, 0.5 * whole->e);  // it does bound: late prefixes come close
  EXPECT_NEAR(ErrorLowerBound(estimate, reference), whole->e, 1e-12);
  EXPECT_EQ(ErrorLowerBound({}, reference), 0.0);
  EXPECT_EQ(ErrorLowerBound({estimate.front()}, reference), 0.0);  // fewer than two matched
}

/// A 200 s loop at 10 Hz; its estimate in `frame` with centimetre noise, and from 100 s to
/// 135 s (a kidnap found late) carried off by `off` as well.
struct LostStretch {
  std::vector<TimedPose> reference, estimate;
};
LostStretch MakeLostStretch(const Pose2& frame, const Pose2& off) {
  Rng rng(11);
  LostStretch run;
  for (int i = 0; i <= 2000; ++i) {
    const double t = 0.1 * i;
    const Pose2 p{3.0 * std::cos(t / 20.0), 2.0 * std::sin(t / 10.0), t / 20.0};
    run.reference.push_back({t, p});
    Pose2 e = Compose(frame, t >= 100.0 && t < 135.0 ? Compose(off, p) : p);
    e.x += 0.01 * rng.Gaussian();
    e.y += 0.01 * rng.Gaussian();
    run.estimate.push_back({t, e});
  }
  return run;
}

double ShiftAt(const RigidTransform2& a, const RigidTransform2& b, const Vec2& p) {
  return (a.Apply(p) - b.Apply(p)).norm();
}

TEST(AlignOnMajority, ALostStretchIsLeftOutWhereLeastSquaresSplitsTheDifference) {
  const Pose2 frame{0.4, -0.7, 0.9};
  const RigidTransform2 truth = RigidTransform2{frame.theta, frame.translation()}.Inverse();
  const LostStretch lost = MakeLostStretch(frame, Pose2{0.8, -0.3, 0.4});
  const auto least_squares = EvaluateTrajectory(lost.estimate, lost.reference);
  const auto majority = AlignOnMajority(lost.estimate, lost.reference);
  ASSERT_TRUE(least_squares && majority);
  for (const Vec2& p : {Vec2(0.0, 0.0), Vec2(3.0, 2.0), Vec2(-3.0, -2.0)}) {
    EXPECT_LT(ShiftAt(*majority, truth, p), 0.005) << p.transpose();
    EXPECT_GT(ShiftAt(least_squares->alignment, truth, p), 0.05) << p.transpose();
  }
  EXPECT_NEAR(NormalizeAngle(majority->rotation_rad - truth.rotation_rad), 0.0, 0.002);

  // Without the stretch, the poses agree throughout: the least-squares fit, all but the tail.
  const LostStretch tracked = MakeLostStretch(frame, Pose2{});
  const auto fit = EvaluateTrajectory(tracked.estimate, tracked.reference);
  const auto kept = AlignOnMajority(tracked.estimate, tracked.reference);
  ASSERT_TRUE(fit && kept);
  EXPECT_LT(ShiftAt(*kept, fit->alignment, {3.0, 2.0}), 0.002);
  EXPECT_LT(ShiftAt(*kept, truth, {3.0, 2.0}), 0.003);

  // Fewer than two poses to fit: none.
  EXPECT_FALSE(AlignOnMajority({{5.0, Pose2{}}}, lost.reference));
  EXPECT_FALSE(AlignOnMajority(lost.estimate, {}));
}

}  // namespace
}  // namespace slam

TEST(RigidTransform2, InverseUndoesAndTransformsTrajectories) {
  const slam::RigidTransform2 a{0.7, {1.5, -2.0}};
  const slam::RigidTransform2 back = a.Inverse();
  const slam::Vec2 p{0.3, 0.4};
  const slam::Vec2 round_trip = back.Apply(a.Apply(p));
  EXPECT_NEAR(round_trip.x(), 0.3, 1e-12);
  EXPECT_NEAR(round_trip.y(), 0.4, 1e-12);

  const std::vector<slam::TimedPose> trajectory{{1.0, {1.0, 0.0, 0.0}}, {2.0, {0.0, 1.0, 3.0}}};
  const auto moved = slam::TransformTrajectory(a, trajectory);
  ASSERT_EQ(moved.size(), 2u);
  const slam::Vec2 expected = a.Apply({1.0, 0.0});
  EXPECT_NEAR(moved[0].pose.x, expected.x(), 1e-12);
  EXPECT_NEAR(moved[0].pose.y, expected.y(), 1e-12);
  EXPECT_NEAR(moved[0].pose.theta, 0.7, 1e-12);
  EXPECT_NEAR(moved[1].pose.theta, slam::NormalizeAngle(3.7), 1e-12);
  EXPECT_EQ(moved[1].t, 2.0);
  const auto restored = slam::TransformTrajectory(back, moved);
  EXPECT_NEAR(restored[1].pose.x, 0.0, 1e-12);
  EXPECT_NEAR(restored[1].pose.y, 1.0, 1e-12);
  EXPECT_NEAR(restored[1].pose.theta, 3.0, 1e-12);
}
