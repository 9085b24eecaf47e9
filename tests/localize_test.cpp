// Localising on a recording (offline::Replay with a map): a short simulated run is mapped, its
// map saved as map.yaml + map.pgm and read back (map_yaml.hpp), then the run is localised on it
// from the start pose, from no pose (a relocalisation first), and across a stretch left out (an
// artificial kidnap, announced or found by the loss detector); and slam-replay's --localize,
// --pose, --drop, --from, --until and --detect-loss, good and bad.

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <tuple>
#include <vector>

#include "engine/cell_encoding.hpp"
#include "engine/io/map_image.hpp"
#include "engine/io/map_yaml.hpp"
#include "engine/quality.hpp"
#include "offline/replay.hpp"
#include "server/state_store.hpp"
#include "tests/command_support.hpp"
#include "tests/experiment_support.hpp"
#include "tests/map_file_support.hpp"

namespace slam {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;
using testing::CommandResult;
using testing::RunCommand;

constexpr int64_t kBudget = 16250;

/// One run mapped once for the whole suite, its map saved by the project's export and read back.
class LocalizeTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fs::path(::testing::TempDir()) / ("slam_localize_test_" + std::to_string(::getpid()));
    fs::remove_all(root_);
    experiment_ = testing::GenerateExperiment((root_ / "rooms").string(), "rooms", 60.0, 3);
    ASSERT_TRUE(experiment_.has_value());
    mapping_.emplace(offline::Replay(experiment_->robot, experiment_->scans,
                                     experiment_->ground_truth, Options()));
    const io::GridImage image = io::MakeGridImage(mapping_->map);
    ASSERT_EQ(image.cells_per_pixel, 1);
    const fs::path map_dir = root_ / "map";
    fs::create_directories(map_dir);
    ASSERT_TRUE(io::WritePgm((map_dir / "map.pgm").string(), image).ok());
    ASSERT_TRUE(io::WriteMapYaml((map_dir / "map.yaml").string(), "map.pgm", image).ok());
    auto loaded = io::LoadMapYaml((map_dir / "map.yaml").string(), mapping_->map.geometry(),
                                  mapping_->map.limit());
    ASSERT_TRUE(loaded.ok()) << loaded.Message();
    map_.emplace(std::move(loaded).value());
  }
  static void TearDownTestSuite() {
    fs::remove_all(root_);
    experiment_.reset();
    mapping_.reset();
    map_.reset();
  }

  static offline::ReplayOptions Options() {
    offline::ReplayOptions options;
    options.params = ParamsChoice{};  // the shipped sets, as slam-replay runs without --params
    options.budget.rays_per_scan = kBudget;
    options.config.seed = 1;
    return options;
  }
  static offline::ReplayOptions LocalizeOptions() {
    offline::ReplayOptions options = Options();
    options.map = *map_;
    options.localize_only = true;
    return options;
  }
  static offline::ReplayResult Run(const offline::ReplayOptions& options) {
    return offline::Replay(experiment_->robot, experiment_->scans, experiment_->ground_truth,
                           options);
  }
  static double Start() { return experiment_->scans.front().t_begin; }

  static inline fs::path root_;
  static inline std::optional<offline::Experiment> experiment_;
  static inline std::optional<offline::ReplayResult> mapping_;
  static inline std::optional<OccupancyGrid> map_;
};

/// Every cell of the map, for exact comparisons.
std::vector<std::pair<TileIndex, std::array<LogOdds, kTileCells>>> Cells(const OccupancyGrid& g) {
  std::vector<std::pair<TileIndex, std::array<LogOdds, kTileCells>>> cells;
  for (const TileRef& t : g.Tiles()) cells.emplace_back(t.index, t.tile->cells);
  std::sort(cells.begin(), cells.end(), [](const auto& a, const auto& b) {
    return std::tie(a.first.y, a.first.x) < std::tie(b.first.y, b.first.x);
  });
  return cells;
}

