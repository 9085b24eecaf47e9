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

/// slam-relations' command line, as parsed.
struct RelationsConfig {
  std::vector<std::string> trajectory_paths;
  std::string relations_path, errors_dir;
  double tolerance_s = 0.1;
};

void AddOptions(CLI::App& app, RelationsConfig& c) {
  app.add_option("TRAJECTORIES", c.trajectory_paths, "trajectory files (TUM format)")->required();
  app.add_option("--relations", c.relations_path, "benchmark relations (Freiburg format)")
      ->required();
  app.add_option("--tolerance", c.tolerance_s,
                 "largest time between a relation's end and the pose it is scored on (s)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 10.0));
  app.add_option("--errors", c.errors_dir,
                 "write each trajectory's per-relation errors to DIR/<n>-<name>.tsv (the columns "
                 "of slam-replay's relations.tsv, without dead reckoning's)");
}

/// Every trajectory, read before any is scored: one bad file fails the run with its line.
slam::Result<std::vector<std::vector<slam::TimedPose>>> LoadTrajectories(
    const std::vector<std::string>& paths) {
  std::vector<std::vector<slam::TimedPose>> trajectories;
  for (const std::string& path : paths) {
    // Read, then parsed: an unreadable file is named with the reason (no such file, a
    // directory, permission denied), a bad line with its number.
    const slam::Result<std::string> text = slam::io::ReadTextFile(path);
    if (!text.ok()) return text.errors();
    auto loaded = slam::io::ParseTum(text.value(), path);
    if (!loaded.ok()) return loaded.errors();
    if (loaded.value().empty()) return slam::Error(path + ": no pose");
    trajectories.push_back(std::move(loaded).value());
  }
  return trajectories;
}

/// Trajectory i's score as JSON, with its errors file written when asked for; sets *failed
/// when no relation was scored or the errors file could not be written.
Json RunJson(const RelationsConfig& c, size_t i, const slam::offline::RelationsScore& score,
             const std::vector<slam::offline::Relation>& relations, bool* failed) {
  Json run = slam::offline::RelationsToJson(score, c.tolerance_s);
  run["trajectory"] = c.trajectory_paths[i];
  if (score.used == 0) {
    std::cerr << "slam-relations: " << c.trajectory_paths[i] << ": no relation has a pose within "
              << c.tolerance_s << " s at both ends (another clock?)\n";
    *failed = true;
  }
  if (!c.errors_dir.empty()) {
    const std::string name = std::filesystem::path(c.trajectory_paths[i]).stem().string();
    const std::string path =
        (std::filesystem::path(c.errors_dir) / (std::to_string(i + 1) + "-" + name + ".tsv"))
            .string();
    // Without a dead-reckoning run to compare, its columns are "nan" (a score of nothing).
    const auto written =
        slam::io::WriteFileAtomic(path, slam::offline::RelationErrorsText(relations, score, {}));
    if (written.ok()) {
      run["errors_file"] = path;
    } else {
      std::cerr << "slam-relations: " << written.Message() << "\n";
      *failed = true;
    }
  }
  return run;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Scores trajectories (TUM: 't x y z qx qy qz qw', times strictly increasing) on benchmark "
      "relations (Freiburg format: 't1 t2 x y z roll pitch yaw'), as slam-replay --relations "
      "does: each relation is scored on the poses nearest in time to t1 and t2 (within the "
      "tolerance) and left out otherwise. Prints one JSON object on stdout: each trajectory's "
      "score and, for several, the mean, best, median and worst of their mean errors."};
  RelationsConfig config;
  AddOptions(app, config);
  app.set_version_flag("--version", std::string("slam-relations ") + SLAM_VERSION);
  if (const std::optional<int> exit_code = slam::cli::Parse(app, argc, argv)) return *exit_code;

  auto relations = slam::offline::LoadRelations(config.relations_path);
  if (!relations.ok()) return Fail(relations.Message());
  const auto trajectories = LoadTrajectories(config.trajectory_paths);
  if (!trajectories.ok()) return Fail(trajectories.Message());
  if (!config.errors_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(config.errors_dir, ec);
    if (ec) return Fail("cannot create " + config.errors_dir + ": " + ec.message());
  }

  Json runs = Json::array();
  std::vector<double> translational, rotational;
  bool failed = false;
  for (size_t i = 0; i < trajectories.value().size(); ++i) {
    const slam::offline::RelationsScore score = slam::offline::ScoreRelations(
        trajectories.value()[i], relations.value(), config.tolerance_s);
    runs.push_back(RunJson(config, i, score, relations.value(), &failed));
    if (score.used > 0) {
      translational.push_back(score.translation_m.mean);
      rotational.push_back(score.rotation_deg.mean);
    }
  }
  Json out = {{"relations_file", config.relations_path}, {"runs", std::move(runs)}};
  if (translational.size() > 1) {
    out["over_runs"] = {{"runs", translational.size()},
                        {"translational_m", FiveNumbersJson(translational)},
                        {"rotational_deg", FiveNumbersJson(rotational)}};
  }
  std::cout << out.dump(2) << "\n";
  return failed ? 1 : 0;
}
