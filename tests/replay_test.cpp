// Replays of small generated experiments end to end: determinism (same seed, parallel or
// serial), the files slam-replay writes read back by independent parsers, and the evaluation
// table. The command lines are in replay_cli_test.cpp.

#include "offline/replay.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <thread>

#include "engine/io/map_image.hpp"
#include "engine/io/params_json.hpp"
#include "engine/io/tum.hpp"
#include "engine/match_window.hpp"
#include "offline/evaluation.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/replay_report.hpp"
#include "sim/experiment_writer.hpp"
#include "sim/scenario.hpp"
#include "tests/experiment_support.hpp"
#include "tests/map_file_support.hpp"
#include "tests/replay_fixture.hpp"
#include "tests/test_support.hpp"

namespace slam {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;

/// Every cell of the map, for exact comparisons.
std::vector<std::pair<TileIndex, std::array<LogOdds, kTileCells>>> Cells(const OccupancyGrid& g) {
  std::vector<std::pair<TileIndex, std::array<LogOdds, kTileCells>>> cells;
  for (const TileRef& t : g.Tiles()) cells.emplace_back(t.index, t.tile->cells);
  std::sort(cells.begin(), cells.end(), [](const auto& a, const auto& b) {
    return std::tie(a.first.y, a.first.x) < std::tie(b.first.y, b.first.x);
  });
  return cells;
}

void ExpectSameRun(const offline::ReplayResult& a, const offline::ReplayResult& b) {
  ASSERT_EQ(a.trajectory.size(), b.trajectory.size());
  for (size_t i = 0; i < a.trajectory.size(); ++i) {
    ASSERT_EQ(a.trajectory[i].t, b.trajectory[i].t) << i;
    ASSERT_EQ(a.trajectory[i].pose.x, b.trajectory[i].pose.x) << i;
    ASSERT_EQ(a.trajectory[i].pose.y, b.trajectory[i].pose.y) << i;
    ASSERT_EQ(a.trajectory[i].pose.theta, b.trajectory[i].pose.theta) << i;
  }
  EXPECT_EQ(a.rays_total, b.rays_total);
  EXPECT_TRUE(Cells(a.map) == Cells(b.map));
}

/// Copies experiment `from` into `to`, shifting the logged times of can.log lines and of
/// groundtruth.tum poses at or after `from_s` (seconds after the log's first frame) by
/// `shift_s`; can.log lines logged in [drop_from_s, drop_to_s) are left out.
void CopyWithClockChange(const fs::path& from, const fs::path& to, double from_s, double shift_s,
                         double drop_from_s = 0.0, double drop_to_s = 0.0) {
  fs::remove_all(to);
  fs::copy(from, to);
  std::optional<double> first;
  const auto rewrite = [&](const std::string& name, bool log) {
    std::ifstream in(from / name);
    std::ostringstream out;
    out.precision(6);
    out << std::fixed;
    std::string line;
    while (std::getline(in, line)) {
      const size_t begin = log ? 1 : 0;
      const size_t end = line.find(log ? ')' : ' ');
      if (line.empty() || line[0] == '#' || end == std::string::npos) {
        out << line << '\n';
        continue;
      }
      double t = std::stod(line.substr(begin, end - begin));
      if (!first) first = t;
      const double since = t - *first;
      if (log && since >= drop_from_s && since < drop_to_s) continue;
      if (since >= from_s) t += shift_s;
      out << (log ? "(" : "") << t << line.substr(end) << '\n';
    }
    std::ofstream(to / name, std::ios::trunc) << out.str();
  };
  rewrite("can.log", true);
  rewrite("groundtruth.tum", false);
}

TEST_F(ReplayTest, AClockJumpInTheLogMovesTheGroundTruthWithTheScans) {
  // The replay takes the jump out of the scans' time; the ground truth kept the log's clock, so
  // every pose after the jump was compared with the ground truth an hour later: ATE inflated.
  const fs::path jumped = root_ / "box-clock-ahead";
  CopyWithClockChange(root_ / "box", jumped, 20.0, 3600.0);
  const Result<offline::Experiment> load = offline::LoadExperiment(jumped.string());
  ASSERT_TRUE(load.ok()) << load.Message();
  const offline::Experiment& e = load.value();
  EXPECT_EQ(e.counters.clock_jumps, 1u);
  EXPECT_EQ(e.counters.ground_truth_unplaced, 0u);
  ASSERT_EQ(e.ground_truth.size(), Box().ground_truth.size());
  // The scan in progress at the jump is abandoned.
  EXPECT_NEAR(static_cast<double>(e.scans.size()), static_cast<double>(Box().scans.size()), 1.0);
  // After the jump, scans and ground truth moved by the same amount in the replay's time.
  const double scan_shift = e.scans.back().t_end - Box().scans.back().t_end;
  const double truth_shift = e.ground_truth.back().t - Box().ground_truth.back().t;
  EXPECT_NEAR(truth_shift, scan_shift, 1e-5);
  EXPECT_EQ(e.ground_truth.front().t, Box().ground_truth.front().t);
  // ... so the evaluation is the unshifted experiment's, within what the 1 s the jump left
  // in the replay's time changes.
  const offline::ReplayResult base = Run(Box(), 8000, true, 1, false);
  const offline::ReplayResult run = Run(e, 8000, true, 1, false);
  ASSERT_TRUE(base.quality && run.quality);
  EXPECT_NEAR(run.quality->matched, base.quality->matched, 3);
  EXPECT_LT(run.quality->ate_rmse_m, base.quality->ate_rmse_m + 0.01);
}

TEST_F(ReplayTest, GroundTruthInASilenceTakenForAClockJumpIsLeftOutAndCounted) {
  // Nothing logged from 10 s to 17 s (more than the 5 s that make a jump): the replay goes on
  // 1 s later, and ground truth from inside the silence matches no replayed time.
  const fs::path silent = root_ / "box-silent";
  CopyWithClockChange(root_ / "box", silent, 1e9, 0.0, 10.0, 17.0);
  const Result<offline::Experiment> load = offline::LoadExperiment(silent.string());
  ASSERT_TRUE(load.ok()) << load.Message();
  const offline::Experiment& e = load.value();
  EXPECT_EQ(e.counters.clock_jumps, 1u);
  // 7 s of the tracker's 30 Hz, less 0.2 s at either end that still belongs to the frames beside
  // it.
  EXPECT_NEAR(static_cast<double>(e.counters.ground_truth_unplaced), 30.0 * 6.6, 2.0);
  EXPECT_EQ(e.ground_truth.size() + e.counters.ground_truth_unplaced, Box().ground_truth.size());
  for (size_t i = 1; i < e.ground_truth.size(); ++i) {
    ASSERT_LT(e.ground_truth[i - 1].t, e.ground_truth[i].t) << i;
  }
}

TEST_F(ReplayTest, SameSeedSameOutputParallelOrSerial) {
  const offline::ReplayResult serial = Run(Box(), 16250, true, 7, false, 3);
  const offline::ReplayResult parallel = Run(Box(), 16250, true, 7, true, 3);
  const offline::ReplayResult again = Run(Box(), 16250, true, 7, true, 3);
  ExpectSameRun(serial, parallel);
  ExpectSameRun(parallel, again);
  // And the seed matters: another one gives another trajectory.
  const offline::ReplayResult other = Run(Box(), 16250, true, 8, true, 3);
  ASSERT_EQ(other.trajectory.size(), serial.trajectory.size());
  EXPECT_NE(other.trajectory.back().pose.x, serial.trajectory.back().pose.x);
}

TEST_F(ReplayTest, BudgetBoundsEveryScanAndPhaseBOffFollowsOdometry) {
  const offline::ReplayResult slam = Run(Box(), 8125, true, 1, true);
  EXPECT_EQ(slam.scans, static_cast<int64_t>(Box().scans.size()));
  EXPECT_LE(slam.rays_per_scan_max, 8125);
  EXPECT_GT(slam.rays_total, slam.scans * 8125 * 9 / 10);
  // Phase B off: the trajectory is dead reckoning, pose for pose.
  const offline::ReplayResult odometry = Run(Box(), 8125, false, 1, true);
  const std::vector<TimedPose> dead = offline::DeadReckoning(Box().scans);
  ASSERT_EQ(odometry.trajectory.size(), dead.size());
  for (size_t i = 0; i < dead.size(); ++i) {
    ASSERT_EQ(odometry.trajectory[i].t, dead[i].t) << i;
    ASSERT_NEAR(odometry.trajectory[i].pose.x, dead[i].pose.x, 1e-12) << i;
    ASSERT_NEAR(odometry.trajectory[i].pose.y, dead[i].pose.y, 1e-12) << i;
    ASSERT_NEAR(odometry.trajectory[i].pose.theta, dead[i].pose.theta, 1e-12) << i;
  }
}

TEST_F(ReplayTest, ACancelledReplayStopsAfterTheScanInProgress) {
  // A tuning job read its cancel flag only between evaluations: at 2e7 rays/scan a cancel took
  // 65 s, and SIGTERM waited for it. The replay now looks at the flag before every scan.
  std::atomic<bool> cancel{false};
  offline::ReplayOptions options;
  options.budget.rays_per_scan = 2000;
  options.cancel = &cancel;
  options.progress = [&](size_t done, size_t) {
    if (done == 3) cancel = true;
  };
  const offline::ReplayResult run =
      offline::Replay(Box().robot, Box().scans, Box().ground_truth, options);
  ASSERT_GT(Box().scans.size(), 10u);
  EXPECT_TRUE(run.cancelled);
  EXPECT_EQ(run.scans, 3);
  EXPECT_EQ(run.plans.size(), 3u);
  cancel = false;
  options.progress = nullptr;
  const offline::ReplayResult whole =
      offline::Replay(Box().robot, Box().scans, Box().ground_truth, options);
  EXPECT_FALSE(whole.cancelled);
  EXPECT_EQ(whole.scans, static_cast<int64_t>(Box().scans.size()));
}

TEST_F(ReplayTest, AReplayStopsOnceNoLaterScanCanBringItsErrorDown) {
  // The tuner's racing: stop_above_e stops a replay once the lower bound of its final e (over
  // every particle's history) exceeds it; the bound never exceeds the e of the whole replay.
  for (const bool refine : {false, true}) {
    offline::ReplayOptions options;
    options.budget.rays_per_scan = 2000;
    options.refine = refine;
    SlamParams params;
    params.particles = 3;
    options.params = ParamsChoice("table-ii", params);
    const offline::ReplayResult whole =
        offline::Replay(Box().robot, Box().scans, Box().ground_truth, options);
    ASSERT_TRUE(whole.quality);
    EXPECT_FALSE(whole.stopped_early);
    const double e = whole.quality->e;
    ASSERT_GT(e, 0.0);

    options.stop_above_e = 0.5 * e;
    const offline::ReplayResult stopped =
        offline::Replay(Box().robot, Box().scans, Box().ground_truth, options);
    EXPECT_TRUE(stopped.stopped_early) << refine;
    EXPECT_LT(stopped.scans, whole.scans);
    EXPECT_GT(stopped.e_lower_bound, 0.5 * e);
    EXPECT_LE(stopped.e_lower_bound, e * (1 + 1e-12));
    // Up to the stop it is the same replay (without phase B every particle is the best one).
    ASSERT_LE(stopped.trajectory.size(), whole.trajectory.size());
    for (size_t i = 0; !refine && i < stopped.trajectory.size(); ++i) {
      ASSERT_EQ(stopped.trajectory[i].pose.x, whole.trajectory[i].pose.x) << i;
    }
    // A bar the whole replay stays under never stops it.
    options.stop_above_e = e * (1 + 1e-9);
    const offline::ReplayResult kept =
        offline::Replay(Box().robot, Box().scans, Box().ground_truth, options);
    EXPECT_FALSE(kept.stopped_early);
    EXPECT_EQ(kept.scans, whole.scans);
    EXPECT_EQ(kept.quality->e, e);
  }
}

TEST_F(ReplayTest, ACancelInTheMiddleOfAScanOfSecondsEndsItSoon) {
  // At 1e8 rays/scan one scan takes seconds: the cancel waited for it.
  std::atomic<bool> cancel{false};
  offline::ReplayOptions options;
  options.budget.rays_per_scan = 100'000'000;
  options.cancel = &cancel;
  std::atomic<double> cancelled_at{0.0};
  const auto start = std::chrono::steady_clock::now();
  const auto seconds = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  };
  std::thread canceller([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    cancelled_at = seconds();
    cancel = true;
  });
  const offline::ReplayResult run =
      offline::Replay(Box().robot, Box().scans, Box().ground_truth, options);
  const double ended_at = seconds();
  canceller.join();
  EXPECT_TRUE(run.cancelled);
  EXPECT_LE(run.scans, 1);
  EXPECT_LT(ended_at - cancelled_at, 1.0);  // 1.47 s before, a whole scan
}

