#include "sim/virtual_marxbot.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "engine/io/robot_json.hpp"
#include "engine/io/tum.hpp"
#include "hw_link/aseba.hpp"
#include "hw_link/frame_decoder.hpp"
#include "hw_link/link.hpp"
#include "hw_link/transports.hpp"
#include "sim/experiment_writer.hpp"
#include "sim/scenario.hpp"
#include "sim/world.hpp"
#include "test_support.hpp"

namespace slam::sim {
namespace {

hw::CanFrame FrameWithId(uint32_t id, uint8_t len) {
  hw::CanFrame f;
  f.id = id;
  f.len = len;
  return f;
}

TEST(CanBusModelTest, LowestIdWinsAndEachNodeKeepsItsOrder) {
  CanBusModel bus;
  bus.Send({FrameWithId(0x102, 8), FrameWithId(0x202, 8)}, 0.0);  // node 2
  bus.Send({FrameWithId(0x101, 8), FrameWithId(0x201, 6)}, 0.0);  // node 1
  std::vector<std::pair<double, hw::CanFrame>> out;
  bus.Deliver(1.0, out);
  ASSERT_EQ(out.size(), 4u);
  // Slot 1: 0x101 vs 0x102; slot 2: 0x102 vs 0x201; slot 3: 0x201 vs 0x202; then 0x202.
  EXPECT_EQ(out[0].second.id, 0x101u);
  EXPECT_EQ(out[1].second.id, 0x102u);
  EXPECT_EQ(out[2].second.id, 0x201u);
  EXPECT_EQ(out[3].second.id, 0x202u);
  // Back-to-back transmissions: each frame ends one frame time after the previous.
  EXPECT_NEAR(out[0].first, bus.FrameSeconds(out[0].second), 1e-12);
  for (size_t i = 1; i < out.size(); ++i) {
    EXPECT_NEAR(out[i].first - out[i - 1].first, bus.FrameSeconds(out[i].second), 1e-12);
  }
  EXPECT_NEAR(bus.FrameSeconds(FrameWithId(0x101, 8)), 122e-6, 1e-9);  // 1 Mbit/s
  EXPECT_EQ(bus.pending(), 0u);
}

TEST(CanBusModelTest, DeliversOnlyTransmissionsStartingBeforeTheHorizon) {
  CanBusModel bus;
  bus.Send({FrameWithId(0x101, 8)}, 0.5);
  std::vector<std::pair<double, hw::CanFrame>> out;
  bus.Deliver(0.5, out);
  EXPECT_TRUE(out.empty());
  EXPECT_EQ(bus.pending(), 1u);
  bus.Deliver(0.5000001, out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_NEAR(out[0].first, 0.5 + 122e-6, 1e-12);
}

class ExperimentTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("slam_experiment_test_" + std::to_string(::getpid()));
    std::filesystem::remove_all(dir_);
    config_.duration_s = 20.0;
    config_.seed = 5;
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::filesystem::path dir_;
  RobotDescription robot_ = testing::ShippedRobot();
  sim::World world_ = *sim::BuiltinWorld("cluttered");
  sim::ScenarioConfig config_;
};

/// Every event a link delivers from `source`, until the source ends.
std::vector<RobotEvent> DrainLink(std::unique_ptr<hw::FrameSource> source,
                                  const RobotDescription& robot, hw::LinkStatus* status) {
  hw::LinkOptions options;
  options.queue_capacity = 1 << 16;  // the whole run: no drop in these tests
  hw::Link link(std::move(source), robot, options);
  link.Start();
  std::vector<RobotEvent> events;
  hw::LinkEvent event;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (!link.Drained() && std::chrono::steady_clock::now() < deadline) {
    while (link.PopWait(event, std::chrono::milliseconds(5))) events.push_back(event.event);
  }
  while (link.Pop(event)) events.push_back(event.event);
  link.Stop();
  if (status != nullptr) *status = link.Status();
  return events;
}

/// Checks the decoded events against the simulator's readings: identical fields, in order, and
/// times shifted only by the bus (the event's time is its last frame's).
void ExpectSameEvents(const std::vector<RobotEvent>& got, const sim::ScenarioOutput& made,
                      double time_offset) {
  const std::vector<RobotEvent> expected = sim::MergeEvents(made.odometry, made.scanner);
  ASSERT_EQ(got.size(), expected.size());
  size_t odometry = 0, scanner = 0;
  for (size_t i = 0; i < got.size(); ++i) {
    // Events of both nodes at the same instant may swap places on the bus; compare per type.
    if (const auto* o = std::get_if<OdometryReading>(&got[i])) {
      OdometryReading want = made.odometry[odometry++];
      ASSERT_NEAR(o->t - time_offset, want.t, 1e-3) << "odometry " << odometry;
      want.t = o->t;
      ASSERT_EQ(*o, want) << "odometry " << odometry;
    } else {
      const auto& s = std::get<ScannerReading>(got[i]);
      ScannerReading want = made.scanner[scanner++];
      ASSERT_NEAR(s.t - time_offset, want.t, 1e-3) << "sample " << scanner;
      want.t = s.t;
      ASSERT_EQ(s, want) << "sample " << scanner;
    }
  }
  EXPECT_EQ(odometry, made.odometry.size());
  EXPECT_EQ(scanner, made.scanner.size());
}

TEST_F(ExperimentTest, RecordedExperimentReadBackThroughTheLinkGivesTheSimulatorsEvents) {
  ExperimentSummary summary;
  ASSERT_TRUE(
      WriteSimulatedExperiment(dir_.string(), world_, "cluttered", robot_, config_, &summary).ok());
  for (const char* name : {"robot.json", "can.log", "groundtruth.tum", "meta.json", "world.json"}) {
    EXPECT_TRUE(std::filesystem::exists(dir_ / name)) << name;
  }
  const sim::ScenarioOutput made = sim::RunScenario(world_, robot_, config_);
  EXPECT_EQ(summary.events, made.odometry.size() + made.scanner.size());

  auto robot = io::LoadRobot((dir_ / "robot.json").string());
  ASSERT_TRUE(robot.ok()) << robot.Message();
  auto source = hw::OpenCandumpReplay((dir_ / "can.log").string());
  ASSERT_TRUE(source.ok());
  hw::LinkStatus status;
  const auto events = DrainLink(std::move(source).value(), robot.value(), &status);
  ExpectSameEvents(events, made, static_cast<double>(kSimulationEpochUs) * 1e-6);
  EXPECT_EQ(status.frames, summary.frames);
  EXPECT_EQ(status.reassembly.Rejected(), 0u);
  EXPECT_EQ(status.decoder.Rejected(), 0u);
  EXPECT_EQ(status.queue_drops, 0u);

  // The same through the thread-less decoder that replays use.
  auto again = hw::OpenCandumpReplay((dir_ / "can.log").string());
  ASSERT_TRUE(again.ok());
  hw::FrameDecoder decoder(robot.value());
  std::vector<RobotEvent> direct;
  EXPECT_TRUE(
      DecodeToEnd(*again.value(), decoder, [&](const RobotEvent& e) { direct.push_back(e); }).ok());
  ExpectSameEvents(direct, made, static_cast<double>(kSimulationEpochUs) * 1e-6);
  EXPECT_EQ(decoder.frames(), summary.frames);

  // The ground truth is the tracker's, at the log's times.
  const auto truth = io::LoadTum((dir_ / "groundtruth.tum").string());
  ASSERT_TRUE(truth.ok()) << truth.Message();
  ASSERT_EQ(truth.value().size(), made.ground_truth.size());
  for (size_t i = 0; i < made.ground_truth.size(); i += 97) {
    EXPECT_NEAR(truth.value()[i].t - 1.7e9, made.ground_truth[i].t, 2e-6);
    EXPECT_NEAR(truth.value()[i].pose.x, made.ground_truth[i].pose.x, 1e-6);
    EXPECT_NEAR(truth.value()[i].pose.theta, made.ground_truth[i].pose.theta, 1e-6);
  }
  // The world and meta data.
  const auto world = sim::LoadWorld((dir_ / "world.json").string());
  ASSERT_TRUE(world.ok());
  EXPECT_EQ(world.value().segments.size(), world_.segments.size());
  std::ifstream meta_file(dir_ / "meta.json");
  std::stringstream meta;
  meta << meta_file.rdbuf();
  EXPECT_NE(meta.str().find("\"source\": \"sim\""), std::string::npos);
  EXPECT_NE(meta.str().find("\"seed\": 5"), std::string::npos);
}

TEST_F(ExperimentTest, SameSeedWritesIdenticalFiles) {
  const auto a = dir_ / "a";
  const auto b = dir_ / "b";
  ASSERT_TRUE(WriteSimulatedExperiment(a.string(), world_, "cluttered", robot_, config_).ok());
  ASSERT_TRUE(WriteSimulatedExperiment(b.string(), world_, "cluttered", robot_, config_).ok());
  for (const char* name : {"can.log", "groundtruth.tum", "meta.json", "world.json"}) {
    std::ifstream fa(a / name), fb(b / name);
    std::stringstream sa, sb;
    sa << fa.rdbuf();
    sb << fb.rdbuf();
    EXPECT_EQ(sa.str(), sb.str()) << name;
    EXPECT_FALSE(sa.str().empty()) << name;
  }
}

TEST_F(ExperimentTest, UnwritableDirectoryIsAnError) {
  std::filesystem::create_directories(dir_);
  std::ofstream(dir_ / "file") << "x";
  const Result<void> written =
      WriteSimulatedExperiment((dir_ / "file" / "sub").string(), world_, "w", robot_, config_);
  ASSERT_FALSE(written.ok());
  EXPECT_NE(written.Message().find("file"), std::string::npos);
}

TEST_F(ExperimentTest, LiveVirtualMarxbotSpeaksTheSameFrames) {
  config_.duration_s = 5.0;
  VirtualMarxbotOptions options;
  options.paced = false;
  options.duration_s = config_.duration_s;
  auto source =
      std::make_unique<VirtualMarxbotSource>(world_, "cluttered", robot_, config_, options);
  hw::LinkStatus status;
  const auto events = DrainLink(std::move(source), robot_, &status);
  const sim::ScenarioOutput made = sim::RunScenario(world_, robot_, config_);
  // The live source stops at the duration: the last readings' frames end after it.
  sim::ScenarioOutput trimmed = made;
  const auto late = [&](const auto& r) { return r.t + 1e-3 > config_.duration_s; };
  std::erase_if(trimmed.odometry, late);
  std::erase_if(trimmed.scanner, late);
  ExpectSameEvents(events, trimmed, 0.0);
  EXPECT_EQ(status.source, "sim:cluttered");
  EXPECT_EQ(status.reassembly.Rejected(), 0u);
}

TEST_F(ExperimentTest, LiveVirtualMarxbotIsPacedInRealTime) {
  VirtualMarxbotOptions options;
  options.paced = true;
  options.speed = 4.0;
  options.duration_s = 1.0;  // 1 s of robot time at 4x: about 250 ms
  VirtualMarxbotSource source(world_, "cluttered", robot_, config_, options);
  std::vector<hw::TimedFrame> frames;
  const auto start = std::chrono::steady_clock::now();
  hw::ReadOutcome outcome;
  for (int i = 0; i < 1000 && outcome.status != hw::ReadStatus::kEnd; ++i) {
    outcome = source.Read(frames, std::chrono::milliseconds(20));
  }
  const double elapsed =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_EQ(outcome.status, hw::ReadStatus::kEnd);
  EXPECT_GE(elapsed, 0.2);
  EXPECT_LT(elapsed, 1.0);
  // 1 s: about 50 odometry + 60 scanner events of two frames each.
  EXPECT_GE(frames.size(), 210u);
  EXPECT_LE(frames.size(), 222u);
  for (size_t i = 1; i < frames.size(); ++i) EXPECT_GE(frames[i].t, frames[i - 1].t);
  EXPECT_FALSE(source.GroundTruth().empty());
}

TEST_F(ExperimentTest, TheVirtualMarxbotKeepsTheLastMinuteOfGroundTruthOnly) {
  // It kept every tracker pose for the whole run (55 KB a minute) though its reader copies
  // them as they come.
  VirtualMarxbotOptions options;
  options.paced = false;
  options.duration_s = 75.0;
  config_.duration_s = 75.0;
  VirtualMarxbotSource source(world_, "cluttered", robot_, config_, options);
  std::vector<hw::TimedFrame> frames;
  std::vector<TimedPose> read;  // what a reader copying as they come gets
  size_t next = 0;
  hw::ReadOutcome outcome;
  for (int i = 0; i < 100000 && outcome.status != hw::ReadStatus::kEnd; ++i) {
    frames.clear();
    outcome = source.Read(frames, std::chrono::milliseconds(20));
    next = source.GroundTruthSince(next, read);
  }
  ASSERT_EQ(outcome.status, hw::ReadStatus::kEnd);
  const double rate = config_.tracker_rate_hz;
  EXPECT_NEAR(static_cast<double>(next), 75.0 * rate, 10.0);  // the tracker runs on a little
  EXPECT_EQ(read.size(), next);  // nothing missed by a reader keeping up
  for (size_t i = 1; i < read.size(); ++i) ASSERT_GT(read[i].t, read[i - 1].t) << i;
  const std::vector<TimedPose> kept = source.GroundTruth();
  EXPECT_NEAR(static_cast<double>(kept.size()), VirtualMarxbotSource::kKeptTruthS * rate, 2.0);
  EXPECT_EQ(kept.back().t, read.back().t);
  // A reader that fell behind gets what is still kept, and the count of all made.
  std::vector<TimedPose> late;
  EXPECT_EQ(source.GroundTruthSince(0, late), next);
  EXPECT_EQ(late.size(), kept.size());
}

/// Reads `source` (unpaced: 0.2 s of simulated time a read) until its ground truth reaches
/// `until_s`.
void ReadUntil(VirtualMarxbotSource& source, double until_s) {
  std::vector<hw::TimedFrame> frames;
  for (int i = 0; i < 10000; ++i) {
    const std::vector<TimedPose> truth = source.GroundTruth();
    if (!truth.empty() && truth.back().t >= until_s) return;
    frames.clear();
    ASSERT_EQ(source.Read(frames, std::chrono::milliseconds(20)).status, hw::ReadStatus::kOk);
  }
  FAIL() << "never reached " << until_s << " s";
}

/// The largest distance between consecutive tracker poses after `from_t`, and the first pose
/// after the largest jump.
std::pair<double, TimedPose> LargestJumpAfter(const std::vector<TimedPose>& truth, double from_t) {
  std::pair<double, TimedPose> largest{0.0, {}};
  for (size_t i = 1; i < truth.size(); ++i) {
    if (truth[i - 1].t < from_t) continue;
    const double jump = (truth[i].pose.translation() - truth[i - 1].pose.translation()).norm();
    if (jump > largest.first) largest = {jump, truth[i]};
  }
  return largest;
}

TEST_F(ExperimentTest, AKidnappedVirtualMarxbotsGroundTruthJumpsAndItCountsKidnaps) {
  VirtualMarxbotOptions options;
  options.paced = false;
  config_.seed = 2;
  VirtualMarxbotSource source(world_, "cluttered", robot_, config_, options);
  ReadUntil(source, 20.0);
  EXPECT_EQ(source.kidnaps(), 0u);
  const std::vector<TimedPose> before = source.GroundTruth();
  const double lifted_t = before.back().t;

  // Set down where it was half its run ago (a pose remembered each second).
  const Result<Pose2> back = source.Kidnap(std::nullopt);
  ASSERT_TRUE(back.ok()) << back.Message();
  const auto truth_near = [&](double t) {
    for (const TimedPose& p : before) {
      if (std::abs(p.t - t) < 1e-6) return p.pose;
    }
    ADD_FAILURE() << "no tracker pose at " << t;
    return Pose2{};
  };
  // Simulated to just past 20 s: half is 10 s, remembered on the second.
  const Pose2 at_half = truth_near(10.0);
  EXPECT_LT((back.value().translation() - at_half.translation()).norm(), 0.01);
  ReadUntil(source, lifted_t + 1.0);
  EXPECT_EQ(source.kidnaps(), 1u);
  const auto [jump, landed] = LargestJumpAfter(source.GroundTruth(), lifted_t - 1.0);
  // Unpaced, it is set down at the start of the next read, after the last pose seen.
  const double moved = (back.value().translation() - before.back().pose.translation()).norm();
  ASSERT_GT(moved, 0.3);
  EXPECT_NEAR(jump, moved, 0.01);
  EXPECT_LT((landed.pose.translation() - back.value().translation()).norm(), 0.01);
  EXPECT_LT(landed.t - lifted_t, 0.05);

  // Set down at a given free pose.
  const Pose2 target{at_half.x, at_half.y, 1.0};
  const Result<Pose2> there = source.Kidnap(target);
  ASSERT_TRUE(there.ok()) << there.Message();
  EXPECT_EQ(there.value().x, target.x);
  const double second_t = source.GroundTruth().back().t;
  ReadUntil(source, second_t + 1.0);
  EXPECT_EQ(source.kidnaps(), 2u);
  const auto [jump2, landed2] = LargestJumpAfter(source.GroundTruth(), second_t - 1.0);
  EXPECT_LT((landed2.pose.translation() - target.translation()).norm(), 0.01);
  EXPECT_LT(std::abs(NormalizeAngle(landed2.pose.theta - target.theta)), 0.03);

  // A target the robot does not fit at is refused: nothing happens.
  const Circle& pillar = world_.circles.front();
  const Result<Pose2> refused = source.Kidnap(Pose2{pillar.center.x(), pillar.center.y(), 0.0});
  EXPECT_FALSE(refused.ok());
  EXPECT_NE(refused.Message().find("overlaps"), std::string::npos) << refused.Message();
  EXPECT_FALSE(source.Kidnap(Pose2{world_.bounds[2] + 1.0, 0.0, 0.0}).ok());
  const double third_t = source.GroundTruth().back().t;
  ReadUntil(source, third_t + 2.0);
  EXPECT_EQ(source.kidnaps(), 2u);
  EXPECT_LT(LargestJumpAfter(source.GroundTruth(), third_t - 0.5).first, 0.02);
}

TEST_F(ExperimentTest, AfterLongRunsTheDefaultTargetIsStillWhereTheRobotWasHalfItsRunAgo) {
  // Past kRememberedPoses seconds every other remembered pose is forgotten: 1100 s leave one
  // every 2 s.
  VirtualMarxbotOptions options;
  options.paced = false;
  VirtualMarxbotSource source(world_, "cluttered", robot_, config_, options);
  std::vector<TimedPose> truth;
  std::vector<hw::TimedFrame> frames;
  size_t next = 0;
  while (truth.empty() || truth.back().t < 1100.0) {
    frames.clear();
    ASSERT_EQ(source.Read(frames, std::chrono::milliseconds(20)).status, hw::ReadStatus::kOk);
    next = source.GroundTruthSince(next, truth);
  }
  const Result<Pose2> target = source.Kidnap(std::nullopt);
  ASSERT_TRUE(target.ok()) << target.Message();
  const double half = truth.back().t / 2.0;
  double nearest = 1e9;
  for (const TimedPose& p : truth) {
    if (std::abs(p.t - half) <= 2.0) {
      nearest = std::min(nearest, (p.pose.translation() - target.value().translation()).norm());
    }
  }
  EXPECT_LT(nearest, 0.01);
}

TEST_F(ExperimentTest, AVirtualMarxbotMayBeKidnappedFromAnotherThreadWhileRead) {
  VirtualMarxbotOptions options;
  options.paced = false;
  VirtualMarxbotSource source(world_, "cluttered", robot_, config_, options);
  std::atomic<int> accepted{0};
  std::atomic<bool> done{false};
  std::thread http([&] {
    while (!done) {
      if (source.Kidnap(std::nullopt).ok()) ++accepted;
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
  });
  ReadUntil(source, 30.0);
  done = true;
  http.join();
  EXPECT_GT(accepted.load(), 0);
  EXPECT_GT(source.kidnaps(), 0u);
  EXPECT_LE(source.kidnaps(), static_cast<uint64_t>(accepted.load()));
}

}  // namespace
}  // namespace slam::sim
