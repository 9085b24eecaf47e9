// The filter's parts on their own, on tiny maps drawn cell by cell where every answer is known:
// the scan matcher (eq. 2, the search, the peak fit, the match window), the motion model, the
// drift tracker and the particle set.
#include "engine/scan_matcher.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <memory>
#include <vector>

#include "engine/cell_encoding.hpp"
#include "engine/drift_tracker.hpp"
#include "engine/match_window.hpp"
#include "engine/matching_rays.hpp"
#include "engine/motion_model.hpp"
#include "engine/particle_set.hpp"
#include "engine/random.hpp"
#include "engine/scan_path.hpp"

namespace slam {
namespace {

constexpr double kCell = 0.05;
constexpr double kSigma = 0.02;
constexpr double kFloor = 0.05;

double Square(double x) { return x * x; }

std::vector<Particle> Particles(size_t count) {
  const OccupancyGrid empty(GridGeometry(kCell), EncodeLogOdds(5.0));
  return std::vector<Particle>(count, Particle{{}, 0.0, empty, nullptr});
}

// A square room of 5 cm cells: walls one cell thick whose inner faces lie at x, y = +-1 m
// (cells -21 and 20), and a pillar of one cell at (0.50, 0.30) to break its symmetry.
OccupancyGrid DrawnRoom() {
  OccupancyGrid grid(GridGeometry(kCell), EncodeLogOdds(5.0));
  grid.BeginWrite();
  const int wall = EncodeLogOdds(3.0);
  for (int k = -21; k <= 20; ++k) {
    grid.Add({20, k}, wall);
    grid.Add({-21, k}, wall);
    grid.Add({k, 20}, wall);
    grid.Add({k, -21}, wall);
  }
  grid.Add({10, 6}, wall);
  grid.RefreshSummaries();
  return grid;
}

MatcherConfig Config(bool parallel = false) {
  MatcherConfig config;
  config.occupied_above = EncodeLogOdds(0.0);
  config.match_floor = kFloor;
  config.sweep_step_rad = DegToRad(2.0);
  config.parallel = parallel;
  return config;
}

// A scan of a robot standing still at the odometry's origin: one sample per reading. Its paths
// take the whole of a correction from the first sample on (start share 1): the scan moves as one.
Scan StillScan(size_t samples) {
  Scan scan;
  scan.t_begin = 0.0;
  scan.t_end = 1.0;
  for (size_t i = 0; i < samples; ++i) {
    ScanSample s;
    s.t = static_cast<double>(i + 1) / static_cast<double>(samples);
    scan.samples.push_back(s);
  }
  return scan;
}

// A reading of sample `sample` from the robot's centre along `angle` (robot frame).
Measurement Reading(size_t sample, double angle, double distance) {
  Measurement m;
  m.sample = sample;
  m.local_angle = angle;
  m.local_direction = Vec2(std::cos(angle), std::sin(angle));
  m.distance_m = distance;
  m.sigma_m = kSigma;
  m.match_range_m = distance + 3.0 * kSigma;
  return m;
}

std::vector<const Measurement*> Pointers(const std::vector<Measurement>& readings) {
  std::vector<const Measurement*> out;
  for (const Measurement& m : readings) out.push_back(&m);
  return out;
}

// What a perfect sensor at `truth` reads on `grid` along `count` directions evenly around: the
// middle of each ray's crossing of the first occupied cell (where eq. 2 expects the surface).
std::vector<Measurement> PerfectReadings(const OccupancyGrid& grid, const Pose2& truth,
                                         size_t count) {
  std::vector<Measurement> readings;
  for (size_t i = 0; i < count; ++i) {
    const double angle = 2.0 * kPi * static_cast<double>(i) / static_cast<double>(count);
    const RayHit hit =
        CastToObstacle(grid, truth.translation(),
                       Vec2(std::cos(truth.theta + angle), std::sin(truth.theta + angle)), 5.0,
                       EncodeLogOdds(0.0));
    EXPECT_TRUE(hit.hit);
    readings.push_back(Reading(i, angle, 0.5 * (hit.distance_m + hit.exit_m)));
  }
  return readings;
}

TEST(ScanMatcher, LogLikelihoodIsEquationTwoOnADrawnWall) {
  const OccupancyGrid grid = DrawnRoom();
  const Scan scan = StillScan(2);
  const ScanPath path(scan, Pose2{}, 1.0);
  // Along +x the first occupied cell spans [1.00, 1.05): the surface is expected at 1.025 m. A
  // reading of 1.01 m lies 0.75 sigma short of it. Along -x, a reading of 0.5 m looks 0.56 m
  // and meets nothing: the floor alone.
  const std::vector<Measurement> readings = {Reading(0, 0.0, 1.01), Reading(1, kPi, 0.5)};
  const ScanMatcher matcher(Config());
  const double expected = std::log(std::exp(-0.5 * 0.75 * 0.75) + kFloor) + std::log(kFloor);
  EXPECT_NEAR(matcher.LogLikelihood(grid, nullptr, path, Pose2{}, Pointers(readings)), expected,
              1e-12);
  // Moved 1.5 cm towards the wall, the reading sits on the expected surface.
  const double moved =
      matcher.LogLikelihood(grid, nullptr, path, Pose2{0.015, 0.0, 0.0}, Pointers(readings));
  EXPECT_NEAR(moved, std::log(1.0 + kFloor) + std::log(kFloor), 1e-12);
}

TEST(ScanMatcher, AWindowGivesTheGridsAnswersBitForBit) {
  const OccupancyGrid grid = DrawnRoom();
  const Pose2 truth{0.12, -0.07, 0.2};
  const std::vector<Measurement> readings = PerfectReadings(grid, truth, 36);
  const Scan scan = StillScan(readings.size());
  const ScanPath path(scan, Pose2{}, 1.0);
  const MatchWindow window(grid, EncodeLogOdds(0.0), {-30, -30}, {30, 30});
  const ScanMatcher matcher(Config());
  Rng rng(7);
  for (int i = 0; i < 50; ++i) {
    const Pose2 end{truth.x + rng.Normal(0.05), truth.y + rng.Normal(0.05),
                    truth.theta + rng.Normal(0.05)};
    EXPECT_EQ(
        matcher.LogLikelihood(grid, &window, path, path.CorrectionTo(end), Pointers(readings)),
        matcher.LogLikelihood(grid, nullptr, path, path.CorrectionTo(end), Pointers(readings)));
  }
}

// One particle's request for `truth`'s readings, predicted at `predicted`.
struct Problem {
  OccupancyGrid grid = DrawnRoom();
  std::vector<Measurement> readings;
  Scan scan;
  std::unique_ptr<ScanPath> path;
  MatchRequest request;