TEST_F(ReplayTest, CpuShareSettlesWithinAFifthOfItsTarget) {
  // 2 % of a core on the box experiment: about 13 ms of CPU per 0.68 s scan. The cost per ray
  // starts from the prior (300 ns) and follows the measured one; over the second half of the
  // run the achieved share is within 20 % of the target.
  offline::ReplayOptions options;
  options.budget.mode = QuotaMode::kCpuShare;
  options.budget.cpu_share = 0.02;
  options.config.parallel = false;  // the share is measured on this thread
  const offline::ReplayResult run =
      offline::Replay(Box().robot, Box().scans, Box().ground_truth, options);
  ASSERT_EQ(run.plans.size(), Box().scans.size());
  double cpu = 0.0, robot = 0.0;
  for (size_t k = run.plans.size() / 2; k < run.plans.size(); ++k) {
    const PlanRecord& r = run.plans[k];
    EXPECT_EQ(r.mode, QuotaMode::kCpuShare);
    EXPECT_LE(r.used_rays, r.quota);
    if (!r.fills_quota) continue;
    cpu += r.cpu_s;
    robot += r.scan_period_s;
  }
  ASSERT_GT(robot, 5.0);
  EXPECT_NEAR(cpu / robot, 0.02, 0.2 * 0.02) << "ns per ray " << run.plans.back().ns_per_ray;
  // The quota follows the measured cost: it is not the prior's.
  EXPECT_NE(run.plans.back().quota, run.plans.front().quota);
}

