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

/// slam-evaluate's command line, as parsed.
struct EvaluateConfig {
  std::vector<std::string> inputs;
  std::string out_dir, params_path, relations_path;
  std::vector<int64_t> budgets{8125, 16250, 32500, 65000};
  std::vector<std::string> modes{"slam", "odometry"};
  uint64_t seed = 1;
  int jobs = 0;
  bool maps = false;
  bool require = false;
  std::string policy_name = "fixed";
  double plan_resolution = 0.0;  // each experiment's robot's
  int max_particles = slam::BudgetSettings{}.max_particles;
  double heading_sweep_turn_deg = slam::SlamConfig{}.heading_sweep_turn_deg;
};

void AddOptions(CLI::App& app, EvaluateConfig& c) {
  app.add_option("DIRS", c.inputs, "experiment directories (or CARMEN logs), or datasets of them")
      ->required();
  app.add_option("--out", c.out_dir, "output directory, created if needed")->required();
  app.add_option("--budgets", c.budgets, "rays per scan")
      ->delimiter(',')
      ->capture_default_str()
      ->check(CLI::Range(int64_t{1}, int64_t{1'000'000'000}));
  app.add_option("--modes", c.modes, "slam (phase B on) and/or odometry (phase B off)")
      ->delimiter(',')
      ->capture_default_str()
      ->check(CLI::IsMember({"slam", "odometry"}));
  app.add_option(
      "--params", c.params_path,
      "SLAM parameters (JSON, Table II keys), or a directory of them per budget "
      "(<budget>.json, as slam-tune writes in OUT/params; a budget without a file keeps its "
      "shipped set) [the shipped set of each budget: config/params/]");
  app.add_option("--policy", c.policy_name, "fixed (the paper's) or adaptive particle count")
      ->capture_default_str()
      ->check(CLI::IsMember({"fixed", "adaptive"}));
  app.add_option("--max-particles", c.max_particles, "adaptive policy: most particles")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  app.add_option("--seed", c.seed, "seed of the particle filter")->capture_default_str();
  app.add_option("--jobs", c.jobs, "replays at once, one thread each (0: one per core)")
      ->capture_default_str()
      ->check(CLI::Range(0, 256));
  app.add_flag("--maps", c.maps, "also write each run's map and trajectory under OUT/runs/");
  app.add_option("--relations", c.relations_path,
                 "benchmark relations (Freiburg format) scoring every run, as slam-replay's "
                 "--relations (for one log, or experiments sharing a clock); with --maps, each "
                 "run's relations.tsv too");
  app.add_option("--resolution", c.plan_resolution,
                 "grid cell size in metres [each robot's: 0.01 for the marXbot's infrared "
                 "scanner, 0.05 for a laser]")
      ->check(CLI::Range(0.002, 1.0));
  app.add_option("--heading-sweep-turn", c.heading_sweep_turn_deg,
                 slam::offline::kHeadingSweepTurnHelp)
      ->check(CLI::Range(0.0, 360.0))
      ->capture_default_str();
  app.add_flag("--require-checks", c.require,
               "exit with status 3 unless SLAM beats odometry-only on every experiment at the "
               "largest budget, halves its mean ATE, and mean q improves with the budget");
  app.set_version_flag("--version", std::string("slam-evaluate ") + SLAM_VERSION);
}

/// The evaluation's plan from the options: budgets sorted and unique, modes, relations and the
/// parameters (one file, or a directory of one per budget; a budget without one keeps its
/// shipped set, said aloud).
slam::Result<slam::offline::EvaluationPlan> PlanOf(const EvaluateConfig& c) {
  slam::offline::EvaluationPlan plan;
  plan.resolution_m = c.plan_resolution;
  plan.heading_sweep_turn_deg = c.heading_sweep_turn_deg;
  if (!c.relations_path.empty()) {
    auto loaded = slam::offline::LoadRelations(c.relations_path);
    if (!loaded.ok()) return slam::Error(loaded.Message());
    plan.relations = std::move(loaded).value();
  }
  plan.budgets = c.budgets;
  std::sort(plan.budgets.begin(), plan.budgets.end());
  plan.budgets.erase(std::unique(plan.budgets.begin(), plan.budgets.end()), plan.budgets.end());
  plan.slam = std::count(c.modes.begin(), c.modes.end(), "slam") > 0;
  plan.odometry_only = std::count(c.modes.begin(), c.modes.end(), "odometry") > 0;
  plan.seed = c.seed;
  plan.jobs = c.jobs;
  plan.policy = *slam::ParseBudgetPolicy(c.policy_name);
  plan.max_particles = c.max_particles;
  if (!c.params_path.empty() && fs::is_directory(c.params_path)) {
    auto loaded = slam::offline::LoadParamsDirectory(c.params_path, plan.budgets);
    if (!loaded.ok()) return slam::Error(loaded.Message());
    plan.params_by_budget = std::move(loaded.value().by_budget);
    for (const int64_t budget : loaded.value().shipped) {
      std::cerr << "slam-evaluate: " << c.params_path << " has no " << budget << ".json: budget "
                << budget << " uses the shipped set (config/params/)\n";
    }
  } else if (!c.params_path.empty()) {
    const auto loaded = slam::io::LoadParams(c.params_path);
    if (!loaded.ok()) return slam::Error(loaded.Message());
    plan.params = slam::ParamsChoice(c.params_path, loaded.value());
  }
  return plan;
}

/// Every experiment, decoded once.
slam::Result<std::vector<slam::offline::Experiment>> LoadExperiments(
    const std::vector<std::string>& dirs) {
  std::vector<slam::offline::Experiment> experiments;
  for (const std::string& dir : dirs) {
    slam::Result<slam::offline::Experiment> load = slam::offline::LoadExperiment(dir);
    if (!load.ok()) return slam::Error("cannot read " + dir + ":\n" + load.Message());
    std::fprintf(stderr, "%s: %zu scans, %.0f s\n", load.value().meta.name.c_str(),
                 load.value().scans.size(), load.value().duration_s());
    experiments.push_back(std::move(load).value());
  }
  return experiments;
}

/// results.md, results.csv and runs.json into `out_dir`; the Markdown, or why not.
slam::Result<std::string> WriteResults(const std::string& out_dir,
                                       const std::vector<slam::offline::Experiment>& experiments,
                                       const std::vector<slam::offline::EvaluationRun>& runs) {
  nlohmann::json all = nlohmann::json::array();
  for (const auto& run : runs) all.push_back(run.summary);
  const std::string md = slam::offline::EvaluationMarkdown(experiments, runs);
  const fs::path out(out_dir);
  for (const auto& [name, text] : {std::pair<std::string, std::string>{"results.md", md},
                                   {"results.csv", slam::offline::EvaluationCsv(experiments, runs)},
                                   {"runs.json", all.dump(2) + "\n"}}) {
    const slam::Result<void> written = slam::io::WriteFileAtomic((out / name).string(), text);
    if (!written.ok()) return slam::Error(written.Message());
  }
  return md;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Replays recorded experiments at each ray budget, with phase B (SLAM) and without "
      "(odometry only), and writes results.md, results.csv and runs.json into --out."};
  EvaluateConfig config;
  AddOptions(app, config);
  if (const std::optional<int> exit_code = slam::cli::Parse(app, argc, argv)) return *exit_code;

  auto planned = PlanOf(config);
  if (!planned.ok()) return Fail(planned.Message());
  slam::offline::EvaluationPlan& plan = planned.value();
  const slam::Result<std::vector<std::string>> found =
      slam::offline::FindExperimentDirs(config.inputs);
  if (!found.ok()) return Fail(found.Message());
  std::error_code ec;
  fs::create_directories(config.out_dir, ec);
  if (ec) return Fail("cannot create " + config.out_dir + ": " + ec.message());
  if (config.maps) plan.outputs_dir = (fs::path(config.out_dir) / "runs").string();
  const auto loaded = LoadExperiments(found.value());
  if (!loaded.ok()) return Fail(loaded.Message());
  const std::vector<slam::offline::Experiment>& experiments = loaded.value();

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
  const bool write_errors =
      std::any_of(runs.begin(), runs.end(), [](const auto& run) { return !run.errors.empty(); });
  const auto md = WriteResults(config.out_dir, experiments, runs);
  if (!md.ok()) return Fail(md.Message());
  std::cout << md.value();
  std::fprintf(stderr, "slam-evaluate: %zu runs in %.1f s; results in %s/results.{md,csv}\n",
               runs.size(),
               std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(),
               config.out_dir.c_str());
  if (write_errors) return 1;
  if (config.require && !slam::offline::CheckEvaluation(runs).all_pass()) return 3;
  return 0;
}
