// slamd's service relocalising on the virtual marXbot, in process: a map resumed where the robot
// is not at the map's origin (a Reset part-way, then a restart, and the virtual marXbot starts
// over from its start pose; or a robot carried while slamd was off) is searched for the robot
// before anything is mapped, and stays one map; a pose given is taken as it is; a hint is
// searched around; the requests' validation.

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <thread>

#include "engine/quality.hpp"
#include "hw_link/link.hpp"
#include "offline/replay.hpp"
#include "server/slam_service.hpp"
#include "server/state_store.hpp"
#include "sim/map_quality.hpp"
#include "sim/scenario.hpp"
#include "sim/virtual_marxbot.hpp"
#include "sim/world.hpp"
#include "tests/test_support.hpp"

namespace slam::server {
namespace {

using testing::ShippedRobot;
using testing::TempDir;

constexpr double kResetAtS = 20.0;  // the first run's map starts here (its origin: the pose then)
constexpr double kFirstRunS = 100.0;
constexpr double kSecondRunS = 60.0;
constexpr int64_t kBudget = 16250;

sim::ScenarioConfig Scenario(double duration_s, uint64_t seed) {
  sim::ScenarioConfig config =
      sim::WithOdometryProfile(sim::ScenarioConfig{}, sim::OdometryProfile::kTracked);
  config.duration_s = duration_s;
  config.seed = seed;
  return config;
}

/// The first run: mapped from kResetAtS on (as after a Reset then), saved and loaded back; the
/// map's frame in the world and the true path of the mapped part.
struct FirstRun {
  SavedState state;
  RigidTransform2 map_to_world;
  std::vector<TimedPose> truth;  // world frame, from kResetAtS
  double precision = 0.0;        // of its own map
};

FirstRun MapFirstRun(const sim::World& world, uint64_t seed, const TempDir& dir) {
  const RobotDescription robot = ShippedRobot();
  const sim::ScenarioOutput out = sim::RunScenario(world, robot, Scenario(kFirstRunS, seed));
  std::vector<Scan> scans = sim::BuildScans(robot, out.odometry, out.scanner);
  std::erase_if(scans, [](const Scan& s) { return s.t_begin < kResetAtS; });
  offline::ReplayOptions replay;
  replay.params = ParamsChoice{};
  replay.budget.rays_per_scan = kBudget;
  replay.config.parallel = false;
  const offline::ReplayResult mapped = offline::Replay(robot, scans, {}, replay);
  FirstRun run;
  const std::optional<Pose2> origin = PoseAt(out.ground_truth, scans.front().t_begin);
  EXPECT_TRUE(origin);
  run.map_to_world = RigidTransform2{origin->theta, origin->translation()};
  for (const TimedPose& p : out.ground_truth) {
    if (p.t >= kResetAtS) run.truth.push_back(p);
  }
  run.precision = sim::EvaluateMap(mapped.map, run.map_to_world, world, run.truth).precision;
  SaveInputs in;
  in.version = mapped.map.Version();
  in.grid = &mapped.map;
  in.trajectory = mapped.trajectory;
  EXPECT_TRUE(SaveState(dir.File("state"), in).ok());
  Result<std::optional<SavedState>> loaded = LoadState(dir.File("state"));
  EXPECT_TRUE(loaded.ok() && loaded.value()) << loaded.Message();
  run.state = *loaded.value();
  return run;
}

/// The second run: slamd's service resumed on the first run's state, on a virtual marXbot that
/// starts over from its start pose.
struct SecondRun {
  std::shared_ptr<const SlamSnapshot> last;
  ServiceCounters counters;
  std::vector<TimedPose> truth;  // world frame, the source's times
  double precision = 0.0;        // of the map at the end, with the first run's truth
  double pose_error_m = 0.0;     // the last pose's, against the truth
  double heading_error_deg = 0.0;
};

SecondRun ResumeOn(const sim::World& world, uint64_t seed, const FirstRun& first,
                   std::optional<Pose2> resume_pose, bool detect_loss = true) {
  const RobotDescription robot = ShippedRobot();
  sim::VirtualMarxbotOptions unpaced;
  unpaced.paced = false;
  unpaced.duration_s = kSecondRunS;
  auto source = std::make_unique<sim::VirtualMarxbotSource>(world, "rooms", robot,
                                                            Scenario(0.0, seed), unpaced);
  sim::VirtualMarxbotSource* truth_source = source.get();
  hw::LinkOptions link_options;
  link_options.queue_capacity = 1 << 16;  // nothing dropped: the run is deterministic
  hw::Link link(std::move(source), robot, link_options);
  ServiceOptions options;
  options.robot = robot;
  options.budget.rays_per_scan = kBudget;
  options.resume = first.state;
  options.resume_pose = resume_pose;
  options.detect_loss = detect_loss;
  SlamService service(link, truth_source, options);
  link.Start();
  service.Start();
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
  while (std::chrono::steady_clock::now() < deadline &&
         !(link.Status().state == hw::LinkState::kEnded && link.Status().queue_size == 0)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(200));  // the last event's scan
  service.Stop();
  link.Stop();
  SecondRun run;
  run.last = service.Snapshot();
  run.counters = service.Counters();
  run.truth = truth_source->GroundTruth();
  std::vector<TimedPose> truth = first.truth;
  for (TimedPose p : run.truth) {  // after the first run's, in time order
    p.t += kFirstRunS + 1.0;
    truth.push_back(p);
  }
  const OccupancyGrid map = SnapshotGrid(*run.last, service.encoded_logodds_limit());
  run.precision = sim::EvaluateMap(map, first.map_to_world, world, truth).precision;
  if (run.last->has_pose) {
    const TimedPose& p = run.last->pose;
    if (const std::optional<Pose2> true_pose = PoseAt(run.truth, p.t - run.last->time_offset_s)) {
      run.pose_error_m =
          (first.map_to_world.Apply(p.pose.translation()) - true_pose->translation()).norm();
      run.heading_error_deg = std::abs(RadToDeg(
          NormalizeAngle(p.pose.theta + first.map_to_world.rotation_rad - true_pose->theta)));
    }
  }
  return run;
}

class ResumeTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir("relocalization_service");
    first_ = new FirstRun(MapFirstRun(*sim::BuiltinWorld("rooms"), kSeed, *dir_));
  }
  static void TearDownTestSuite() {
    delete first_;
    delete dir_;
  }
  static constexpr uint64_t kSeed = 2;
  static TempDir* dir_;
  static FirstRun* first_;
};