TEST_F(ReplayTest, TheShippedSetOfTheQuotaRunsUnlessOneIsGiven) {
  offline::ReplayOptions options;
  options.params = ParamsChoice{};  // the tools' default
  options.budget.rays_per_scan = 20000;
  const offline::ReplayResult run =
      offline::Replay(Box().robot, Box().scans, Box().ground_truth, options);
  EXPECT_EQ(run.params_set, ShippedParamsFor(16250));
  EXPECT_EQ(run.params_switches, 0);
  const Json summary = offline::ReplaySummary(Box(), run, options);
  EXPECT_EQ(summary["params_set"], "shipped-16250");
  EXPECT_EQ(summary["params"], io::ParamsToJson(ShippedParamsFor(16250).params));
  // The same run as with that set given outright.
  options.params = ParamsChoice("given", ShippedParamsFor(16250).params);
  const offline::ReplayResult given =
      offline::Replay(Box().robot, Box().scans, Box().ground_truth, options);
  EXPECT_EQ(given.params_set.name, "given");
  ASSERT_EQ(given.trajectory.size(), run.trajectory.size());
  EXPECT_EQ(given.trajectory.back().pose.x, run.trajectory.back().pose.x);
  EXPECT_EQ(offline::ReplaySummary(Box(), given, options).count("params_switches"), 0u);

  // Under a CPU share the quota moves with the measured cost per ray; the set follows it. The
  // prior of 1 ns per ray makes the first quotas large (the largest budget's set); the measured
  // cost (tens of ns) brings them down to some thousand rays (the smallest budget's).
  options.params = ParamsChoice{};
  options.budget.mode = QuotaMode::kCpuShare;
  options.budget.cpu_share = 0.0005;
  options.scheduler.initial_ns_per_ray = 1.0;
  options.config.parallel = false;
  const offline::ReplayResult share =
      offline::Replay(Box().robot, Box().scans, Box().ground_truth, options);
  ASSERT_GE(share.plans.size(), 2u);
  EXPECT_EQ(ShippedParamsFor(share.plans.front().quota).budget, 65000);
  EXPECT_EQ(share.params_set, ShippedParamsFor(share.plans.back().quota));
  EXPECT_LT(share.plans.back().quota, 65000);
  EXPECT_GE(share.params_switches, 1);
}