/// How far `trajectory` strays from `reference` over its poses at or after `from_t`: the
/// largest and the mean distance, and the largest heading difference (degrees).
struct Deviation {
  double max_m = 0.0;
  double mean_m = 0.0;
  double max_deg = 0.0;
  size_t poses = 0;
};
Deviation DeviationFrom(const std::vector<TimedPose>& trajectory,
                        const std::vector<TimedPose>& reference, double from_t) {
  Deviation d;
  double sum = 0.0;
  for (const TimedPose& p : trajectory) {
    if (p.t < from_t) continue;
    const std::optional<Pose2> r = PoseAt(reference, p.t);
    if (!r) continue;
    const double distance = (r->translation() - p.pose.translation()).norm();
    d.max_m = std::max(d.max_m, distance);
    d.max_deg = std::max(d.max_deg, std::abs(RadToDeg(NormalizeAngle(r->theta - p.pose.theta))));
    sum += distance;
    ++d.poses;
  }
  d.mean_m = d.poses > 0 ? sum / static_cast<double>(d.poses) : 0.0;
  return d;
}

TEST_F(LocalizeTest, FromTheStartPoseTheTrackFollowsTheMappingAndTheMapStaysCellForCell) {
  offline::ReplayOptions options = LocalizeOptions();
  options.start_pose = Pose2{};  // mapping started at the origin
  const offline::ReplayResult run = Run(options);
  EXPECT_TRUE(run.relocalizations.empty());
  EXPECT_EQ(run.lookups_total, 0);
  EXPECT_EQ(run.scans, static_cast<int64_t>(experiment_->scans.size()));
  const Deviation d = DeviationFrom(run.trajectory, mapping_->trajectory, Start());
  EXPECT_GT(d.poses, experiment_->scans.size());
  EXPECT_LT(d.mean_m, 0.02);
  EXPECT_LT(d.max_m, 0.05);
  EXPECT_LT(d.max_deg, 5.0);
  EXPECT_TRUE(Cells(run.map) == Cells(*map_));  // localise-only: not one cell written
  EXPECT_GT(run.rays_total, 0);
}

TEST_F(LocalizeTest, WithoutAPoseItRelocalisesOnceWithinTwentySecondsThenTracks) {
  offline::ReplayOptions options = LocalizeOptions();
  options.log_searches = true;
  const offline::ReplayResult run = Run(options);
  ASSERT_EQ(run.relocalizations.size(), 1u);
  const offline::ReplayRelocalization& r = run.relocalizations.front();
  // The searches logged: those that ended unsure (each with the places it scored, best first),
  // then the answer, as the relocalisation reported it.
  ASSERT_FALSE(run.searches.empty());
  const offline::ReplaySearch& last = run.searches.back();
  EXPECT_EQ(last.outcome, offline::SearchOutcome::kAnswer);
  EXPECT_EQ(last.t, r.t);
  ASSERT_EQ(last.places.size(), 1u);
  EXPECT_EQ(last.places[0].pose.x, r.found.pose.x);
  EXPECT_EQ(last.places[0].pose.theta, r.found.pose.theta);
  EXPECT_EQ(last.places[0].score, r.found.score);
  EXPECT_EQ(last.points, r.found.points);
  EXPECT_EQ(static_cast<int64_t>(run.searches.size()) - 1, run.searches_unsure);
  // Each line's cost runs from the line before: together, what the relocalisation spent, over
  // the scans it took.
  int64_t lookups = 0, scans = 0;
  for (const offline::ReplaySearch& s : run.searches) {
    EXPECT_GT(s.lookups, 0);
    EXPECT_GT(s.scans, 0);
    lookups += s.lookups;
    scans += s.scans;
  }
  EXPECT_EQ(lookups, r.found.lookups);
  EXPECT_EQ(scans, r.scans);
  for (size_t i = 0; i + 1 < run.searches.size(); ++i) {
    const offline::ReplaySearch& s = run.searches[i];
    EXPECT_NE(s.outcome, offline::SearchOutcome::kAnswer) << i;
    EXPECT_GE(s.t, Start());
    EXPECT_LT(s.t, r.t);
    EXPECT_LE(s.t, run.searches[i + 1].t);
    ASSERT_FALSE(s.places.empty()) << i;
    EXPECT_EQ(s.points, 0);
    for (size_t k = 1; k < s.places.size(); ++k) EXPECT_LE(s.places[k].score, s.places[0].score);
  }
  EXPECT_EQ(r.cause, offline::RelocalizationStart::kStart);
  EXPECT_TRUE(r.taken);
  EXPECT_EQ(r.started_t, Start());
  EXPECT_LT(r.t - Start(), 20.0);
  EXPECT_GT(r.scans, 1);
  EXPECT_EQ(r.found.lookups, run.lookups_total);
  EXPECT_EQ(run.relocalizing_scans, r.scans);
  EXPECT_FALSE(run.relocalizing_at_end);
  const std::optional<Pose2> truth = PoseAt(mapping_->trajectory, r.t);
  ASSERT_TRUE(truth);
  EXPECT_LT((truth->translation() - r.found.pose.translation()).norm(), 0.05);
  // Nothing tracked before the answer; after it, the mapping's track.
  ASSERT_FALSE(run.trajectory.empty());
  EXPECT_GE(run.trajectory.front().t, r.t);
  const Deviation d = DeviationFrom(run.trajectory, mapping_->trajectory, r.t);
  EXPECT_LT(d.mean_m, 0.03);
  EXPECT_LT(d.max_m, 0.08);
  EXPECT_TRUE(Cells(run.map) == Cells(*map_));
}

