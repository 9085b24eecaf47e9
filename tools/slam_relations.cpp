// slam-relations: scores trajectories (TUM files: this project's runs, or any other system's) on
// a benchmark's relations (the Freiburg format), as slam-replay --relations does, so that other
// SLAM systems' trajectories are measured by the same code on the same relations. Prints one
// JSON object on stdout; --errors DIR writes each trajectory's per-relation errors.

#include <CLI/CLI.hpp>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "engine/io/atomic_file.hpp"
#include "engine/io/text_fields.hpp"
#include "engine/io/tum.hpp"
#include "offline/relations.hpp"
#include "offline/statistics.hpp"
#include "tools/command_line.hpp"

namespace {

using Json = nlohmann::json;

int Fail(const std::string& message) {
  std::cerr << "slam-relations: " << message << "\n";
  return 1;
}

Json FiveNumbersJson(const std::vector<double>& values) {
  const slam::offline::FiveNumbers five = slam::offline::SummarizeFive(values);
  double sum = 0.0;
  for (double v : values) sum += v;
  return {{"mean", sum / static_cast<double>(values.size())},
          {"best", five.min},
          {"median", five.median},
          {"worst", five.max}};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Scores trajectories (TUM: 't x y z qx qy qz qw', times strictly increasing) on benchmark "
      "relations (Freiburg format: 't1 t2 x y z roll pitch yaw'), as slam-replay --relations "
      "does: each relation is scored on the poses nearest in time to t1 and t2 (within the "
      "tolerance) and left out otherwise. Prints one JSON object on stdout: each trajectory's "
      "score and, for several, the mean, best, median and worst of their mean errors."};
  std::vector<std::string> trajectory_paths;
  std::string relations_path, errors_dir;
  double tolerance_s = 0.1;
  app.add_option("TRAJECTORIES", trajectory_paths, "trajectory files (TUM format)")->required();
  app.add_option("--relations", relations_path, "benchmark relations (Freiburg format)")
      ->required();
  app.add_option("--tolerance", tolerance_s,
                 "largest time between a relation's end and the pose it is scored on (s)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 10.0));
  app.add_option("--errors", errors_dir,
                 "write each trajectory's per-relation errors to DIR/<n>-<name>.tsv (the columns "
                 "of slam-replay's relations.tsv, without dead reckoning's)");
  app.set_version_flag("--version", std::string("slam-relations ") + SLAM_VERSION);
  if (const std::optional<int> exit_code = slam::cli::Parse(app, argc, argv)) return *exit_code;

  auto relations = slam::offline::LoadRelations(relations_path);
  if (!relations.ok()) return Fail(relations.Message());
  // Every trajectory is read before any is scored: one bad file fails the run with its line.
  std::vector<std::vector<slam::TimedPose>> trajectories;
  for (const std::string& path : trajectory_paths) {
    // Read, then parsed: an unreadable file is named with the reason (no such file, a
    // directory, permission denied), a bad line with its number.
    const slam::Result<std::string> text = slam::io::ReadTextFile(path);
    if (!text.ok()) return Fail(text.Message());
    auto loaded = slam::io::ParseTum(text.value(), path);
    if (!loaded.ok()) return Fail(loaded.Message());
    if (loaded.value().empty()) return Fail(path + ": no pose");
    trajectories.push_back(std::move(loaded).value());
  }
  if (!errors_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(errors_dir, ec);
    if (ec) return Fail("cannot create " + errors_dir + ": " + ec.message());
  }

  Json runs = Json::array();
  std::vector<double> translational, rotational;
  int status = 0;
  for (size_t i = 0; i < trajectories.size(); ++i) {
    const slam::offline::RelationsScore score =
        slam::offline::ScoreRelations(trajectories[i], relations.value(), tolerance_s);
    Json run = slam::offline::RelationsToJson(score, tolerance_s);
    run["trajectory"] = trajectory_paths[i];
    if (score.used == 0) {
      std::cerr << "slam-relations: " << trajectory_paths[i] << ": no relation has a pose within "
                << tolerance_s << " s at both ends (another clock?)\n";
      status = 1;
    } else {
      translational.push_back(score.translation_m.mean);
      rotational.push_back(score.rotation_deg.mean);
    }
    if (!errors_dir.empty()) {
      const std::string name = std::filesystem::path(trajectory_paths[i]).stem().string();
      const std::string path =
          (std::filesystem::path(errors_dir) / (std::to_string(i + 1) + "-" + name + ".tsv"))
              .string();
      // Without a dead-reckoning run to compare, its columns are "nan" (a score of nothing).
      const auto written = slam::io::WriteFileAtomic(
          path, slam::offline::RelationErrorsText(relations.value(), score, {}));
      if (written.ok()) {
        run["errors_file"] = path;
      } else {
        std::cerr << "slam-relations: " << written.Message() << "\n";
        status = 1;
      }
    }
    runs.push_back(std::move(run));
  }
  Json out = {{"relations_file", relations_path}, {"runs", std::move(runs)}};
  if (translational.size() > 1) {
    out["over_runs"] = {{"runs", translational.size()},
                        {"translational_m", FiveNumbersJson(translational)},
                        {"rotational_deg", FiveNumbersJson(rotational)}};
  }
  std::cout << out.dump(2) << "\n";
  return status;
}