TEST_F(ReplayTest, AdaptivePolicyStaysWithinTheQuotaAndRecordsItsPlans) {
  for (const offline::Experiment& e : *experiments_) {
    offline::ReplayOptions options;
    options.budget.rays_per_scan = 16250;
    options.budget.policy = BudgetPolicy::kAdaptive;
    options.config.parallel = true;
    const offline::ReplayResult run = offline::Replay(e.robot, e.scans, e.ground_truth, options);
    ASSERT_EQ(run.plans.size(), e.scans.size());
    EXPECT_LE(run.rays_per_scan_max, 16250);
    for (const PlanRecord& r : run.plans) {
      EXPECT_EQ(r.policy, BudgetPolicy::kAdaptive);
      EXPECT_LE(r.used_rays, r.quota);
      EXPECT_EQ(r.used_rays, r.planned_rays);
      if (r.fills_quota) {
        EXPECT_GE(r.used_rays, 16250 * 9 / 10);
      }
      EXPECT_LE(r.plan.particles, options.budget.max_particles);
    }
    ASSERT_TRUE(run.quality.has_value());
    // Deterministic like the fixed policy: the same run again gives the same trajectory.
    options.config.parallel = false;
    const offline::ReplayResult again = offline::Replay(e.robot, e.scans, e.ground_truth, options);
    ASSERT_EQ(again.trajectory.size(), run.trajectory.size());
    EXPECT_EQ(again.trajectory.back().pose.x, run.trajectory.back().pose.x);
    EXPECT_EQ(again.rays_total, run.rays_total);
  }
}