  Problem(const Pose2& truth, const Pose2& predicted, size_t count = 36) {
    readings = PerfectReadings(grid, truth, count);
    scan = StillScan(readings.size());
    path = std::make_unique<ScanPath>(scan, Pose2{}, 1.0);
    request = {&grid, nullptr, path.get(), predicted, predicted};
  }
};

MatchSearch Search(size_t candidates) {
  MatchSearch search;
  search.candidates = candidates;
  search.search = {0.04, DegToRad(3.0)};
  search.prior = {10.0, 10.0};  // too wide to pull: the readings decide
  return search;
}

TEST(ScanMatcher, FindsTheTruePoseFromAPredictionOffByACellAndTwoDegrees) {
  const Pose2 truth{0.12, -0.07, 0.2};
  const Problem problem(truth, {truth.x + 0.04, truth.y - 0.03, truth.theta + DegToRad(2.0)});
  const ScanMatcher matcher(Config());
  const auto matching = Pointers(problem.readings);
  const MatchResult result = matcher.Match({&problem.request, 1}, matching, Search(200), 1);
  ASSERT_EQ(result.chosen.size(), 1u);
  EXPECT_LT(std::hypot(result.chosen[0].x - truth.x, result.chosen[0].y - truth.y), 0.01);
  EXPECT_LT(std::abs(NormalizeAngle(result.chosen[0].theta - truth.theta)), DegToRad(0.5));
  // The weight is the best candidate's log-likelihood: above the prediction's.
  const double predicted_ll =
      matcher.LogLikelihood(problem.grid, nullptr, *problem.path,
                            problem.path->CorrectionTo(problem.request.predicted), matching);
  EXPECT_GT(result.chosen_ll[0], predicted_ll + 10.0);
  EXPECT_EQ(result.rays, int64_t{200} * 36);
  EXPECT_FALSE(result.interrupted);
}

TEST(ScanMatcher, SerialAndParallelSearchesGiveTheSameAnswers) {
  const Pose2 truth{-0.2, 0.3, -0.4};
  const Problem a(truth, {truth.x + 0.03, truth.y, truth.theta - 0.03});
  const Problem b(truth, {truth.x - 0.02, truth.y + 0.02, truth.theta + 0.02});
  const std::vector<MatchRequest> requests = {a.request, b.request};
  const auto matching = Pointers(a.readings);  // the same readings: the same truth
  const MatchResult serial = ScanMatcher(Config(false)).Match(requests, matching, Search(64), 5);
  const MatchResult parallel = ScanMatcher(Config(true)).Match(requests, matching, Search(64), 5);
  for (size_t p = 0; p < 2; ++p) {
    EXPECT_EQ(serial.chosen[p].x, parallel.chosen[p].x);
    EXPECT_EQ(serial.chosen[p].y, parallel.chosen[p].y);
    EXPECT_EQ(serial.chosen[p].theta, parallel.chosen[p].theta);
    EXPECT_EQ(serial.chosen_ll[p], parallel.chosen_ll[p]);
  }
  EXPECT_EQ(serial.ambiguity, parallel.ambiguity);
}

TEST(ScanMatcher, AnInterruptKeepsEachParticlesPrediction) {
  const Pose2 truth{0.1, 0.1, 0.1};
  const Pose2 predicted{0.13, 0.1, 0.12};
  const Problem problem(truth, predicted);
  const std::atomic<bool> interrupt{true};
  const MatchResult result = ScanMatcher(Config()).Match(
      {&problem.request, 1}, Pointers(problem.readings), Search(100), 1, &interrupt);
  EXPECT_TRUE(result.interrupted);
  EXPECT_EQ(result.rays, 36);  // the first candidate alone
  EXPECT_EQ(result.chosen[0].x, predicted.x);
  EXPECT_EQ(result.chosen[0].theta, predicted.theta);
}

// Candidates on a lattice around `best` whose log-likelihood is a quadratic with its peak at
// `peak` (flat along y when `flat_y`).
struct Lattice {
  std::vector<Pose2> poses;
  std::vector<double> ll;
};
Lattice QuadraticLattice(const Pose2& best, const Pose2& peak, Spread search, bool flat_y) {
  Lattice out;
  for (int i = -2; i <= 2; ++i) {
    for (int j = -2; j <= 2; ++j) {
      for (int k = -2; k <= 2; ++k) {
        const Pose2 p{best.x + 0.5 * i * search.pos, best.y + 0.5 * j * search.pos,
                      best.theta + 0.5 * k * search.angle};
        const double u = (p.x - peak.x) / search.pos, v = (p.y - peak.y) / search.pos,
                     t = (p.theta - peak.theta) / search.angle;
        out.poses.push_back(p);
        out.ll.push_back(-3.0 * u * u - (flat_y ? 0.0 : 2.0 * v * v) - 4.0 * t * t + u * t);
      }
    }
  }
  return out;
}

TEST(FittedPeak, FindsAQuadraticsPeakBetweenTheCandidates) {
  const Spread search{0.02, 0.03};
  const Pose2 best{1.0, 2.0, 0.5};
  const Pose2 peak{1.013, 1.991, 0.517};
  const Lattice lattice = QuadraticLattice(best, peak, search, false);
  // A prior too wide to count: the fit is the quadratic's own peak.
  const std::optional<Pose2> fit =
      FittedPeak(lattice.poses, lattice.ll, 1000, best, best, search, {1e4, 1e4});
  ASSERT_TRUE(fit);
  EXPECT_NEAR(fit->x, peak.x, 1e-6);
  EXPECT_NEAR(fit->y, peak.y, 1e-6);
  EXPECT_NEAR(fit->theta, peak.theta, 1e-6);
}

TEST(FittedPeak, WhereTheLikelihoodIsFlatThePriorDecides) {
  const Spread search{0.02, 0.03};
  const Pose2 best{0.0, 0.0, 0.0};
  const Pose2 peak{0.01, 0.0, -0.01};
  const Lattice lattice = QuadraticLattice(best, peak, search, true);
  const Pose2 nominal{0.0, 0.025, 0.0};  // the odometry's end, off along the flat direction
  const std::optional<Pose2> fit =
      FittedPeak(lattice.poses, lattice.ll, 1000, best, nominal, search, {0.05, 1e4});
  ASSERT_TRUE(fit);
  EXPECT_NEAR(fit->y, nominal.y, 1e-6);  // the readings said nothing about y
  EXPECT_NEAR(fit->x, peak.x, 2e-3);     // they did about x (the prior pulls a little)
}

TEST(FittedPeak, RefusesTooFewCandidatesAndAPeakBeyondTwoSpreads) {
  const Spread search{0.02, 0.03};
  const Pose2 best{0.0, 0.0, 0.0};
  Lattice lattice = QuadraticLattice(best, {0.01, 0.0, 0.0}, search, false);
  const size_t few = kPeakFitMinCandidates - 1;
  EXPECT_FALSE(FittedPeak(std::span(lattice.poses).first(few), std::span(lattice.ll).first(few),
                          1000, best, best, search, {1e4, 1e4}));
  const Lattice far = QuadraticLattice(best, {0.1, 0.0, 0.0}, search, false);  // 5 spreads
  EXPECT_FALSE(FittedPeak(far.poses, far.ll, 1000, best, best, search, {1e4, 1e4}));
}

TEST(PlanWindow, CoversTheRaysAndIsRefusedNearTheBoundOrWhenRaysAreFew) {
  const Pose2 truth{0.1, 0.1, 0.1};
  const Problem problem(truth, truth);
  const GridGeometry geometry(kCell);
  const auto matching = Pointers(problem.readings);
  const std::optional<WindowBounds> window =
      PlanWindow(geometry, *problem.path, truth, matching, Search(100));
  ASSERT_TRUE(window);
  // Every ray's end (the walls, within 1.1 m) lies inside, with the padding around.
  EXPECT_LE(window->lo.x, -22);
  EXPECT_LE(window->lo.y, -22);
  EXPECT_GE(window->hi.x, 21);
  EXPECT_GE(window->hi.y, 21);
  // One candidate's 36 rays do not pay for a window of about 60 x 60 cells.
  EXPECT_FALSE(PlanWindow(geometry, *problem.path, truth, matching, Search(1)));
  // Past the map's bound, the rays go through the grid.
  const double edge = (kMapCellBound - 5) * kCell;
  const Scan scan = StillScan(problem.readings.size());
  const ScanPath far(scan, Pose2{edge, 0.0, 0.0}, 1.0);
  EXPECT_FALSE(PlanWindow(geometry, far, Pose2{edge, 0.0, 0.0}, matching, Search(100)));
}

TEST(MotionModel, DecomposesForwardAndBackwardMotionAndRecomposesIt) {
  const Pose2 forward{0.3, 0.1, 0.4};
  const MotionDelta f = Decompose(forward);
  EXPECT_GT(f.trans, 0.0);
  const Pose2 back{-0.2, 0.05, -0.1};
  const MotionDelta b = Decompose(back);
  EXPECT_LT(b.trans, 0.0);  // reversing is not a half-turn
  EXPECT_LT(std::abs(b.rot1), kPi / 2);
  for (const Pose2& p : {forward, back, Pose2{0.0, 0.0, 0.7}}) {
    const Pose2 r = Recompose(Decompose(p));
    EXPECT_NEAR(r.x, p.x, 1e-12);
    EXPECT_NEAR(r.y, p.y, 1e-12);
    EXPECT_NEAR(r.theta, p.theta, 1e-12);
  }
}

TEST(MotionModel, NoiseGrowsWithEachPartAndDrawsSpreadByIt) {
  SlamParams params;
  params.dist_error_ratio = 0.1;
  params.dist_error_const_m = 0.01;
  params.angle_error_ratio = 0.2;
  params.angle_error_const_deg = 1.0;
  const MotionDelta motion{0.5, -0.3, -0.1};
  const MotionNoise noise = OdometryNoise(params, motion);
  EXPECT_DOUBLE_EQ(noise.trans, 0.1 * 0.3 + 0.01);
  EXPECT_DOUBLE_EQ(noise.rot1, 0.2 * 0.5 + DegToRad(1.0));
  EXPECT_DOUBLE_EQ(noise.rot2, 0.2 * 0.1 + DegToRad(1.0));
  // Without noise the draw is the motion itself; with it, the ends spread as the translation's
  // deviation says (along the motion, about 4 cm).
  Rng quiet(1);
  const Pose2 start{1.0, 2.0, 0.3};
  const Pose2 exact = SampleMotion(start, motion, MotionNoise{}, quiet);
  const Pose2 expected = Compose(start, Recompose(motion));
  EXPECT_NEAR(exact.x, expected.x, 1e-12);
  EXPECT_NEAR(exact.theta, expected.theta, 1e-12);
  Rng rng(2);
  double sum_sq = 0.0;
  const MotionNoise trans_only{noise.trans, 0.0, 0.0};
  for (int i = 0; i < 4000; ++i) {
    const Pose2 p = SampleMotion(start, motion, trans_only, rng);
    sum_sq += Square(p.x - expected.x) + Square(p.y - expected.y);
  }
  EXPECT_NEAR(std::sqrt(sum_sq / 4000), noise.trans, 0.1 * noise.trans);
}

TEST(DriftTracker, ALasersHeadingSearchNarrowsWithSmallCorrectionsButNotBelowAQuarter) {
  DriftTracker laser(/*heading_from_gyro=*/false, /*range_scanner=*/true);
  DriftTracker infrared(/*heading_from_gyro=*/true, /*range_scanner=*/false);
  const double set = DegToRad(8.0);
  EXPECT_EQ(laser.LeastSearchAngle(set), set);  // before any match
  Scan scan;
  scan.t_end = 0.2;
  scan.odom_end = {0.1, 0.0, 0.0};  // driving: its corrections count
  std::vector<Particle> particles = Particles(2);
  const std::vector<Pose2> nominal(2, Pose2{0.1, 0.0, 0.0});
  const std::vector<Pose2> chosen(2, Pose2{0.1, 0.0, DegToRad(0.1)});
  for (int i = 0; i < 300; ++i) {
    laser.LearnFromMatch(scan, 0.1, chosen, nominal, set, particles);
    infrared.LearnFromMatch(scan, 0.2, chosen, nominal, set, particles);
  }
  EXPECT_DOUBLE_EQ(laser.LeastSearchAngle(set), 0.25 * set);
  EXPECT_EQ(infrared.LeastSearchAngle(set), set);
  // The wheels' drift is learnt per metre, against the corrections: counter-clockwise
  // corrections mean the odometry turns clockwise, which the prediction takes out.
  EXPECT_LT(particles[0].heading_drift, 0.0);
}

TEST(DriftTracker, WhatTheMapDoesNotCorrectAccumulatesUntilAMatch) {
  DriftTracker tracker(true, false);
  const MotionNoise noise{0.01, DegToRad(1.0), DegToRad(1.0)};
  const double alone = tracker.DriftAngle(noise);
  EXPECT_NEAR(alone, std::hypot(noise.rot1, noise.rot2), 1e-15);
  for (int i = 0; i < 10; ++i) tracker.AddUncorrected(noise, 0.1);
  EXPECT_NEAR(tracker.DriftAngle(noise), std::sqrt(11.0) * alone, 1e-12);
  EXPECT_GT(tracker.DriftPos(noise), std::sqrt(10.0) * noise.trans);  // the heading's share too
  std::vector<Particle> particles = Particles(1);
  const std::vector<Pose2> poses(1);
  tracker.LearnFromMatch(Scan{}, 0.0, poses, poses, DegToRad(5.0), particles);
  EXPECT_NEAR(tracker.DriftAngle(noise), alone, 1e-15);
  EXPECT_NEAR(tracker.DriftPos(noise), noise.trans, 1e-15);
}

TEST(ParticleSet, ResamplingDrawsInProportionToTheWeights) {
  std::vector<Particle> particles = Particles(4);
  for (size_t i = 0; i < particles.size(); ++i) particles[i].pose.x = static_cast<double>(i);
  particles[2].log_weight = std::log(1000.0);  // all but certain
  EXPECT_EQ(BestIndex(particles), 2u);
  EXPECT_NEAR(EffectiveSampleSize(particles), 1.0, 0.01);
  Rng rng(3);
  Resample(particles, 6, rng);
  ASSERT_EQ(particles.size(), 6u);
  for (const Particle& p : particles) {
    EXPECT_EQ(p.pose.x, 2.0);
    EXPECT_EQ(p.log_weight, 0.0);
  }
  EXPECT_DOUBLE_EQ(EffectiveSampleSize(particles), 6.0);
  EXPECT_EQ(BestIndex(particles), 0u);  // the lowest index on ties
}

}  // namespace
}  // namespace slam