TempDir* ResumeTest::dir_ = nullptr;
FirstRun* ResumeTest::first_ = nullptr;

TEST_F(ResumeTest, AResumedMapIsSearchedForTheRobotAndStaysOneMap) {
  ASSERT_GT(first_->precision, 0.8) << "precondition: the first run mapped well";
  const SecondRun run = ResumeOn(*sim::BuiltinWorld("rooms"), kSeed, *first_, std::nullopt);
  EXPECT_EQ(run.counters.relocalizations, 1);
  EXPECT_GT(run.counters.relocalizing_scans, 0);
  EXPECT_GT(run.counters.relocalization_lookups, 0);
  // Each relocalising scan within its quota's lookups.
  EXPECT_LE(run.counters.relocalization_lookups,
            run.counters.relocalizing_scans * kBudget * kLookupsPerRay);
  ASSERT_TRUE(run.last->last_relocalization);
  const RelocalizationRecord& r = *run.last->last_relocalization;
  EXPECT_EQ(r.cause, RelocalizationCause::kResume);
  EXPECT_LT(r.search_s, 20.0) << "found within 20 s of driving";
  EXPECT_FALSE(run.last->relocalizing);
  EXPECT_EQ(run.counters.state, SlamState::kRunning);
  // One map: as precise as the first run's own.
  EXPECT_GT(run.precision, 0.8);
  EXPECT_GT(run.precision, first_->precision - 0.05);
  EXPECT_LT(run.pose_error_m, 0.05);
  EXPECT_LT(run.heading_error_deg, 3.0);
}