TEST_F(ReplayTest, PoseRefinementBeatsOdometryAtTheLargestBudget) {
  for (const offline::Experiment& e : *experiments_) {
    const offline::ReplayResult slam = Run(e, 65000, true, 1, true);
    const offline::ReplayResult odometry = Run(e, 65000, false, 1, true);
    ASSERT_TRUE(slam.quality && odometry.quality);
    EXPECT_LT(slam.quality->ate_rmse_m, odometry.quality->ate_rmse_m) << e.meta.name;
  }
}

TEST_F(ReplayTest, SummaryHasTheContractKeysAndMapQuality) {
  offline::ReplayOptions options;
  options.budget.rays_per_scan = 8125;
  const offline::ReplayResult run =
      offline::Replay(Box().robot, Box().scans, Box().ground_truth, options);
  const Json summary = offline::ReplaySummary(Box(), run, options);
  for (const char* key : {"q", "e", "ate_rmse_m", "scans", "rays_total", "rays_per_scan_max",
                          "budget", "wall_s", "realtime_factor", "frames", "frames_rejected"}) {
    ASSERT_TRUE(summary.contains(key)) << key;
    EXPECT_TRUE(summary[key].is_number()) << key;
  }
  EXPECT_EQ(summary["budget"], 8125);
  EXPECT_EQ(summary.value("ray_kernel", ""), BestWindowKernelName());
  EXPECT_NE(summary.value("ray_kernel", ""), "");
  EXPECT_EQ(summary["frames"], Box().counters.frames);
  EXPECT_EQ(summary["frames_rejected"], 0);
  EXPECT_DOUBLE_EQ(summary["e"].get<double>(), std::log(1.0 - summary["q"].get<double>()));
  const Json& m = summary["map_quality"];
  ASSERT_TRUE(m.is_object());
  EXPECT_GT(m["precision"].get<double>(), 0.8);
  EXPECT_GT(m["recall"].get<double>(), 0.8);
  EXPECT_LE(m["recall"].get<double>(), 1.0);
  // Tracked throughout: the majority's frame is the ATE's, near enough.
  EXPECT_TRUE(m["frame"] == "trajectory" || m["frame"] == "majority") << m["frame"];
  EXPECT_LT(m["frame_shift_m"].get<double>(), 0.02);
  EXPECT_LT(m["frame_rotation_deg"].get<double>(), 1.0);
}

