#pragma once
// Replays a set of recorded experiments at several budgets, with and without phase B, and
// tabulates the results (the reference table of docs/performance.md). Runs go in parallel, one
// thread each, and give the same numbers whatever the number of jobs (only the timings differ).

#include <cstdint>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "engine/params.hpp"
#include "engine/result.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/relations.hpp"
#include "scheduler/params_catalog.hpp"
#include "scheduler/ray_budget_scheduler.hpp"

namespace slam::offline {

/// The experiments named by `paths`: each is an experiment (a directory holding can.log or
/// log.clf, or a CARMEN log file) or a dataset of them (its subdirectories holding one, sorted);
/// an error naming the path that is neither.
Result<std::vector<std::string>> FindExperimentDirs(const std::vector<std::string>& paths);

/// The parameter sets of a directory as slam-tune writes them (<budget>.json), for `budgets`.
struct ParamsDirectory {
  std::map<int64_t, ParamsChoice> by_budget;  // the budgets with a file
  std::vector<int64_t> shipped;               // the budgets without one: the shipped sets
};

/// Reads `dir`/<budget>.json for each budget (a study may have tuned only some of them); a
/// budget without a file goes to `shipped`. An error names a file that exists but cannot be
/// read or is not a valid parameter set, or a `dir` that is not a directory.
Result<ParamsDirectory> LoadParamsDirectory(const std::string& dir,
                                            const std::vector<int64_t>& budgets);

struct EvaluationPlan {
  std::vector<int64_t> budgets{8125, 16250, 32500, 65000};
  bool slam = true;                                  // with phase B
  bool odometry_only = true;                         // phase B off (--no-refine)
  ParamsChoice params;                               // the shipped sets unless one is given
  std::map<int64_t, ParamsChoice> params_by_budget;  // given per budget; overrides `params`
  BudgetPolicy policy = BudgetPolicy::kFixed;
  int max_particles = BudgetSettings{}.max_particles;
  uint64_t seed = 1;
  int jobs = 0;               // concurrent replays; 0: one per core
  std::string outputs_dir;    // when set: each run's map and trajectory in a subdirectory
  double resolution_m = 0.0;  // the grid's cell size; 0: each experiment's robot's
  double heading_sweep_turn_deg = SlamConfig{}.heading_sweep_turn_deg;  // SlamConfig's
  /// Benchmark relations (slam-evaluate --relations): when given, every run's summary gains a
  /// `relations` object, as slam-replay's.
  std::vector<Relation> relations;
};

struct EvaluationRun {
  size_t experiment = 0;  // index into the experiments
  int64_t budget = 0;
  bool refine = true;
  nlohmann::json summary;           // slam-replay's JSON summary of the run
  std::vector<std::string> errors;  // files that could not be written
};

/// The runs of the plan, in a fixed order: experiment, then mode (SLAM first), then budget.
std::vector<EvaluationRun> PlanRuns(size_t experiments, const EvaluationPlan& plan);

/// Replays every run. `on_done(run, done, total)` is called after each, from one thread at a
/// time, in completion order. Returns the runs in PlanRuns order.
std::vector<EvaluationRun> Evaluate(
    const std::vector<offline::Experiment>& experiments, const EvaluationPlan& plan,
    const std::function<void(const EvaluationRun&, size_t, size_t)>& on_done = {});

/// One row per run: experiment, world, mode, budget, ATE, q, e, map precision and recall,
/// real-time factor, CPU ms per scan, rays per scan.
std::string EvaluationCsv(const std::vector<offline::Experiment>& experiments,
                          const std::vector<EvaluationRun>& runs);

/// Means per budget and mode, ATE per experiment, and the checks of the issue tracker's
/// quality bar (SLAM beats odometry-only everywhere at the largest budget; mean SLAM ATE under
/// half of odometry-only's; mean q improving from the smallest to the largest budget).
std::string EvaluationMarkdown(const std::vector<offline::Experiment>& experiments,
                               const std::vector<EvaluationRun>& runs);

/// The checks of EvaluationMarkdown, for tools and tests.
struct EvaluationChecks {
  int64_t largest_budget = 0;
  int experiments_compared = 0;
  int slam_beats_odometry = 0;   // experiments where SLAM at the largest budget has lower ATE
  double mean_ate_slam_m = 0.0;  // at the largest budget
  double mean_ate_odometry_m = 0.0;
  int64_t smallest_budget = 0;
  double mean_q_smallest = 0.0;  // SLAM's mean q at the smallest and largest budgets
  double mean_q_largest = 0.0;
  bool all_pass() const {
    return experiments_compared > 0 && slam_beats_odometry == experiments_compared &&
           mean_ate_slam_m < 0.5 * mean_ate_odometry_m && mean_q_largest > mean_q_smallest;
  }
};

EvaluationChecks CheckEvaluation(const std::vector<EvaluationRun>& runs);

}  // namespace slam::offline
