// slam-sim's kidnapping options as a user meets them (tools/slam_sim.cpp): --kidnap T and
// --kidnap-to X,Y,THETA_DEG write meta.json's "kidnap" and make the ground truth jump; a bad
// value is named on stderr with status 2 and nothing is written. The tool runs as a child
// process.

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "engine/io/tum.hpp"
#include "engine/pose.hpp"
#include "sim/experiment_writer.hpp"
#include "sim/scenario.hpp"
#include "sim/world.hpp"
#include "test_support.hpp"

namespace slam {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;

struct ToolRun {
  int status = -1;  // exit status; -1 when killed or not run
  std::string out, err;
};

std::string ReadAll(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

/// Runs slam-sim with `args` (no shell) in `dir`, its output in files there.
ToolRun RunSlamSim(const std::vector<std::string>& args, const fs::path& dir) {
  const fs::path out = dir / "stdout.txt", err = dir / "stderr.txt";
  std::vector<std::string> argv{SLAM_SIM_BIN};
  argv.insert(argv.end(), args.begin(), args.end());
  const pid_t pid = ::fork();
  if (pid == 0) {
    const int o = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int e = ::open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (o < 0 || e < 0 || ::dup2(o, 1) < 0 || ::dup2(e, 2) < 0 || ::chdir(dir.c_str()) != 0)
      ::_exit(127);
    std::vector<char*> pointers;
    for (const std::string& a : argv) pointers.push_back(const_cast<char*>(a.c_str()));
    pointers.push_back(nullptr);
    ::execv(pointers[0], pointers.data());
    ::_exit(127);
  }
  ToolRun run;
  if (pid < 0) return run;
  int status = 0;
  ::waitpid(pid, &status, 0);
  if (WIFEXITED(status)) run.status = WEXITSTATUS(status);
  run.out = ReadAll(out);
  run.err = ReadAll(err);
  return run;
}

/// slam-sim's one-experiment arguments for a 30 s run in rooms, seed 1, into `out`.
std::vector<std::string> RoomsRun(const std::string& out, std::vector<std::string> more = {}) {
  std::vector<std::string> args{"--world", "rooms", "--duration", "30",
                                "--seed",  "1",     "--out",      out};
  args.insert(args.end(), more.begin(), more.end());
  return args;
}

/// What slam-sim simulates for RoomsRun: the tracked profile.
sim::ScenarioConfig RoomsConfig() {
  sim::ScenarioConfig config;
  config.duration_s = 30.0;
  config.seed = 1;
  return sim::WithOdometryProfile(config, sim::OdometryProfile::kTracked);
}

Pose2 PoseOf(const Json& xyz) { return {xyz.at(0), xyz.at(1), xyz.at(2)}; }

TEST(SlamSimKidnapTest, KidnapWritesMetaJsonsKeyAndTheGroundTruthJumps) {
  testing::TempDir dir("slam_sim_kidnap");
  const ToolRun run = RunSlamSim(RoomsRun("exp", {"--kidnap", "20"}), dir.path());
  ASSERT_EQ(run.status, 0) << run.err;
  const Json meta = Json::parse(ReadAll(dir.path() / "exp" / "meta.json"));
  // The design's keys as without, and the kidnapping.
  EXPECT_EQ(meta.at("name"), "rooms-seed1");
  EXPECT_EQ(meta.at("world"), "rooms");
  EXPECT_EQ(meta.at("duration_s"), 30.0);
  EXPECT_EQ(meta.at("source"), "sim");
  EXPECT_EQ(meta.at("seed"), 1);
  ASSERT_TRUE(meta.contains("kidnap")) << meta.dump(2);
  const Json& kidnap = meta.at("kidnap");
  EXPECT_EQ(kidnap.at("t"), 20.0);
  ASSERT_EQ(kidnap.at("from").size(), 3u);
  ASSERT_EQ(kidnap.at("to").size(), 3u);

  // From where the robot is at 20 s to where it was at 10 s, as the library simulates it.
  sim::ScenarioConfig config = RoomsConfig();
  const sim::ScenarioOutput plain =
      sim::RunScenario(*sim::BuiltinWorld("rooms"), testing::ShippedRobot(), config);
  const auto true_at = [&](double t) {
    for (const TimedPose& p : plain.true_path) {
      if (std::abs(p.t - t) < 1e-9) return p.pose;
    }
    ADD_FAILURE() << "no pose at " << t;
    return Pose2{};
  };
  const Pose2 from = PoseOf(kidnap.at("from")), to = PoseOf(kidnap.at("to"));
  EXPECT_DOUBLE_EQ(from.x, true_at(20.0).x);
  EXPECT_DOUBLE_EQ(from.y, true_at(20.0).y);
  EXPECT_DOUBLE_EQ(to.x, true_at(10.0).x);
  EXPECT_DOUBLE_EQ(to.y, true_at(10.0).y);
  EXPECT_DOUBLE_EQ(to.theta, true_at(10.0).theta);

  // groundtruth.tum: the first pose from 20 s on is there.
  const auto truth = io::LoadTum((dir.path() / "exp" / "groundtruth.tum").string());
  ASSERT_TRUE(truth.ok()) << truth.Message();
  const double epoch_s = static_cast<double>(sim::kSimulationEpochUs) * 1e-6;
  bool seen = false;
  for (const TimedPose& p : truth.value()) {
    if (p.t - epoch_s < 20.0 - 1e-4) continue;
    EXPECT_LT((p.pose.translation() - to.translation()).norm(), 0.006);
    seen = true;
    break;
  }
  EXPECT_TRUE(seen);
}

TEST(SlamSimKidnapTest, KidnapToSetsTheTargetAndWithoutKidnapThereIsNoKey) {
  testing::TempDir dir("slam_sim_kidnap_to");
  const ToolRun run =
      RunSlamSim(RoomsRun("exp", {"--kidnap", "12.5", "--kidnap-to", "0.5,0.5,90"}), dir.path());
  ASSERT_EQ(run.status, 0) << run.err;
  const Json meta = Json::parse(ReadAll(dir.path() / "exp" / "meta.json"));
  EXPECT_EQ(meta.at("kidnap").at("t"), 12.5);
  const Pose2 to = PoseOf(meta.at("kidnap").at("to"));
  EXPECT_EQ(to.x, 0.5);
  EXPECT_EQ(to.y, 0.5);
  EXPECT_DOUBLE_EQ(to.theta, kPi / 2.0);

  const ToolRun plain = RunSlamSim(RoomsRun("plain"), dir.path());
  ASSERT_EQ(plain.status, 0) << plain.err;
  EXPECT_FALSE(Json::parse(ReadAll(dir.path() / "plain" / "meta.json")).contains("kidnap"));

  const ToolRun help = RunSlamSim({"--help"}, dir.path());
  EXPECT_EQ(help.status, 0);
  EXPECT_NE(help.out.find("--kidnap "), std::string::npos) << help.out;
  EXPECT_NE(help.out.find("--kidnap-to"), std::string::npos) << help.out;
}

TEST(SlamSimKidnapTest, BadKidnapValuesExitTwoNamingTheOptionAndWriteNothing) {
  testing::TempDir dir("slam_sim_kidnap_bad");
  const sim::World rooms = *sim::BuiltinWorld("rooms");
  const Vec2 on_wall = 0.5 * (rooms.segments.front().a + rooms.segments.front().b);
  char in_wall[64];
  std::snprintf(in_wall, sizeof(in_wall), "%.6f,%.6f,0", on_wall.x(), on_wall.y());
  const struct {
    std::vector<std::string> args;
    std::string says;
  } cases[] = {
      {{"--kidnap", "abc"}, "--kidnap abc: expected a time in seconds"},
      {{"--kidnap", ""}, "expected a time in seconds"},
      {{"--kidnap", "0"}, "0 < T < 30"},
      {{"--kidnap", "30"}, "0 < T < 30"},
      {{"--kidnap", "-3"}, "--kidnap -3"},
      {{"--kidnap", "inf"}, "--kidnap inf"},
      {{"--kidnap-to", "0.5,0.5,0"}, "--kidnap-to needs --kidnap"},
      {{"--kidnap", "10", "--kidnap-to", "0.5,0.5"}, "expected X,Y,THETA_DEG"},
      {{"--kidnap", "10", "--kidnap-to", "0.5,x,0"}, "expected X,Y,THETA_DEG"},
      {{"--kidnap", "10", "--kidnap-to", in_wall}, "overlaps a wall"},
      {{"--kidnap", "10", "--kidnap-to", "50,0.5,0"}, "outside the world's bounds"},
  };
  for (const auto& c : cases) {
    const ToolRun run = RunSlamSim(RoomsRun("exp", c.args), dir.path());
    EXPECT_EQ(run.status, 2) << c.args.back() << ": " << run.err;
    EXPECT_NE(run.err.find("slam-sim: "), std::string::npos) << run.err;
    EXPECT_NE(run.err.find(c.says), std::string::npos) << run.err;
    EXPECT_FALSE(fs::exists(dir.path() / "exp" / "meta.json")) << c.args.back();
  }
  const ToolRun dataset = RunSlamSim({"--kidnap", "5", "dataset", "--out", "set"}, dir.path());
  EXPECT_EQ(dataset.status, 2) << dataset.err;
  EXPECT_NE(dataset.err.find("not 'dataset'"), std::string::npos) << dataset.err;
  EXPECT_FALSE(fs::exists(dir.path() / "set"));
}

}  // namespace
}  // namespace slam
