#include "engine/scan_assembler.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "test_support.hpp"

namespace slam {
namespace {

// A robot driving straight along x at 0.1 m/s; the platform turns 1.5 half turns per second.
// Odometry at 50 Hz, samples at 60 Hz: 40 samples per half turn.
struct Stream {
  std::vector<OdometryReading> odometry;
  std::vector<ScannerReading> scanner;
};

Stream Straight(double duration_s, const RobotDescription& robot) {
  Stream s;
  for (int i = 0; i * 0.02 <= duration_s + 0.02; ++i) {
    OdometryReading r;
    r.t = 100.0 + 0.02 * i;
    r.seq = static_cast<uint16_t>(i);
    const auto ticks = std::llround(0.1 * 0.02 * i * robot.base.ticks_per_m);
    r.left_ticks = r.right_ticks = static_cast<int32_t>(ticks);
    s.odometry.push_back(r);
  }
  for (int i = 0; i / 60.0 <= duration_s; ++i) {
    ScannerReading r;
    r.t = 100.0 + i / 60.0;
    r.seq = static_cast<uint16_t>(i);
    r.angle_raw = static_cast<uint16_t>((i * 32768 / 40) & 0xFFFF);
    r.raw = {static_cast<uint16_t>(i & 0x3FF), 0, 0, 0};
    s.scanner.push_back(r);
  }
  return s;
}

std::vector<RobotEvent> Merge(const Stream& s) {
  std::vector<RobotEvent> events;
  for (const auto& r : s.odometry) events.emplace_back(r);
  for (const auto& r : s.scanner) events.emplace_back(r);
  std::stable_sort(events.begin(), events.end(), [](const RobotEvent& a, const RobotEvent& b) {
    return EventTime(a) < EventTime(b);
  });
  return events;
}

std::vector<Scan> Assemble(ScanAssembler& assembler, const std::vector<RobotEvent>& events) {
  std::vector<Scan> scans;
  for (const RobotEvent& e : events) assembler.Add(e, scans);
  return scans;
}

// Every scan begins where the previous one ended, also after an abandoned one: the motion in a
// gap reaches the SLAM (the robot drives straight at 0.1 m/s from x = 0 at t = 100 s).
void ExpectMotionCarriedAcross(const std::vector<Scan>& scans) {
  for (size_t k = 1; k < scans.size(); ++k) {
    EXPECT_EQ(scans[k].t_begin, scans[k - 1].t_end) << k;
    EXPECT_EQ(scans[k].odom_begin.x, scans[k - 1].odom_end.x) << k;
    EXPECT_EQ(scans[k].odom_begin.y, scans[k - 1].odom_end.y) << k;
    EXPECT_EQ(scans[k].odom_begin.theta, scans[k - 1].odom_end.theta) << k;
  }
  // The scans' motions add up to the distance driven from the first scan's start to the last
  // one's end.
  double driven = 0.0;
  for (const Scan& scan : scans) driven += scan.odom_end.x - scan.odom_begin.x;
  EXPECT_NEAR(driven, 0.1 * (scans.back().t_end - scans.front().t_begin), 4e-4);
}

TEST(ScanAssemblerTest, RegularStreamGivesContiguousHalfTurns) {
  const RobotDescription robot = testing::ShippedRobot();
  ScanAssembler assembler(robot);
  const auto scans = Assemble(assembler, Merge(Straight(10.0, robot)));
  ASSERT_EQ(scans.size(), 15u);  // 601 samples: 15 full half turns + 1 sample
  for (size_t k = 0; k < scans.size(); ++k) {
    EXPECT_EQ(scans[k].index, static_cast<int64_t>(k));
    EXPECT_EQ(scans[k].samples.size(), 40u);
    if (k > 0) {
      EXPECT_EQ(scans[k].t_begin, scans[k - 1].t_end);
    }
    for (const ScanSample& s : scans[k].samples) {
      EXPECT_NEAR(s.odom.x, 0.1 * (s.t - 100.0), 2e-4);
    }
  }
  const auto& c = assembler.counters();
  EXPECT_EQ(c.scans, 15u);
  EXPECT_EQ(c.samples_in_scans, 600u);
  EXPECT_EQ(c.out_of_order + c.samples_lost + c.odometry_lost + c.sample_gaps + c.odometry_gaps +
                c.odometry_jumps + c.samples_unposed + c.scans_discarded,
            0u);
}

TEST(ScanAssemblerTest, LateOdometryGivesTheSameScans) {
  // On a live link the base's events may arrive after the scanner's: delay every odometry
  // event by up to 30 ms in arrival order (times unchanged).
  const RobotDescription robot = testing::ShippedRobot();
  const Stream s = Straight(10.0, robot);
  std::vector<std::pair<double, RobotEvent>> arrivals;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> delay(0.0, 0.03);
  double last_odometry_arrival = 0.0;
  for (const auto& r : s.odometry) {
    last_odometry_arrival = std::max(last_odometry_arrival, r.t + delay(rng));
    arrivals.emplace_back(last_odometry_arrival, r);
  }
  for (const auto& r : s.scanner) arrivals.emplace_back(r.t, r);
  std::stable_sort(arrivals.begin(), arrivals.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<RobotEvent> late;
  for (const auto& [t, e] : arrivals) late.push_back(e);

  ScanAssembler a(robot), b(robot);
  const auto expected = Assemble(a, Merge(s));
  const auto got = Assemble(b, late);
  ASSERT_EQ(got.size(), expected.size());
  for (size_t k = 0; k < got.size(); ++k) {
    ASSERT_EQ(got[k].samples.size(), expected[k].samples.size());
    for (size_t i = 0; i < got[k].samples.size(); ++i) {
      EXPECT_EQ(got[k].samples[i].t, expected[k].samples[i].t);
      EXPECT_EQ(got[k].samples[i].odom.x, expected[k].samples[i].odom.x);
    }
  }
  EXPECT_EQ(b.counters().samples_unposed, 0u);
}

TEST(ScanAssemblerTest, LostSamplesAreCountedAndTheScanGoesOn) {
  const RobotDescription robot = testing::ShippedRobot();
  Stream s = Straight(4.0, robot);
  // Lose samples 45..49 (within the second half turn) and odometry readings 30..31.
  s.scanner.erase(s.scanner.begin() + 45, s.scanner.begin() + 50);
  s.odometry.erase(s.odometry.begin() + 30, s.odometry.begin() + 32);
  ScanAssembler assembler(robot);
  const auto scans = Assemble(assembler, Merge(s));
  ASSERT_EQ(scans.size(), 6u);
  EXPECT_EQ(scans[1].samples.size(), 35u);
  EXPECT_EQ(assembler.counters().samples_lost, 5u);
  EXPECT_EQ(assembler.counters().odometry_lost, 2u);
  EXPECT_EQ(assembler.counters().scans_discarded, 0u);
}

TEST(ScanAssemblerTest, ScannerSilenceDiscardsTheScanInProgress) {
  const RobotDescription robot = testing::ShippedRobot();
  Stream s = Straight(6.0, robot);
  // 0.5 s without samples in the middle of the third half turn (samples 90..119).
  s.scanner.erase(s.scanner.begin() + 90, s.scanner.begin() + 120);
  ScanAssembler assembler(robot);
  const auto scans = Assemble(assembler, Merge(s));
  const auto& c = assembler.counters();
  EXPECT_EQ(c.sample_gaps, 1u);
  EXPECT_EQ(c.scans_discarded, 1u);
  EXPECT_EQ(c.samples_lost, 30u);
  // Two scans before the gap; after it, grouping restarts at sample 120: 240 samples, 6 scans
  // (the last sample of the 361 begins an incomplete one).
  ASSERT_EQ(scans.size(), 8u);
  EXPECT_EQ(scans[2].samples.front().t, 100.0 + 120 / 60.0);
  for (const Scan& scan : scans) EXPECT_EQ(scan.samples.size(), 40u);
  ExpectMotionCarriedAcross(scans);
}

TEST(ScanAssemblerTest, OdometrySilenceDropsTheSamplesInIt) {
  const RobotDescription robot = testing::ShippedRobot();
  Stream s = Straight(6.0, robot);
  // Odometry stops for 0.6 s from t = 101.5 (readings 75..104).
  s.odometry.erase(s.odometry.begin() + 76, s.odometry.begin() + 105);
  ScanAssembler assembler(robot);
  const auto scans = Assemble(assembler, Merge(s));
  const auto& c = assembler.counters();
  EXPECT_EQ(c.odometry_gaps, 1u);
  EXPECT_EQ(c.odometry_lost, 29u);
  EXPECT_GE(c.samples_unposed, 34u);  // the samples in (101.5, 102.1)
  EXPECT_EQ(c.scans_discarded, 1u);
  for (const Scan& scan : scans) {
    EXPECT_EQ(scan.samples.size(), 40u);
    for (const ScanSample& sample : scan.samples) {
      EXPECT_FALSE(sample.t > 101.5 && sample.t < 102.1);
      EXPECT_NEAR(sample.odom.x, 0.1 * (sample.t - 100.0), 2e-4);
    }
  }
  ExpectMotionCarriedAcross(scans);
}

// The distance the scans' odometry covers, and the largest |x| of any sample.
struct Covered {
  double driven = 0.0;
  double max_abs_x = 0.0;
};
Covered CoveredBy(const std::vector<Scan>& scans) {
  Covered covered;
  for (const Scan& scan : scans) {
    covered.driven += scan.odom_end.x - scan.odom_begin.x;
    for (const ScanSample& sample : scan.samples) {
      covered.max_abs_x = std::max(covered.max_abs_x, std::abs(sample.odom.x));
    }
  }
  return covered;
}

TEST(ScanAssemblerTest, AnImpossibleOdometryJumpIsRefusedAndThePoseHolds) {
  // One spoofed reading (random counters, as a forged datagram carries) at t = 104 s: on its own
  // it would move the robot 40 km in 20 ms, and the map would try to cover both poses.
  const RobotDescription robot = testing::ShippedRobot();
  Stream s = Straight(10.0, robot);
  s.odometry[200].left_ticks = 471'000'000;
  s.odometry[200].right_ticks = -1'093'000'000;
  ScanAssembler assembler(robot);
  const auto scans = Assemble(assembler, Merge(s));
  const auto& c = assembler.counters();
  // The forged reading and the genuine one after it (a jump back from the forged counters).
  EXPECT_EQ(c.odometry_jumps, 2u);
  EXPECT_GE(c.scans_discarded, 1u);
  ASSERT_GE(scans.size(), 12u);
  EXPECT_GT(scans.back().t_end, 109.0);  // mapping goes on after it
  const Covered covered = CoveredBy(scans);
  EXPECT_LT(covered.max_abs_x, 1.01);
  // Only the motion of the two refused readings (40 ms at 0.1 m/s) is missing.
  EXPECT_NEAR(covered.driven, 0.1 * (scans.back().t_end - scans.front().t_begin) - 0.004, 4e-4);
  for (size_t k = 1; k < scans.size(); ++k)
    EXPECT_EQ(scans[k].odom_begin.x, scans[k - 1].odom_end.x);
}

TEST(ScanAssemblerTest, EncoderCountersThatRestartAreTheNewReference) {
  // The base restarts at t = 105 s: its counters begin again at 0 (and would otherwise move the
  // robot back to where it started, or by whatever the counters held).
  const RobotDescription robot = testing::ShippedRobot();
  Stream s = Straight(10.0, robot);
  const int32_t before_restart = s.odometry[250].left_ticks;
  for (size_t i = 250; i < s.odometry.size(); ++i) {
    s.odometry[i].left_ticks = s.odometry[i].right_ticks =
        s.odometry[i].left_ticks - before_restart - 1'000'000;
  }
  ScanAssembler assembler(robot);
  const auto scans = Assemble(assembler, Merge(s));
  EXPECT_EQ(assembler.counters().odometry_jumps, 1u);
  EXPECT_GT(scans.back().t_end, 109.0);
  const Covered covered = CoveredBy(scans);
  EXPECT_LT(covered.max_abs_x, 1.01);
  EXPECT_NEAR(covered.driven, 0.1 * (scans.back().t_end - scans.front().t_begin) - 0.002, 4e-4);
}

TEST(ScanAssemblerTest, ARobotAtItsTopSpeedIsNotRefused) {
  // Readings 20 ms apart at 95 % of max_speed_m_s, and one 9 s silence at that speed: possible,
  // so taken (the silence as a gap).
  RobotDescription robot = testing::ShippedRobot();
  robot.base.max_speed_m_s = 0.5;
  OdometryIntegrator integrator(robot.base);
  OdometryReading r;
  r.t = 10.0;
  integrator.Add(r);
  const auto ticks_in = [&](double seconds) {
    return static_cast<int32_t>(0.95 * robot.base.max_speed_m_s * seconds * robot.base.ticks_per_m);
  };
  r.t += 0.02;
  r.left_ticks = r.right_ticks = ticks_in(0.02);
  EXPECT_TRUE(integrator.Plausible(r));
  integrator.Add(r);
  r.t += 9.0;
  r.left_ticks = r.right_ticks = r.left_ticks + ticks_in(9.0);
  EXPECT_TRUE(integrator.Plausible(r));
  r.right_ticks += ticks_in(1.0);  // one treel a metre further than it can go
  EXPECT_FALSE(integrator.Plausible(r));
  // A clock jump does not make a jump possible: at most 10 s of motion count.
  r.t += 3600.0;
  r.left_ticks = r.right_ticks = ticks_in(3600.0);
  EXPECT_FALSE(integrator.Plausible(r));
  // Rebase takes the reading as the reference without moving.
  const Pose2 before = integrator.pose();
  integrator.Rebase(r);
  EXPECT_EQ(integrator.pose().x, before.x);
  r.t += 0.02;
  r.left_ticks = r.right_ticks = r.left_ticks + ticks_in(0.02);
  EXPECT_TRUE(integrator.Plausible(r));
  EXPECT_NEAR(integrator.Add(r).x - before.x, 0.95 * 0.5 * 0.02, 1e-4);
}

TEST(ScanAssemblerTest, APlatformThatStopsTurningCannotPileUpSamples) {
  const RobotDescription robot = testing::ShippedRobot();
  Stream s = Straight(120.0, robot);
  // The platform stops at its angle of t = 102 s and never turns again.
  for (size_t i = 120; i < s.scanner.size(); ++i) s.scanner[i].angle_raw = s.scanner[120].angle_raw;
  ScanAssemblerConfig config;
  config.max_scan_samples = 1000;
  ScanAssembler assembler(robot, config);
  const auto scans = Assemble(assembler, Merge(s));
  const auto& c = assembler.counters();
  // 7081 stalled samples: abandoned 1000 at a time (counted), none delivered as a scan.
  EXPECT_EQ(c.scans_too_long, 7u);
  EXPECT_EQ(c.scans_discarded, 7u);
  ASSERT_EQ(scans.size(), 3u);
  for (const Scan& scan : scans) EXPECT_LE(scan.samples.size(), 40u);
  EXPECT_TRUE(config.Validate().empty());
  config.max_scan_samples = 1;
  EXPECT_EQ(config.Validate().size(), 1u);
}

TEST(ScanAssemblerTest, OutOfOrderEventsAreDropped) {
  const RobotDescription robot = testing::ShippedRobot();
  const Stream s = Straight(3.0, robot);
  std::vector<RobotEvent> events = Merge(s);
  // Replay a stale odometry reading and a stale sample, and repeat one event.
  events.insert(events.begin() + 150, RobotEvent(s.odometry[10]));
  events.insert(events.begin() + 200, RobotEvent(s.scanner[20]));
  const RobotEvent repeated = events[249];
  events.insert(events.begin() + 250, repeated);
  ScanAssembler assembler(robot), clean(robot);
  const auto scans = Assemble(assembler, events);
  const auto expected = Assemble(clean, Merge(s));
  EXPECT_EQ(assembler.counters().out_of_order, 3u);
  ASSERT_EQ(scans.size(), expected.size());
  for (size_t k = 0; k < scans.size(); ++k) {
    EXPECT_EQ(scans[k].samples.size(), expected[k].samples.size());
    EXPECT_EQ(scans[k].odom_end.x, expected[k].odom_end.x);
  }
}

TEST(ScanAssemblerTest, StalledOdometryDropsWaitingSamples) {
  const RobotDescription robot = testing::ShippedRobot();
  Stream s = Straight(4.0, robot);
  s.odometry.resize(100);  // odometry ends at t = 101.98; the scanner goes on to 104
  ScanAssembler assembler(robot);
  Assemble(assembler, Merge(s));
  // Samples more than max_odometry_wait_s (0.5 s) older than the newest are given up.
  const auto& c = assembler.counters();
  EXPECT_GE(c.samples_unposed, 90u);
  EXPECT_LE(c.samples_unposed, 92u);
}

TEST(ScanAssemblerTest, ConfigValidation) {
  EXPECT_TRUE(ScanAssemblerConfig{}.Validate().empty());
  ScanAssemblerConfig bad;
  bad.max_sample_gap_s = 0.0;
  bad.max_odometry_wait_s = std::nan("");
  EXPECT_EQ(bad.Validate().size(), 2u);
}

}  // namespace
}  // namespace slam
