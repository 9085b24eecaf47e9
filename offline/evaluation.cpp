#include "offline/evaluation.hpp"

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <map>
#include <mutex>
#include <numeric>
#include <optional>

#include "engine/io/atomic_file.hpp"
#include "engine/io/params_json.hpp"
#include "engine/thread_safety.hpp"
#include "offline/carmen_log.hpp"
#include "offline/replay.hpp"
#include "offline/replay_report.hpp"

namespace slam::offline {
namespace {

using Json = nlohmann::json;

/// A number from a summary, NaN when absent or null.
double Number(const Json& summary, const char* key) {
  const auto it = summary.find(key);
  return it != summary.end() && it->is_number() ? it->get<double>() : std::nan("");
}

double MapNumber(const Json& summary, const char* key) {
  const auto it = summary.find("map_quality");
  return it != summary.end() && it->is_object() ? Number(*it, key) : std::nan("");
}

std::string Format(const char* format, double value) {
  if (!std::isfinite(value)) return "-";
  char text[64];
  std::snprintf(text, sizeof(text), format, value);
  return text;
}

/// Mean of the finite values, NaN when there is none.
double Mean(const std::vector<double>& values) {
  double sum = 0.0;
  int n = 0;
  for (double v : values) {
    if (std::isfinite(v)) {
      sum += v;
      ++n;
    }
  }
  return n > 0 ? sum / n : std::nan("");
}

double Max(const std::vector<double>& values) {
  double best = std::nan("");
  for (double v : values) {
    if (std::isfinite(v) && !(v <= best)) best = v;
  }
  return best;
}

const char* ModeName(bool refine) { return refine ? "SLAM" : "odometry only"; }

std::vector<int64_t> Budgets(const std::vector<EvaluationRun>& runs) {
  std::vector<int64_t> budgets;
  for (const EvaluationRun& r : runs) budgets.push_back(r.budget);
  std::sort(budgets.begin(), budgets.end());
  budgets.erase(std::unique(budgets.begin(), budgets.end()), budgets.end());
  return budgets;
}

/// The values of `key` over the runs of one budget and mode, by experiment.
std::vector<double> Column(const std::vector<EvaluationRun>& runs, int64_t budget, bool refine,
                           double (*get)(const Json&, const char*), const char* key,
                           const std::function<bool(const EvaluationRun&)>& keep = {}) {
  std::vector<double> values;
  for (const EvaluationRun& r : runs) {
    if (r.budget == budget && r.refine == refine && (!keep || keep(r)))
      values.push_back(get(r.summary, key));
  }
  return values;
}

}  // namespace

Result<ParamsDirectory> LoadParamsDirectory(const std::string& dir,
                                            const std::vector<int64_t>& budgets) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) {
    return Error(dir + ": not a directory of parameter sets" +
                 (ec ? " (" + ec.message() + ")" : std::string()));
  }
  ParamsDirectory found;
  for (const int64_t budget : budgets) {
    const fs::path path = fs::path(dir) / (std::to_string(budget) + ".json");
    // Missing only when nothing is there, not even a broken link: a file that exists but cannot
    // be read is an error, never silently replaced by the shipped set.
    if (fs::symlink_status(path, ec).type() == fs::file_type::not_found) {
      found.shipped.push_back(budget);
      continue;
    }
    const Result<SlamParams> loaded = io::LoadParams(path.string());
    if (!loaded.ok()) return {loaded.errors(), loaded.error_context()};
    found.by_budget[budget] = ParamsChoice(path.string(), loaded.value());
  }
  return found;
}

Result<std::vector<std::string>> FindExperimentDirs(const std::vector<std::string>& paths) {
  // An experiment directory holds can.log, or log.clf for a robot with a laser.
  const auto is_experiment = [](const std::filesystem::path& dir) {
    std::error_code ec;
    return std::filesystem::exists(dir / "can.log", ec) ||
           std::filesystem::exists(dir / "log.clf", ec);
  };
  std::vector<std::string> dirs;
  for (const std::string& path : paths) {
    std::error_code ec;
    if (is_experiment(path) || LooksLikeCarmenLog(path)) {
      dirs.push_back(path);
      continue;
    }
    if (!std::filesystem::is_directory(path, ec)) {
      return Error(path + ": not an experiment or dataset directory");
    }
    std::vector<std::string> found;
    for (const std::filesystem::directory_entry& entry :
         std::filesystem::directory_iterator(path, ec)) {
      if (entry.is_directory() && is_experiment(entry.path())) {
        found.push_back(entry.path().string());
      }
    }
    if (ec || found.empty()) {
      return Error(path + ": no experiment in it (no subdirectory with a can.log or log.clf)");
    }
    std::sort(found.begin(), found.end());
    dirs.insert(dirs.end(), found.begin(), found.end());
  }
  return dirs;
}

