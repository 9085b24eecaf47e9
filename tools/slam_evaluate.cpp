// slam-evaluate: replays recorded experiments at several ray budgets, with and without phase B,
// in parallel, and writes the results as a table (Markdown and CSV) plus every run's JSON
// summary. scripts/reference runs it on the reference set (docs/performance.md).

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "engine/io/atomic_file.hpp"
#include "engine/io/params_json.hpp"
#include "offline/evaluation.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/replay.hpp"
#include "tools/command_line.hpp"

namespace {

namespace fs = std::filesystem;

int Fail(const std::string& message) {
  std::cerr << "slam-evaluate: " << message << "\n";
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Replays recorded experiments at each ray budget, with phase B (SLAM) and without "
      "(odometry only), and writes results.md, results.csv and runs.json into --out."};
  std::vector<std::string> inputs;
  std::string out_dir, params_path;
  std::vector<int64_t> budgets{8125, 16250, 32500, 65000};
  std::vector<std::string> modes{"slam", "odometry"};
  uint64_t seed = 1;
  int jobs = 0;
  bool maps = false;
  bool require = false;
  std::string policy_name = "fixed";
  double plan_resolution = 0.0;  // each experiment's robot's
  int max_particles = slam::BudgetSettings{}.max_particles;
  app.add_option("DIRS", inputs, "experiment directories (or CARMEN logs), or datasets of them")
      ->required();
  app.add_option("--out", out_dir, "output directory, created if needed")->required();
  app.add_option("--budgets", budgets, "rays per scan")
      ->delimiter(',')
      ->capture_default_str()
      ->check(CLI::Range(int64_t{1}, int64_t{1'000'000'000}));
  app.add_option("--modes", modes, "slam (phase B on) and/or odometry (phase B off)")
      ->delimiter(',')
      ->capture_default_str()
      ->check(CLI::IsMember({"slam", "odometry"}));
  app.add_option(
      "--params", params_path,
      "SLAM parameters (JSON, Table II keys), or a directory of them per budget "
      "(<budget>.json, as slam-tune writes in OUT/params; a budget without a file keeps its "
      "shipped set) [the shipped set of each budget: config/params/]");
  app.add_option("--policy", policy_name, "fixed (the paper's) or adaptive particle count")
      ->capture_default_str()
      ->check(CLI::IsMember({"fixed", "adaptive"}));
  app.add_option("--max-particles", max_particles, "adaptive policy: most particles")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  app.add_option("--seed", seed, "seed of the particle filter")->capture_default_str();
  app.add_option("--jobs", jobs, "replays at once, one thread each (0: one per core)")
      ->capture_default_str()
      ->check(CLI::Range(0, 256));
  app.add_flag("--maps", maps, "also write each run's map and trajectory under OUT/runs/");
  std::string relations_path;
  app.add_option("--relations", relations_path,
                 "benchmark relations (Freiburg format) scoring every run, as slam-replay's "
                 "--relations (for one log, or experiments sharing a clock); with --maps, each "
                 "run's relations.tsv too");
  app.add_option("--resolution", plan_resolution,
                 "grid cell size in metres [each robot's: 0.01 for the marXbot's infrared "
                 "scanner, 0.05 for a laser]")
      ->check(CLI::Range(0.002, 1.0));
  double heading_sweep_turn_deg = slam::SlamConfig{}.heading_sweep_turn_deg;
  app.add_option("--heading-sweep-turn", heading_sweep_turn_deg,
                 slam::offline::kHeadingSweepTurnHelp)
      ->check(CLI::Range(0.0, 360.0))
      ->capture_default_str();
  app.add_flag("--require-checks", require,
               "exit with status 3 unless SLAM beats odometry-only on every experiment at the "
               "largest budget, halves its mean ATE, and mean q improves with the budget");
  app.set_version_flag("--version", std::string("slam-evaluate ") + SLAM_VERSION);
  if (const std::optional<int> exit_code = slam::cli::Parse(app, argc, argv)) return *exit_code;

  slam::offline::EvaluationPlan plan;
  plan.resolution_m = plan_resolution;
  plan.heading_sweep_turn_deg = heading_sweep_turn_deg;
  if (!relations_path.empty()) {
    auto loaded = slam::offline::LoadRelations(relations_path);
    if (!loaded.ok()) return Fail(loaded.Message());
    plan.relations = std::move(loaded).value();
  }
  plan.budgets = budgets;
  std::sort(plan.budgets.begin(), plan.budgets.end());
  plan.budgets.erase(std::unique(plan.budgets.begin(), plan.budgets.end()), plan.budgets.end());
  plan.slam = std::count(modes.begin(), modes.end(), "slam") > 0;
  plan.odometry_only = std::count(modes.begin(), modes.end(), "odometry") > 0;
  plan.seed = seed;
  plan.jobs = jobs;
  plan.policy = *slam::ParseBudgetPolicy(policy_name);
  plan.max_particles = max_particles;
  if (!params_path.empty() && fs::is_directory(params_path)) {
    // One file per budget; a budget the study did not tune keeps the shipped set, said aloud.
    auto loaded = slam::offline::LoadParamsDirectory(params_path, plan.budgets);
    if (!loaded.ok()) return Fail(loaded.Message());
    plan.params_by_budget = std::move(loaded.value().by_budget);
    for (const int64_t budget : loaded.value().shipped) {
      std::cerr << "slam-evaluate: " << params_path << " has no " << budget << ".json: budget "
                << budget << " uses the shipped set (config/params/)\n";
    }
  } else if (!params_path.empty()) {
    const auto loaded = slam::io::LoadParams(params_path);
    if (!loaded.ok()) return Fail(loaded.Message());
    plan.params = slam::ParamsChoice(params_path, loaded.value());
  }
  const slam::Result<std::vector<std::string>> found = slam::offline::FindExperimentDirs(inputs);
  if (!found.ok()) return Fail(found.Message());
  const std::vector<std::string>& dirs = found.value();
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  if (ec) return Fail("cannot create " + out_dir + ": " + ec.message());
  if (maps) plan.outputs_dir = (fs::path(out_dir) / "runs").string();

  // Decode every experiment once.
  std::vector<slam::offline::Experiment> experiments;
  for (const std::string& dir : dirs) {
    slam::Result<slam::offline::Experiment> load = slam::offline::LoadExperiment(dir);
    if (!load.ok()) return Fail("cannot read " + dir + ":\n" + load.Message());
    std::fprintf(stderr, "%s: %zu scans, %.0f s\n", load.value().meta.name.c_str(),
                 load.value().scans.size(), load.value().duration_s());
    experiments.push_back(std::move(load).value());
  }

  const auto start = std::chrono::steady_clock::now();
  const auto runs = slam::offline::Evaluate(
      experiments, plan, [&](const slam::offline::EvaluationRun& run, size_t done, size_t total) {
        const double elapsed =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        const auto& s = run.summary;
        std::fprintf(stderr, "[%zu/%zu] %s %s %lld: ATE %s cm, %.1f s elapsed\n", done, total,
                     experiments[run.experiment].meta.name.c_str(),
                     run.refine ? "slam" : "odometry", static_cast<long long>(run.budget),
                     s["ate_rmse_m"].is_number()
                         ? std::to_string(100.0 * s["ate_rmse_m"].get<double>()).c_str()
                         : "-",
                     elapsed);
        for (const std::string& e : run.errors) std::fprintf(stderr, "  %s\n", e.c_str());
      });

  nlohmann::json all = nlohmann::json::array();
  bool write_errors = false;
  for (const auto& run : runs) {
    all.push_back(run.summary);
    write_errors = write_errors || !run.errors.empty();
  }
  const std::string md = slam::offline::EvaluationMarkdown(experiments, runs);
  const fs::path out(out_dir);
  for (const auto& [name, text] : {std::pair<std::string, std::string>{"results.md", md},
                                   {"results.csv", slam::offline::EvaluationCsv(experiments, runs)},
                                   {"runs.json", all.dump(2) + "\n"}}) {
    const slam::Result<void> written = slam::io::WriteFileAtomic((out / name).string(), text);
    if (!written.ok()) return Fail(written.Message());
  }
  std::cout << md;
  std::fprintf(stderr, "slam-evaluate: %zu runs in %.1f s; results in %s/results.{md,csv}\n",
               runs.size(),
               std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(),
               out_dir.c_str());
  if (write_errors) return 1;
  if (require && !slam::offline::CheckEvaluation(runs).all_pass()) return 3;
  return 0;
}
