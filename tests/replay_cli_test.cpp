// The replay tools on their command lines: slam-replay with each ray kernel, scored on a
// benchmark's relations (and slam-relations on the files it writes), and on good and bad
// experiments.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "engine/io/tum.hpp"
#include "engine/match_window.hpp"
#include "offline/evaluation.hpp"
#include "offline/relations.hpp"
#include "offline/replay.hpp"
#include "tests/command_support.hpp"
#include "tests/map_file_support.hpp"
#include "tests/replay_fixture.hpp"

namespace slam {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;
using testing::CommandResult;
using testing::RunCommand;

// SLAM_RAY_KERNEL caps the ray kernel, slam-replay says which one ran, and the replay's answers
// (trajectory, quality, counters: everything but the timings) are the same with every kernel.
TEST_F(ReplayTest, EveryRayKernelGivesTheSameReplay) {
  const fs::path scratch = root_ / "kernels";
  fs::create_directories(scratch);
  const std::string replay =
      std::string(SLAM_REPLAY_BIN) + " " + (root_ / "rooms").string() + " --budget 65000 --quiet";
  std::vector<std::pair<std::string, Json>> runs;
  for (const std::string kernel : {"", "portable", "avx2"}) {
    const std::string env =
        kernel.empty() ? "env -u SLAM_RAY_KERNEL " : "env SLAM_RAY_KERNEL=" + kernel + " ";
    const fs::path out = scratch / ("out-" + (kernel.empty() ? std::string("best") : kernel));
    const CommandResult run = RunCommand(env + replay + " --out " + out.string(), scratch);
    ASSERT_EQ(run.status, 0) << run.err;
    runs.emplace_back(kernel, Json::parse(run.out));
  }
  EXPECT_EQ(runs[0].second.value("ray_kernel", ""),
            WindowKernelAvailable(WindowKernel::kAvx512) ? "avx512"
            : WindowKernelAvailable(WindowKernel::kAvx2) ? "avx2"
                                                         : "portable");
  EXPECT_EQ(runs[1].second.value("ray_kernel", ""), "portable");
  EXPECT_EQ(runs[2].second.value("ray_kernel", ""),
            WindowKernelAvailable(WindowKernel::kAvx2) ? "avx2" : "portable");
  EXPECT_GT(runs[0].second.value("rays_total", 0), 0);
  for (auto& [kernel, summary] : runs) {
    for (const char* timing :
         {"wall_s", "cpu_s", "cpu_ms_per_scan", "realtime_factor", "ns_per_ray", "ray_kernel"}) {
      summary.erase(timing);
    }
    summary.erase("out");  // each run's own directory
  }
  EXPECT_EQ(runs[1].second, runs[0].second);
  EXPECT_EQ(runs[2].second, runs[0].second);
}

TEST_F(ReplayTest, RelationsScoreTheTrajectoryAndOdometryOnTheBenchmarkMetric) {
  // Relations from the ground truth between scans 20 apart (about 13 s: odometry drifts more
  // than the SLAM errs there; over a second or two it does not), at the scans' times.
  const fs::path scratch = root_ / "relations";
  fs::create_directories(scratch);
  const offline::Experiment& e = Box();
  const auto truth_at = [&](double t) {
    return std::min_element(e.ground_truth.begin(), e.ground_truth.end(),
                            [&](const TimedPose& a, const TimedPose& b) {
                              return std::abs(a.t - t) < std::abs(b.t - t);
                            })
        ->pose;
  };
  std::ostringstream text;
  text.precision(9);
  size_t written = 0;
  for (size_t i = 0; i + 20 < e.scans.size(); i += 2, ++written) {
    const double t1 = e.scans[i].t_end, t2 = e.scans[i + 20].t_end;
    const Pose2 motion = Between(truth_at(t1), truth_at(t2));
    text << std::fixed << t1 << ' ' << t2 << ' ' << motion.x << ' ' << motion.y << " 0 0 0 "
         << motion.theta << '\n';
  }
  ASSERT_GT(written, 10u);
  const std::string relations = (scratch / "box.relations").string();
  std::ofstream(relations) << text.str();

  const std::string tool = std::string(SLAM_REPLAY_BIN) + " " + (root_ / "box").string() +
                           " --budget 65000 --quiet --out " + (scratch / "out").string();
  const CommandResult run = RunCommand(tool + " --relations " + relations, scratch);
  ASSERT_EQ(run.status, 0) << run.err;
  const Json summary = Json::parse(run.out);
  ASSERT_TRUE(summary.contains("relations")) << run.out;
  const Json& r = summary["relations"];
  EXPECT_EQ(r["count"], written);
  EXPECT_EQ(r["relations"], written);
  EXPECT_EQ(r["file"], relations);
  EXPECT_EQ(r["odometry"]["count"], written);
  const double slam_m = r["translational_m"]["mean"],
               odometry_m = r["odometry"]["translational_m"]["mean"];
  EXPECT_GT(slam_m, 0.0);
  EXPECT_LT(slam_m, odometry_m);
  EXPECT_LT(r["rotational_deg"]["mean"].get<double>(),
            r["odometry"]["rotational_deg"]["mean"].get<double>());
  EXPECT_NEAR(r["translational_m"]["squared_mean"].get<double>(),
              std::pow(slam_m, 2) + std::pow(r["translational_m"]["std"].get<double>(), 2), 1e-12);
  // Each relation's errors in relations.tsv: a header and one line per relation, whose
  // translational errors average to the summary's mean.
  EXPECT_EQ(r["errors_file"], (scratch / "out" / "relations.tsv").string());
  std::ifstream errors(scratch / "out" / "relations.tsv");
  std::string line;
  ASSERT_TRUE(std::getline(errors, line));
  EXPECT_EQ(line.rfind("# t1\t", 0), 0u) << line;
  size_t listed = 0;
  double sum_m = 0.0;
  while (std::getline(errors, line)) {
    std::istringstream fields(line);
    std::vector<double> v(17);
    for (double& x : v) ASSERT_TRUE(fields >> x) << line;
    sum_m += v[10];
    ++listed;
  }
  EXPECT_EQ(listed, written);
  EXPECT_NEAR(sum_m / static_cast<double>(listed), slam_m, 1e-4);

  // slam-evaluate --relations scores each of its runs the same way.
  const auto loaded = offline::LoadRelations(relations);
  ASSERT_TRUE(loaded.ok()) << loaded.Message();
  offline::EvaluationPlan plan;
  plan.budgets = {65000};
  plan.odometry_only = false;
  plan.relations = loaded.value();
  plan.outputs_dir = (scratch / "evaluated").string();
  const auto evaluated = offline::Evaluate(std::vector<offline::Experiment>{e}, plan);
  ASSERT_EQ(evaluated.size(), 1u);
  ASSERT_TRUE(evaluated[0].summary.contains("relations"));
  const Json& scored = evaluated[0].summary["relations"];
  EXPECT_EQ(scored["count"], written);
  EXPECT_NEAR(scored["translational_m"]["mean"].get<double>(), slam_m, 1e-9);
  EXPECT_NEAR(scored["rotational_deg"]["mean"].get<double>(),
              r["rotational_deg"]["mean"].get<double>(), 1e-9);
  // With the runs' outputs (--maps), each run's relations.tsv is slam-replay's, line for line.
  EXPECT_TRUE(evaluated[0].errors.empty());
  const auto read = [](const fs::path& path) {
    std::ifstream in(path);
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  };
  const std::string replayed = read(scratch / "out" / "relations.tsv");
  EXPECT_FALSE(replayed.empty());
  EXPECT_EQ(read(scratch / "evaluated" / e.meta.name / "slam-65000" / "relations.tsv"), replayed);

  // slam-relations scores any trajectory file the same way: slam-replay's trajectory.tum and
  // dead reckoning's give the replay's two scores, and over both it reports their spread.
  const std::string scorer = std::string(SLAM_RELATIONS_BIN) + " --relations " + relations;
  const std::string slam_tum = (scratch / "out" / "trajectory.tum").string();
  const std::string odometry_tum = (scratch / "odometry.tum").string();
  std::ofstream(odometry_tum) << io::FormatTum(offline::DeadReckoning(e.scans));
  const CommandResult scored_files = RunCommand(
      scorer + " " + slam_tum + " " + odometry_tum + " --errors " + (scratch / "errors").string(),
      scratch);
  ASSERT_EQ(scored_files.status, 0) << scored_files.err;
  const Json files = Json::parse(scored_files.out);
  ASSERT_EQ(files["runs"].size(), 2u);
  EXPECT_EQ(files["runs"][0]["trajectory"], slam_tum);
  EXPECT_EQ(files["runs"][0]["count"], written);
  // The files carry micrometres and microseconds.
  EXPECT_NEAR(files["runs"][0]["translational_m"]["mean"].get<double>(), slam_m, 1e-5);
  EXPECT_NEAR(files["runs"][1]["translational_m"]["mean"].get<double>(), odometry_m, 1e-5);
  EXPECT_EQ(files["over_runs"]["runs"], 2);
  EXPECT_NEAR(files["over_runs"]["translational_m"]["best"].get<double>(), slam_m, 1e-5);
  EXPECT_NEAR(files["over_runs"]["translational_m"]["worst"].get<double>(), odometry_m, 1e-5);
  EXPECT_NEAR(files["over_runs"]["translational_m"]["mean"].get<double>(),
              (slam_m + odometry_m) / 2.0, 1e-5);
  const std::string listed_errors =
      testing::ReadFile((scratch / "errors" / "1-trajectory.tsv").string());
  EXPECT_EQ(static_cast<size_t>(std::count(listed_errors.begin(), listed_errors.end(), '\n')),
            written + 1);  // the header and one line per relation
  EXPECT_EQ(files["runs"][0]["errors_file"], (scratch / "errors" / "1-trajectory.tsv").string());
  // A trajectory on another clock scores nothing and says so; a broken file names its line.
  const std::string shifted_tum = (scratch / "shifted.tum").string();
  std::vector<TimedPose> shifted = offline::DeadReckoning(e.scans);
  for (TimedPose& p : shifted) p.t += 1000.0;
  std::ofstream(shifted_tum) << io::FormatTum(shifted);
  const CommandResult other_clock = RunCommand(scorer + " " + shifted_tum, scratch);
  EXPECT_EQ(other_clock.status, 1);
  EXPECT_NE(other_clock.err.find("no relation has a pose within 0.1 s"), std::string::npos)
      << other_clock.err;
  const std::string broken_tum = (scratch / "broken.tum").string();
  std::ofstream(broken_tum) << "1 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n";
  const CommandResult broken = RunCommand(scorer + " " + slam_tum + " " + broken_tum, scratch);
  EXPECT_EQ(broken.status, 1);
  EXPECT_TRUE(broken.out.empty());
  EXPECT_NE(broken.err.find("broken.tum:2:"), std::string::npos) << broken.err;

  // A bad relations file is refused before the replay, naming its line.
  std::ofstream(relations, std::ios::app) << "1 2 3\n";
  const CommandResult bad = RunCommand(tool + " --relations " + relations, scratch);
  EXPECT_EQ(bad.status, 1);
  EXPECT_TRUE(bad.out.empty());
  EXPECT_NE(bad.err.find("box.relations:" + std::to_string(written + 1) + ": expected 8 fields"),
            std::string::npos)
      << bad.err;
}

TEST_F(ReplayTest, CommandLineReplaysAndReportsBadExperiments) {
  const fs::path scratch = root_ / "cli";
  fs::create_directories(scratch);
  const std::string tool = SLAM_REPLAY_BIN;

  const CommandResult help = RunCommand(tool + " --help", scratch);
  EXPECT_EQ(help.status, 0);
  EXPECT_NE(help.out.find("--no-refine"), std::string::npos);

  const CommandResult ok =
      RunCommand(tool + " " + (root_ / "rooms").string() +
                     " --budget 4000 --no-refine --quiet --out " + (scratch / "rooms-out").string(),
                 scratch);
  ASSERT_EQ(ok.status, 0) << ok.err;
  const Json summary = Json::parse(ok.out);
  EXPECT_EQ(summary["budget"], 4000);
  EXPECT_EQ(summary["refine"], false);
  EXPECT_EQ(summary["ate_rmse_m"], summary["odometry_ate_rmse_m"]);
  for (const char* file : {"map.pgm", "map.yaml", "map.png", "trajectory.tum"}) {
    EXPECT_TRUE(fs::exists(scratch / "rooms-out" / file)) << file;
  }

  // A broken copy: the error names the file and the line, and the exit status is not 0.
  const fs::path broken = scratch / "broken";
  fs::copy(root_ / "rooms", broken);
  {
    std::string tum = testing::ReadFile((broken / "groundtruth.tum").string());
    tum.insert(0, "1700000010.0 0 0 0 0 0 0 1\n");  // before the first line's time: not increasing
    std::ofstream((broken / "groundtruth.tum").string(), std::ios::trunc) << tum;
  }
  const CommandResult bad = RunCommand(tool + " " + broken.string() + " --quiet", scratch);
  EXPECT_EQ(bad.status, 1);
  EXPECT_TRUE(bad.out.empty());
  EXPECT_NE(bad.err.find("groundtruth.tum:2:"), std::string::npos) << bad.err;

  const CommandResult params = RunCommand(
      tool + " " + (root_ / "rooms").string() + " --params " + (scratch / "none.json").string(),
      scratch);
  EXPECT_EQ(params.status, 1);
  EXPECT_NE(params.err.find("none.json"), std::string::npos) << params.err;

  // Without --params the shipped set of the budget runs; --params names the file it read.
  const CommandResult shipped =
      RunCommand(tool + " " + (root_ / "rooms").string() + " --budget 32500 --quiet --out " +
                     (scratch / "shipped").string(),
                 scratch);
  ASSERT_EQ(shipped.status, 0) << shipped.err;
  EXPECT_EQ(Json::parse(shipped.out)["params_set"], "shipped-32500");
  const std::string mine = (scratch / "mine.json").string();
  std::ofstream(mine) << R"({"particles": 2})";
  const CommandResult given =
      RunCommand(tool + " " + (root_ / "rooms").string() + " --budget 32500 --quiet --params " +
                     mine + " --out " + (scratch / "given").string(),
                 scratch);
  ASSERT_EQ(given.status, 0) << given.err;
  EXPECT_EQ(Json::parse(given.out)["params_set"], mine);
  EXPECT_EQ(Json::parse(given.out)["params"]["particles"], 2);

  const CommandResult usage =
      RunCommand(tool + " " + (root_ / "rooms").string() + " --budget 0", scratch);
  EXPECT_NE(usage.status, 0);
  EXPECT_NE(usage.err.find("--budget"), std::string::npos) << usage.err;
}

}  // namespace
}  // namespace slam