std::vector<EvaluationRun> PlanRuns(size_t experiments, const EvaluationPlan& plan) {
  std::vector<EvaluationRun> runs;
  for (size_t e = 0; e < experiments; ++e) {
    for (bool refine : {true, false}) {
      if ((refine && !plan.slam) || (!refine && !plan.odometry_only)) continue;
      for (int64_t budget : plan.budgets) {
        EvaluationRun run;
        run.experiment = e;
        run.budget = budget;
        run.refine = refine;
        runs.push_back(std::move(run));
      }
    }
  }
  return runs;
}

std::vector<EvaluationRun> Evaluate(
    const std::vector<offline::Experiment>& experiments, const EvaluationPlan& plan,
    const std::function<void(const EvaluationRun&, size_t, size_t)>& on_done) {
  std::vector<EvaluationRun> runs = PlanRuns(experiments.size(), plan);
  // The costliest runs first (SLAM at large budgets), so that the last ones to finish are short.
  std::vector<size_t> order(runs.size());
  std::iota(order.begin(), order.end(), size_t{0});
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    const auto cost = [&](const EvaluationRun& r) { return r.refine ? r.budget : 0; };
    return cost(runs[a]) > cost(runs[b]);
  });
  Mutex mutex;
  size_t done = 0;
  const int jobs = plan.jobs > 0 ? plan.jobs : tbb::task_arena::automatic;
  tbb::task_arena arena(jobs);
  arena.execute([&] {
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, order.size(), 1), [&](const tbb::blocked_range<size_t>& r) {
          for (size_t k = r.begin(); k != r.end(); ++k) {
            EvaluationRun& run = runs[order[k]];
            const offline::Experiment& experiment = experiments[run.experiment];
            ReplayOptions options;
            const auto tuned = plan.params_by_budget.find(run.budget);
            options.params = tuned != plan.params_by_budget.end() ? tuned->second : plan.params;
            options.config.seed = plan.seed;
            options.config.parallel = false;  // one thread per run; runs are the parallelism
            options.config.resolution_m = plan.resolution_m;
            options.config.heading_sweep_turn_deg = plan.heading_sweep_turn_deg;
            options.budget.rays_per_scan = run.budget;
            options.budget.policy = plan.policy;
            options.budget.max_particles = plan.max_particles;
            options.refine = run.refine;
            const ReplayResult result =
                Replay(experiment.robot, experiment.scans, experiment.ground_truth, options);
            run.summary = ReplaySummary(experiment, result, options);
            std::optional<RelationsScore> relations;
            if (!plan.relations.empty()) {
              relations = ScoreRelations(result.trajectory, plan.relations);
              run.summary["relations"] = RelationsToJson(*relations);
            }
            if (!plan.outputs_dir.empty()) {
              const std::filesystem::path dir =
                  std::filesystem::path(plan.outputs_dir) / experiment.meta.name /
                  ((run.refine ? "slam-" : "odometry-") + std::to_string(run.budget));
              std::error_code ec;
              std::filesystem::create_directories(dir, ec);
              if (ec) {
                run.errors.push_back("cannot create " + dir.string() + ": " + ec.message());
              } else {
                run.errors = WriteReplayOutputs(dir.string(), experiment, result, !run.refine,
                                                options.budget)
                                 .errors;
                if (relations) {  // each relation's errors, as slam-replay writes them
                  const std::string path = (dir / "relations.tsv").string();
                  const auto written = io::WriteFileAtomic(
                      path, RelationErrorsText(
                                plan.relations, *relations,
                                ScoreRelations(DeadReckoning(experiment.scans), plan.relations)));
                  if (!written.ok()) run.errors.push_back(written.Message());
                }
              }
            }
            MutexLock lock(mutex);
            ++done;
            if (on_done) on_done(run, done, runs.size());
          }
        });
  });
  return runs;
}