TEST_F(LocalizeTest, AfterAStretchLeftOutTheRobotIsReacquired) {
  offline::ReplayOptions options = LocalizeOptions();
  options.start_pose = Pose2{};
  options.drop = {{20.0, 28.0}};
  const offline::ReplayResult run = Run(options);
  EXPECT_GT(run.scans_dropped, 3);
  EXPECT_EQ(run.scans + run.scans_dropped, static_cast<int64_t>(experiment_->scans.size()));
  ASSERT_EQ(run.relocalizations.size(), 1u);
  const offline::ReplayRelocalization& r = run.relocalizations.front();
  EXPECT_EQ(r.cause, offline::RelocalizationStart::kDrop);
  EXPECT_GE(r.started_t - Start(), 28.0);
  EXPECT_LT(r.started_t - Start(), 30.0);
  EXPECT_LT(r.t - r.started_t, 20.0);
  // Before the stretch and after the answer, the mapping's track; nothing between.
  const Deviation before = DeviationFrom(run.trajectory, mapping_->trajectory, Start());
  const Deviation after = DeviationFrom(run.trajectory, mapping_->trajectory, r.t);
  EXPECT_LT(after.mean_m, 0.03);
  EXPECT_LT(after.max_m, 0.08);
  EXPECT_LT(before.max_m, 0.08);
  // The engine had no pose from the last scan it processed before the stretch to the answer.
  ASSERT_EQ(run.untracked.size(), 1u);
  EXPECT_GT(run.untracked[0].t0_s, 19.0);
  EXPECT_LT(run.untracked[0].t0_s, 21.0);
  EXPECT_NEAR(run.untracked[0].t1_s, r.t - Start(), 1e-9);
  for (const TimedPose& p : run.trajectory) {
    EXPECT_FALSE(p.t > Start() + run.untracked[0].t0_s && p.t < r.t) << p.t - Start();
  }
  EXPECT_TRUE(Cells(run.map) == Cells(*map_));

  // Unannounced, the engine tracks on from where it was: no relocalisation...
  options.relocalize_after_drop = false;
  const offline::ReplayResult unannounced = Run(options);
  EXPECT_TRUE(unannounced.relocalizations.empty());
  EXPECT_EQ(unannounced.lookups_total, 0);
  // ... unless the loss detector finds it lost: then it relocalises.
  options.loss_detector = LossDetectorConfig{};
  const offline::ReplayResult detected = Run(options);
  EXPECT_TRUE(detected.searches.empty());  // not asked for
  EXPECT_EQ(detected.losses, 1);
  ASSERT_EQ(detected.relocalizations.size(), 1u);
  const offline::ReplayRelocalization& found = detected.relocalizations.front();
  EXPECT_EQ(found.cause, offline::RelocalizationStart::kLost);
  EXPECT_GE(found.started_t - Start(), 28.0);
  EXPECT_LT(found.started_t - Start(), 34.0);  // found lost within a few scans
  EXPECT_LT(found.t - found.started_t, 20.0);
  const Deviation tracked = DeviationFrom(detected.trajectory, mapping_->trajectory, found.t);
  EXPECT_LT(tracked.mean_m, 0.03);
  EXPECT_TRUE(Cells(detected.map) == Cells(*map_));
}