TEST_F(ResumeTest, AResumedMapTakenFromAWrongPoseGetsASecondCopyWithoutTheLossDetector) {
  // What slamd did before it relocalised: the virtual marXbot restarted at the map's origin,
  // which is where the robot was at the Reset, not where it starts. The measure above tells.
  const SecondRun run =
      ResumeOn(*sim::BuiltinWorld("rooms"), kSeed, *first_, Pose2{}, /*detect_loss=*/false);
  EXPECT_EQ(run.counters.relocalizations, 0);
  EXPECT_LT(run.precision, first_->precision - 0.15);
  EXPECT_GT(run.pose_error_m, 0.2);
}

TEST_F(ResumeTest, AResumedMapTakenFromAWrongPoseIsFoundLostAndStaysOneMap) {
  // The same wrong pose, with the loss detector as slamd runs it: the readings land in the
  // map's free space, what was mapped from the wrong pose is taken back, and the relocaliser
  // finds the robot. The detector checks against the map of some scans ago; against the map
  // of the moment, the wrong pose's own walls agreed with the next scans and it never fired.
  const SecondRun run = ResumeOn(*sim::BuiltinWorld("rooms"), kSeed, *first_, Pose2{});
  EXPECT_EQ(run.counters.losses, 1);
  EXPECT_EQ(run.counters.relocalizations, 1);
  ASSERT_TRUE(run.last->last_relocalization);
  EXPECT_EQ(run.last->last_relocalization->cause, RelocalizationCause::kLost);
  EXPECT_GT(run.precision, first_->precision - 0.05);
  EXPECT_LT(run.pose_error_m, 0.05);
  EXPECT_LT(run.heading_error_deg, 3.0);
}

TEST(ResumeInAStudio, WhileUnsureThePlacesTheRobotMayBeAreReportedTheTruthAmongThem) {
  // The studio is square with its furniture in the middle: turned by 90 degrees it looks much
  // the same, and the relocaliser stays unsure. The snapshot (status and the relocalization
  // event) carries the places its last search scored, best first, carried to the latest scan:
  // the robot is at one of them (the last search's multiscan, 30 s of a drifting odometry,
  // places it to some centimetres).
  const sim::World world = *sim::BuiltinWorld("studio");
  const TempDir dir("relocalization_studio");
  const FirstRun first = MapFirstRun(world, 1, dir);
  ASSERT_GT(first.precision, 0.8) << "precondition: the first run mapped well";
  const SecondRun run = ResumeOn(world, 1, first, std::nullopt);
  ASSERT_TRUE(run.last->relocalizing) << "precondition: still unsure at the end";
  EXPECT_GT(run.counters.relocalization_searches_unsure, 0);
  const std::vector<GlobalMatch>& places = run.last->relocalization_places;
  ASSERT_GE(places.size(), 2u);
  for (size_t i = 1; i < places.size(); ++i) EXPECT_LE(places[i].score, places[i - 1].score);
  const std::optional<Pose2> truth =
      PoseAt(run.truth, run.last->relocalization_places_t - run.last->time_offset_s);
  ASSERT_TRUE(truth);
  double nearest_m = 1e9, its_heading_deg = 0.0;
  for (const GlobalMatch& p : places) {
    const double d = (first.map_to_world.Apply(p.pose.translation()) - truth->translation()).norm();
    if (d < nearest_m) {
      nearest_m = d;
      its_heading_deg = std::abs(
          RadToDeg(NormalizeAngle(p.pose.theta + first.map_to_world.rotation_rad - truth->theta)));
    }
  }
  // Nearer than two distinct places ever are (GlobalSearchConfig::distinct_m): this place.
  EXPECT_LT(nearest_m, 0.25);
  EXPECT_LT(its_heading_deg, 5.0);
}

}  // namespace
}  // namespace slam::server