std::string EvaluationCsv(const std::vector<offline::Experiment>& experiments,
                          const std::vector<EvaluationRun>& runs) {
  std::string csv =
      "experiment,world,mode,budget,ate_rmse_m,q,e,odometry_ate_rmse_m,map_precision,"
      "map_recall,realtime_factor,cpu_ms_per_scan,rays_per_scan_mean,rays_per_scan_max,scans\n";
  for (const EvaluationRun& r : runs) {
    const offline::Experiment& e = experiments[r.experiment];
    const Json& s = r.summary;
    csv += e.meta.name + "," + e.meta.world + "," + (r.refine ? "slam" : "odometry") + "," +
           std::to_string(r.budget) + "," + Format("%.6f", Number(s, "ate_rmse_m")) + "," +
           Format("%.4f", Number(s, "q")) + "," + Format("%.6f", Number(s, "e")) + "," +
           Format("%.6f", Number(s, "odometry_ate_rmse_m")) + "," +
           Format("%.4f", MapNumber(s, "precision")) + "," +
           Format("%.4f", MapNumber(s, "recall")) + "," +
           Format("%.1f", Number(s, "realtime_factor")) + "," +
           Format("%.3f", Number(s, "cpu_ms_per_scan")) + "," +
           Format("%.0f", Number(s, "rays_per_scan_mean")) + "," +
           Format("%.0f", Number(s, "rays_per_scan_max")) + "," +
           Format("%.0f", Number(s, "scans")) + "\n";
  }
  return csv;
}

EvaluationChecks CheckEvaluation(const std::vector<EvaluationRun>& runs) {
  EvaluationChecks checks;
  const std::vector<int64_t> budgets = Budgets(runs);
  if (budgets.empty()) return checks;
  checks.smallest_budget = budgets.front();
  checks.largest_budget = budgets.back();
  // Per experiment: SLAM's and odometry-only's ATE at the largest budget.
  std::map<size_t, std::pair<double, double>> ate;
  for (const EvaluationRun& r : runs) {
    if (r.budget != checks.largest_budget) continue;
    auto& pair = ate.try_emplace(r.experiment, std::nan(""), std::nan("")).first->second;
    (r.refine ? pair.first : pair.second) = Number(r.summary, "ate_rmse_m");
  }
  std::vector<double> slam, odometry;
  for (const auto& [experiment, pair] : ate) {
    if (!std::isfinite(pair.first) || !std::isfinite(pair.second)) continue;
    ++checks.experiments_compared;
    checks.slam_beats_odometry += pair.first < pair.second ? 1 : 0;
    slam.push_back(pair.first);
    odometry.push_back(pair.second);
  }
  checks.mean_ate_slam_m = Mean(slam);
  checks.mean_ate_odometry_m = Mean(odometry);
  checks.mean_q_smallest = Mean(Column(runs, checks.smallest_budget, true, Number, "q"));
  checks.mean_q_largest = Mean(Column(runs, checks.largest_budget, true, Number, "q"));
  return checks;
}