TEST_F(LocalizeTest, AStretchLeftOutWhileMappingRelocalisesOnTheMapSoFar) {
  offline::ReplayOptions options = Options();
  options.drop = {{20.0, 24.0}};
  const offline::ReplayResult run = Run(options);
  ASSERT_EQ(run.relocalizations.size(), 1u);
  EXPECT_EQ(run.relocalizations.front().cause, offline::RelocalizationStart::kDrop);
  // Where the mapping without the stretch had the robot then.
  const offline::ReplayRelocalization& r = run.relocalizations.front();
  const std::optional<Pose2> truth = PoseAt(mapping_->trajectory, r.t);
  ASSERT_TRUE(truth);
  EXPECT_LT((truth->translation() - r.found.pose.translation()).norm(), 0.05);
  // The start's cut is no kidnap: the replay starts at the first scan kept.
  options.drop = {{0.0, 10.0}};
  const offline::ReplayResult cut = Run(options);
  EXPECT_TRUE(cut.relocalizations.empty());
  ASSERT_FALSE(cut.trajectory.empty());
  EXPECT_GE(cut.trajectory.front().t, Start() + 9.0);
}

TEST_F(LocalizeTest, SlamReplayLocalisesOnAMapYamlAndOnSlamdsState) {
  const fs::path scratch = root_ / "cli";
  fs::create_directories(scratch);
  const std::string tool = std::string(SLAM_REPLAY_BIN) + " " + (root_ / "rooms").string() +
                           " --budget " + std::to_string(kBudget) + " --quiet";
  const CommandResult run =
      RunCommand(tool + " --localize " + (root_ / "map" / "map.yaml").string() +
                     " --pose 0,0,0 --drop 20:28 --out " + (scratch / "yaml").string(),
                 scratch);
  ASSERT_EQ(run.status, 0) << run.err;
  const Json j = Json::parse(run.out);
  EXPECT_TRUE(j["localize"].get<bool>());
  EXPECT_TRUE(j["localize_only"].get<bool>());
  EXPECT_EQ(j["localize_map"]["kind"], "map.yaml");
  EXPECT_EQ(j["start_pose"]["x"], 0.0);
  ASSERT_EQ(j["drop"].size(), 1u);
  EXPECT_EQ(j["drop"][0]["from_s"], 20.0);
  ASSERT_EQ(j["relocalizations"].size(), 1u);
  const Json& r = j["relocalizations"][0];
  EXPECT_EQ(r["cause"], "drop");
  EXPECT_LT(r["took_s"].get<double>(), 20.0);
  EXPECT_GT(r["lookups"].get<int64_t>(), 0);
  EXPECT_EQ(j["lookups_total"], r["lookups"]);
  // Simulated: the answer's error against the ground truth, aligned.
  ASSERT_TRUE(r.contains("error_m"));
  EXPECT_LT(r["error_m"].get<double>(), 0.1);
  EXPECT_FALSE(j["detect_loss"].get<bool>());
  EXPECT_EQ(j["losses"], 0);
  EXPECT_TRUE(j["losses_s"].empty());
  EXPECT_TRUE(j["loss_share_max"].is_null());
  EXPECT_TRUE(j["watch"].is_null());
  const CommandResult detected =
      RunCommand(tool + " --localize " + (root_ / "map" / "map.yaml").string() +
                     " --pose 0,0,0 --drop 20:28 --no-relocalize --detect-loss --log-searches"
                     " --out " +
                     (scratch / "lost").string(),
                 scratch);
  ASSERT_EQ(detected.status, 0) << detected.err;
  const Json lost = Json::parse(detected.out);
  EXPECT_TRUE(lost["detect_loss"].get<bool>());
  EXPECT_FALSE(lost["relocalize_after_drop"].get<bool>());
  EXPECT_EQ(lost["losses"], 1);
  ASSERT_EQ(lost["relocalizations"].size(), 1u);
  EXPECT_EQ(lost["relocalizations"][0]["cause"], "lost");
  // When it was found lost, and the window share that said so.
  ASSERT_EQ(lost["losses_s"].size(), 1u);
  EXPECT_DOUBLE_EQ(lost["losses_s"][0].get<double>(),
                   lost["relocalizations"][0]["started_s"].get<double>());
  EXPECT_GE(lost["loss_share_max"]["share"].get<double>(), LossDetectorConfig{}.lost_share);
  EXPECT_LE(lost["loss_share_max"]["t_s"].get<double>(), lost["losses_s"][0].get<double>() + 2.0);
  EXPECT_TRUE(lost["watch"].is_null());  // not asked for
  // --log-searches: a line a search, the last the answer, each place against the ground truth.
  ASSERT_EQ(lost["searches_file"], (scratch / "lost" / "searches.jsonl").string());
  std::ifstream log(lost["searches_file"].get<std::string>());
  std::vector<Json> searches;
  for (std::string line; std::getline(log, line);) searches.push_back(Json::parse(line));
  ASSERT_FALSE(searches.empty());
  EXPECT_EQ(static_cast<int64_t>(searches.size()) - 1, lost["searches_unsure"].get<int64_t>());
  const Json& answer = searches.back();
  EXPECT_EQ(answer["outcome"], "answer");
  EXPECT_DOUBLE_EQ(answer["t_s"].get<double>(), lost["relocalizations"][0]["t_s"].get<double>());
  EXPECT_EQ(answer["points"], lost["relocalizations"][0]["points"]);
  ASSERT_EQ(answer["places"].size(), 1u);
  EXPECT_DOUBLE_EQ(answer["places"][0]["error_m"].get<double>(),
                   lost["relocalizations"][0]["error_m"].get<double>());
  for (const Json& s : searches) {
    EXPECT_TRUE(s["outcome"] == "unsure" || s["outcome"] == "unconfirmed" || &s == &answer)
        << s.dump();
    ASSERT_FALSE(s["places"].empty()) << s.dump();
    EXPECT_TRUE(s["places"][0].contains("heading_error_deg")) << s.dump();
    EXPECT_GT(s["lookups"].get<int64_t>(), 0) << s.dump();
    EXPECT_GT(s["scans"].get<int64_t>(), 0) << s.dump();
  }
  // The background check, asked for: what it spent and found, in the summary.
  const CommandResult watched =
      RunCommand(std::string(SLAM_REPLAY_BIN) + " " + (root_ / "rooms").string() +
                     " --quiet --detect-loss --watch --out " + (scratch / "watched").string(),
                 scratch);
  ASSERT_EQ(watched.status, 0) << watched.err;
  const Json w = Json::parse(watched.out);
  ASSERT_TRUE(w["watch"].is_object());
  EXPECT_GT(w["watch"]["lookups"].get<int64_t>(), 0);
  EXPECT_GE(w["watch"]["searches_unsure"].get<int64_t>() + w["watch"]["confirmed"].get<int64_t>(),
            1)
      << "a search ended";
  // The map written is the map localised on.
  EXPECT_EQ(testing::ReadFile((scratch / "yaml" / "map.pgm").string()),
            testing::ReadFile((root_ / "map" / "map.pgm").string()));

  // slamd's saved state of the same map; a folder holding a map.yaml.
  const fs::path state = scratch / "state";
  server::SaveInputs inputs;
  inputs.version = 7;
  inputs.resolution_m = map_->geometry().resolution();
  inputs.grid = &*map_;
  ASSERT_TRUE(server::SaveState(state.string(), inputs).ok());
  for (const fs::path& where : {state, root_ / "map"}) {
    const CommandResult saved = RunCommand(
        tool + " --localize " + where.string() + " --out " + (scratch / "state-out").string(),
        scratch);
    ASSERT_EQ(saved.status, 0) << saved.err;
    const Json s = Json::parse(saved.out);
    EXPECT_EQ(s["localize_map"]["kind"], where == state ? "slamd-state" : "map.yaml");
    ASSERT_EQ(s["relocalizations"].size(), 1u);
    EXPECT_EQ(s["relocalizations"][0]["cause"], "start");
    EXPECT_EQ(testing::ReadFile((scratch / "state-out" / "map.pgm").string()),
              testing::ReadFile((root_ / "map" / "map.pgm").string()));
  }

  // --from and --until cut the recording; --drop also while mapping.
  const CommandResult cut = RunCommand(
      tool + " --from 5 --until 40 --drop 20:24 --out " + (scratch / "cut").string(), scratch);
  ASSERT_EQ(cut.status, 0) << cut.err;
  const Json c = Json::parse(cut.out);
  EXPECT_FALSE(c["localize"].get<bool>());
  EXPECT_EQ(c["from_s"], 5.0);
  EXPECT_EQ(c["until_s"], 40.0);
  EXPECT_TRUE(c["drop"][0]["from_s"].is_null());
  EXPECT_GT(c["scans_dropped"].get<int64_t>(), 0);
  EXPECT_EQ(c["relocalizations"].size(), 1u);
}