TEST_F(ReplayTest, WrittenMapFilesReadBackWithTheDocumentedValues) {
  const fs::path dir = root_ / "out";
  fs::create_directories(dir);
  const offline::ReplayResult run = Run(Box(), 8125, true, 1, true);
  const auto written = offline::WriteReplayOutputs(dir.string(), Box(), run, false,
                                                   BudgetSettings{.rays_per_scan = 8125});
  ASSERT_TRUE(written.errors.empty()) << written.errors.front();

  // map.yaml: map_server's keys and values.
  const auto yaml = testing::ParseYaml(testing::ReadFile((dir / "map.yaml").string()));
  EXPECT_EQ(yaml.at("image"), "map.pgm");
  EXPECT_DOUBLE_EQ(std::stod(yaml.at("resolution")), 0.01);
  EXPECT_EQ(yaml.at("negate"), "0");
  EXPECT_DOUBLE_EQ(std::stod(yaml.at("occupied_thresh")), 0.65);
  EXPECT_DOUBLE_EQ(std::stod(yaml.at("free_thresh")), 0.196);
  const io::GridImage image = io::MakeGridImage(run.map);
  char origin[128];
  std::snprintf(origin, sizeof(origin), "[%.17g, %.17g, 0.0]", image.origin_m.x(),
                image.origin_m.y());
  double ox = 0, oy = 0, oz = 1;
  ASSERT_EQ(std::sscanf(yaml.at("origin").c_str(), "[%lf, %lf, %lf]", &ox, &oy, &oz), 3);
  EXPECT_DOUBLE_EQ(ox, image.origin_m.x());
  EXPECT_DOUBLE_EQ(oy, image.origin_m.y());
  EXPECT_EQ(oz, 0.0);

  // map.pgm: only the three map_server values, each present, matching the grid.
  const testing::Pgm pgm = testing::ParsePgm(testing::ReadFile((dir / "map.pgm").string()));
  EXPECT_EQ(pgm.magic, "P5");
  EXPECT_EQ(pgm.width, image.width);
  EXPECT_EQ(pgm.height, image.height);
  EXPECT_EQ(pgm.maxval, 255);
  ASSERT_EQ(pgm.pixels.size(), static_cast<size_t>(pgm.width) * static_cast<size_t>(pgm.height));
  std::map<uint8_t, int> histogram;
  for (char c : pgm.pixels) ++histogram[static_cast<uint8_t>(c)];
  EXPECT_EQ(histogram.size(), 3u);
  EXPECT_GT(histogram[0], 500);      // walls
  EXPECT_GT(histogram[254], 10000);  // free space
  EXPECT_GT(histogram[205], 1000);   // unknown around
  // The cell under the robot's start is free.
  const int col = static_cast<int>(std::floor((0.0 - image.origin_m.x()) / 0.01));
  const int row =
      image.height - 1 - static_cast<int>(std::floor((0.0 - image.origin_m.y()) / 0.01));
  EXPECT_EQ(static_cast<uint8_t>(pgm.pixels[static_cast<size_t>(row * pgm.width + col)]), 254);

  // map.png: the rendered picture, with the trajectory and the ground truth drawn.
  const io::RgbImage png = testing::ReadPng((dir / "map.png").string());
  ASSERT_GT(png.width, 0);
  EXPECT_GE(png.width, image.width * 3);
  EXPECT_GT(png.height, image.height * 3);  // the map plus the legend strip
  EXPECT_GT(testing::CountColor(png, 0, 0, png.width, image.height * 3, {230, 0, 0}), 1000);
  EXPECT_GT(testing::CountColor(png, 0, 0, png.width, image.height * 3, {0, 90, 255}), 300);
  EXPECT_GT(testing::CountColor(png, 0, 0, png.width, image.height * 3, {150, 150, 150}), 300);

  // trajectory.tum: the run's trajectory.
  const auto tum = io::LoadTum((dir / "trajectory.tum").string());
  ASSERT_TRUE(tum.ok()) << tum.Message();
  ASSERT_EQ(tum.value().size(), run.trajectory.size());
  EXPECT_NEAR(tum.value().back().pose.x, run.trajectory.back().pose.x, 1e-6);
}