std::string EvaluationMarkdown(const std::vector<offline::Experiment>& experiments,
                               const std::vector<EvaluationRun>& runs) {
  const std::vector<int64_t> budgets = Budgets(runs);
  std::string md;
  md +=
      "| rays/scan | mode | ATE RMSE cm, mean | worst | q cm², mean | e, mean | map precision | "
      "map recall | real-time factor | CPU ms/scan |\n";
  md += "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  for (int64_t budget : budgets) {
    for (bool refine : {true, false}) {
      const std::vector<double> ate = Column(runs, budget, refine, Number, "ate_rmse_m");
      if (ate.empty()) continue;
      md += "| " + std::to_string(budget) + " | " + ModeName(refine) + " | " +
            Format("%.2f", 100.0 * Mean(ate)) + " | " + Format("%.2f", 100.0 * Max(ate)) + " | " +
            Format("%.2f", Mean(Column(runs, budget, refine, Number, "q"))) + " | " +
            Format("%.3f", Mean(Column(runs, budget, refine, Number, "e"))) + " | " +
            Format("%.3f", Mean(Column(runs, budget, refine, MapNumber, "precision"))) + " | " +
            Format("%.3f", Mean(Column(runs, budget, refine, MapNumber, "recall"))) + " | " +
            Format("%.0f", Mean(Column(runs, budget, refine, Number, "realtime_factor"))) + " | " +
            Format("%.2f", Mean(Column(runs, budget, refine, Number, "cpu_ms_per_scan"))) + " |\n";
    }
  }

  // Per world, when there are several: SLAM at each budget, odometry only once.
  std::vector<std::string> worlds;
  for (const offline::Experiment& e : experiments) {
    if (std::find(worlds.begin(), worlds.end(), e.meta.world) == worlds.end())
      worlds.push_back(e.meta.world);
  }
  if (worlds.size() > 1) {
    md += "\nPer world (ATE RMSE in cm, mean and worst of its experiments):\n\n";
    md +=
        "| world | runs | odometry only | rays/scan | ATE mean | worst | map precision | "
        "map recall | CPU ms/scan |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for (const std::string& world : worlds) {
      const auto in_world = [&](const EvaluationRun& r) {
        return experiments[r.experiment].meta.world == world;
      };
      const std::vector<double> odometry =
          Column(runs, budgets.back(), false, Number, "ate_rmse_m", in_world);
      for (int64_t budget : budgets) {
        const std::vector<double> ate = Column(runs, budget, true, Number, "ate_rmse_m", in_world);
        if (ate.empty()) continue;
        md +=
            "| " + world + " | " + std::to_string(ate.size()) + " | " +
            (odometry.empty() ? "–" : Format("%.1f", 100.0 * Mean(odometry))) + " | " +
            std::to_string(budget) + " | " + Format("%.1f", 100.0 * Mean(ate)) + " | " +
            Format("%.1f", 100.0 * Max(ate)) + " | " +
            Format("%.2f", Mean(Column(runs, budget, true, MapNumber, "precision", in_world))) +
            " | " +
            Format("%.2f", Mean(Column(runs, budget, true, MapNumber, "recall", in_world))) +
            " | " +
            Format("%.2f", Mean(Column(runs, budget, true, Number, "cpu_ms_per_scan", in_world))) +
            " |\n";
      }
    }
  }

  // The parameter set of each budget's SLAM runs (one set per budget: the plan gives it).
  std::string sets;
  for (int64_t budget : budgets) {
    for (const EvaluationRun& r : runs) {
      if (r.budget != budget || !r.refine || !r.summary.contains("params_set")) continue;
      sets += (sets.empty() ? "" : ", ") + std::to_string(budget) + ": " +
              r.summary["params_set"].get<std::string>();
      break;
    }
  }
  if (!sets.empty()) md += "\nParameter sets: " + sets + ".\n";

  // ATE per experiment: odometry only (the largest budget's run), then SLAM at each budget.
  md += "\nATE RMSE per experiment, cm:\n\n| experiment | odometry only |";
  for (int64_t budget : budgets) md += " " + std::to_string(budget) + " |";
  md += "\n|---|---:|";
  for (size_t i = 0; i < budgets.size(); ++i) md += "---:|";
  md += "\n";
  for (size_t e = 0; e < experiments.size(); ++e) {
    double odometry = std::nan("");
    std::map<int64_t, double> slam;
    for (const EvaluationRun& r : runs) {
      if (r.experiment != e) continue;
      if (r.refine) {
        slam[r.budget] = Number(r.summary, "ate_rmse_m");
      } else {
        odometry = Number(r.summary, "ate_rmse_m");  // same for every budget: the largest wins
      }
    }
    md += "| " + experiments[e].meta.name + " | " + Format("%.2f", 100.0 * odometry) + " |";
    for (int64_t budget : budgets) {
      const auto it = slam.find(budget);
      md += " " + Format("%.2f", it == slam.end() ? std::nan("") : 100.0 * it->second) + " |";
    }
    md += "\n";
  }

  const EvaluationChecks c = CheckEvaluation(runs);
  if (c.experiments_compared > 0) {
    md += "\nChecks at " + std::to_string(c.largest_budget) + " rays/scan:\n\n";
    md += "- SLAM beats odometry-only on " + std::to_string(c.slam_beats_odometry) + " of " +
          std::to_string(c.experiments_compared) + " experiments.\n";
    md += "- Mean ATE, SLAM / odometry-only: " + Format("%.2f", 100.0 * c.mean_ate_slam_m) + " / " +
          Format("%.2f", 100.0 * c.mean_ate_odometry_m) +
          " cm = " + Format("%.2f", c.mean_ate_slam_m / c.mean_ate_odometry_m) +
          " (bar: under 0.5).\n";
    md += "- Mean q from " + std::to_string(c.smallest_budget) + " to " +
          std::to_string(c.largest_budget) + " rays/scan: " + Format("%.2f", c.mean_q_smallest) +
          " -> " + Format("%.2f", c.mean_q_largest) + " cm² (" +
          (c.mean_q_largest > c.mean_q_smallest ? "improves" : "does not improve") + ").\n";
    md += std::string("- All checks: ") + (c.all_pass() ? "pass" : "FAIL") + ".\n";
  }
  return md;
}

}  // namespace slam::offline