TEST_F(LocalizeTest, SlamReplaysBadLocalisationOptionsExitWithStatusTwo) {
  const fs::path scratch = root_ / "cli-errors";
  fs::create_directories(scratch);
  const std::string tool = std::string(SLAM_REPLAY_BIN) + " " + (root_ / "rooms").string() +
                           " --quiet --out " + (scratch / "out").string();
  const std::string yaml = (root_ / "map" / "map.yaml").string();
  std::ofstream(scratch / "bad.yaml") << "image: map.pgm\nresolution: x\n";
  fs::create_directories(scratch / "empty");
  struct Case {
    std::string args;
    std::string message;
  };
  const std::vector<Case> cases = {
      {"--pose 0,0,0", "--pose needs --localize MAP"},
      {"--localize " + yaml + " --pose 0,0", "--pose 0,0: expected X,Y,THETA_DEG"},
      {"--localize " + yaml + " --pose 0,nan,0", "expected X,Y,THETA_DEG"},
      {"--localize " + yaml + " --pose 1e9,0,0", "--pose 1e9,0,0: outside the map's bound"},
      {"--drop 5:3", "--drop 5:3: expected T0:T1 with 0 <= T0 < T1"},
      {"--drop 5", "--drop 5: expected T0:T1"},
      {"--drop -1:3", "--drop -1:3: expected T0:T1"},
      {"--drop a:b", "--drop a:b"},
      {"--from 30 --until 10", "--from 30.000000 is not before --until 10.000000"},
      {"--from 1000", "leave no scan of"},
      {"--localize " + (scratch / "none.yaml").string(), "none.yaml: the map's yaml not found"},
      {"--localize " + (scratch / "bad.yaml").string(),
       (scratch / "bad.yaml").string() + ":2: resolution: 'x' is not a finite number"},
      {"--localize " + (scratch / "empty").string(), "neither a slamd state directory"},
      {"--watch", "--watch needs --detect-loss"},
  };
  for (const Case& c : cases) {
    const CommandResult run = RunCommand(tool + " " + c.args, scratch);
    EXPECT_EQ(run.status, 2) << c.args << "\n" << run.err;
    EXPECT_NE(run.err.find(c.message), std::string::npos)
        << c.args << ": wanted \"" << c.message << "\" in:\n"
        << run.err;
    EXPECT_TRUE(run.out.empty()) << c.args;
  }
  const CommandResult help = RunCommand(std::string(SLAM_REPLAY_BIN) + " --help", scratch);
  EXPECT_EQ(help.status, 0);
  for (const char* option :
       {"--localize", "--pose", "--drop", "--from", "--until", "--no-relocalize", "--detect-loss",
        "--watch", "seconds after the first scan"}) {
    EXPECT_NE(help.out.find(option), std::string::npos) << option;
  }
}

}  // namespace
}  // namespace slam