TEST_F(ReplayTest, EvaluationIsTheSameWithOneJobOrTwo) {
  offline::EvaluationPlan plan;
  plan.budgets = {8125, 2000};
  plan.jobs = 1;
  const auto serial = offline::Evaluate(*experiments_, plan);
  plan.jobs = 2;
  size_t calls = 0;
  const auto parallel = offline::Evaluate(
      *experiments_, plan, [&](const offline::EvaluationRun&, size_t done, size_t total) {
        ++calls;
        EXPECT_EQ(done, calls);
        EXPECT_EQ(total, 8u);
      });
  EXPECT_EQ(calls, 8u);
  ASSERT_EQ(serial.size(), 8u);
  ASSERT_EQ(parallel.size(), 8u);
  for (size_t i = 0; i < serial.size(); ++i) {
    Json a = serial[i].summary, b = parallel[i].summary;
    for (const char* timing :
         {"wall_s", "cpu_s", "cpu_ms_per_scan", "realtime_factor", "ns_per_ray"}) {
      a.erase(timing);
      b.erase(timing);
    }
    EXPECT_EQ(a, b) << i;
    EXPECT_EQ(serial[i].budget, parallel[i].budget);
  }
  // Plan order: experiment, SLAM before odometry, budgets as given.
  EXPECT_EQ(serial[0].experiment, 0u);
  EXPECT_TRUE(serial[0].refine);
  EXPECT_EQ(serial[0].budget, 8125);
  EXPECT_FALSE(serial[2].refine);
  EXPECT_EQ(serial[4].experiment, 1u);

  const std::string csv = offline::EvaluationCsv(*experiments_, serial);
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 9);
  EXPECT_EQ(csv.rfind("experiment,world,mode,budget,ate_rmse_m,q,e,", 0), 0u);
  const std::string md = offline::EvaluationMarkdown(*experiments_, serial);
  EXPECT_NE(md.find("| 8125 | SLAM |"), std::string::npos) << md;
  EXPECT_NE(md.find("| box-seed1 |"), std::string::npos) << md;
  // Two worlds: a row per world and budget, with its one experiment.
  EXPECT_NE(md.find("| box | 1 | "), std::string::npos) << md;
  EXPECT_NE(md.find("| rooms | 1 | "), std::string::npos) << md;
  // The plan's default: each budget's shipped set (2000 is below every paper budget).
  EXPECT_NE(md.find("Parameter sets: 2000: shipped-8125, 8125: shipped-8125."), std::string::npos)
      << md;
  const offline::EvaluationChecks checks = offline::CheckEvaluation(serial);
  EXPECT_EQ(checks.largest_budget, 8125);
  EXPECT_EQ(checks.smallest_budget, 2000);
  EXPECT_EQ(checks.experiments_compared, 2);
  EXPECT_NE(md.find("SLAM beats odometry-only on " + std::to_string(checks.slam_beats_odometry) +
                    " of 2 experiments"),
            std::string::npos)
      << md;
}

}  // namespace
}  // namespace slam
