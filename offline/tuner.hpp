#pragma once
// The offline tuner (docs/design.md section 4, paper section VI-B): for each ray budget on its own,
// the evolution strategy searches the SLAM parameters that minimise the mean of e = log(1 - q) over
// recorded experiments held in memory. Evaluations run in parallel under oneTBB; results depend
// only on the settings and seed, never on the thread count. The state after every generation is
// complete enough to resume from.

#include <atomic>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "engine/params.hpp"
#include "engine/pose.hpp"
#include "engine/robot.hpp"
#include "engine/scan.hpp"
#include "offline/evolution.hpp"
#include "offline/statistics.hpp"
#include "scheduler/ray_budget_scheduler.hpp"

namespace slam::offline {

/// A decoded experiment with ground truth (not owned).
struct TuningExperiment {
  std::string name;
  const RobotDescription* robot = nullptr;
  const std::vector<Scan>* scans = nullptr;
  const std::vector<TimedPose>* ground_truth = nullptr;
};

struct TuningSettings {
  std::vector<int64_t> budgets{8125, 16250, 32500, 65000};
  EvolutionConfig evolution;  // its seed also seeds every replay
  BudgetPolicy policy = BudgetPolicy::kFixed;
  int max_particles = BudgetSettings{}.max_particles;
  SlamParams start;  // the first generation's first individual (Table II defaults)
  /// Racing (RunTuning): a new individual's evaluation stops as soon as it can no longer enter
  /// the elite. It never changes which individuals are elites, so neither the study's course
  /// nor its best sets; only the fitness of the individuals it stopped (a lower bound).
  bool racing = true;
  /// Racing's statistical test (0: off, only the bound above): an individual also stops when,
  /// on the experiments replayed so far, it trails the elite's worst by more than the rest
  /// could make up at this one-sided level, given how much two elites' e differ from one
  /// experiment to another (RunTuning). It may drop an individual that would have just made the
  /// elite, in exchange for stopping most others after one or two experiments.
  double race_alpha = 0.05;
};

struct GenerationSummary {
  int generation = 0;                  // 0-based (results.json); shown as generation + 1
  FiveNumbers fitness;                 // over the whole population
  Individual best;                     // best so far (elitism keeps it)
  std::vector<double> fitness_values;  // every individual's, in population order
  int evaluations = 0;                 // individuals evaluated in this generation (elites are not)
  // What the generation cost: replays started and scans replayed; and what racing spared
  // against replaying every evaluated individual on every experiment to its end.
  int64_t replays = 0, scans = 0, replays_saved = 0, scans_saved = 0;
  int raced_out = 0;  // individuals whose evaluation racing stopped
};

struct BudgetRun {
  int64_t budget = 0;
  std::vector<GenerationSummary> generations;
  std::vector<Individual> population;  // the last summarised generation, evaluated
};

struct TuningState {
  TuningSettings settings;
  std::vector<std::string> experiments;  // names, in order: a resumed run must use the same
  std::vector<BudgetRun> budgets;        // in the order of settings.budgets
  int ranks = 1;  // processes (MPI ranks) of the run that wrote it last; results never depend on it
};

/// Spreads each generation's evaluations over processes that all run the same study (MPI ranks,
/// tools/slam_tune.cpp): each evaluates the new individuals it owns, then every process gets
/// every result. The study is the same with any number of processes.
class EvaluationSpread {
 public:
  virtual ~EvaluationSpread() = default;
  /// Processes in all.
  virtual int size() const = 0;
  /// Whether this process evaluates the generation's `item`-th new individual.
  virtual bool Mine(size_t item) const = 0;
  /// Sums `values` element by element over every process, in place (each process leaves zeros
  /// where it has no result, so the sum is every result; exact: x + 0 = x). Every process calls
  /// it once per generation, with the same size; it returns only when all have.
  virtual void SumAll(std::vector<double>& values) const = 0;
};

/// A fresh state for `settings` over these experiments.
TuningState NewTuningState(const TuningSettings& settings,
                           const std::vector<TuningExperiment>& experiments);

/// Fitness of one parameter set at one budget: the mean of e over the experiments, each replayed
/// on this thread with the settings' policy and seed. Preconditions: params valid, every
/// experiment has ground truth.
/// With `cancel` set to true during the call, it returns soon (between two scans) with a
/// meaningless value.
double Fitness(const std::vector<TuningExperiment>& experiments, const SlamParams& params,
               int64_t budget, const TuningSettings& settings,
               const std::atomic<bool>* cancel = nullptr);

/// Where a study stands, for a progress line.
struct TuningProgress {
  double done = 0.0, total = 0.0;  // work (scans times budget); what racing spares counts done
  int64_t budget = 0;              // the budget in progress
  int generation = 0;              // its generation in progress (0-based)
  int64_t replays = 0;             // finished in this call
  int64_t replays_saved = 0;       // spared by racing in this call
};

/// The callbacks are never called at once (budgets may run side by side, on several threads).
struct TuningCallbacks {
  /// After every finished generation of a budget (to save the state); may be empty.
  std::function<void(const TuningState&, int64_t budget)> generation_done;
  /// Work done and in all for this call (replayed scans times budget), serialised; may be empty.
  std::function<void(const TuningProgress&)> progress;
  /// When set to true, the run stops soon; unfinished generations are dropped.
  const std::atomic<bool>* cancel = nullptr;
  /// Evaluations spread over processes; null: all here.
  const EvaluationSpread* spread = nullptr;
};

/// Runs or continues the study until every budget has settings.evolution.generations
/// generations, `jobs` evaluations at a time (0: one per core). Returns false when cancelled;
/// `state` then holds every finished generation. With more than one thread and no spread over
/// processes, the budgets run side by side (the dearest first), so that a thread idle at the end
/// of one budget's generation takes another's individuals; each budget's study is the same as
/// when they run one after the other.
///
/// Racing (settings.racing), in every generation but the last (whose whole population is
/// evaluated: Table III compares the last one's fitness values). The new individuals are
/// evaluated in two halves, one after the other; each half's elite cut T is the fitness of the
/// `elites`-th best individual evaluated whole so far in the generation (the elites carried over,
/// then also the first half's individuals that finished; generation 0 has no elite, so its first
/// half is evaluated whole). A new individual is replayed on the experiments one after the
/// other, and stops as soon as the e it has gathered, over the number of experiments, exceeds T
/// (e >= 0, so its mean can only exceed T more); within a replay, as soon as the e that replay
/// can at best score would take it over (ErrorLowerBound, ReplayOptions::stop_above_e). Such an
/// individual has `elites` individuals better than it, whatever the others score, so the
/// elites, the best sets and every later generation are those of the study without racing; its
/// fitness is the lower bound it reached. Deterministic: T is fixed for each half and every stop
/// depends only on the individual's own replays.
///
/// With settings.race_alpha > 0 and the elites' scores known, racing also tests, as F-Race
/// does, against the individual at the cut on the same experiments: after k of n experiments, with
/// S the sum of the individual's e minus that elite's over them, the individual stops when S > z
/// sigma sqrt(n - k), z the normal quantile of 1 - alpha and sigma the pooled standard deviation,
/// over the experiments, of each other elite's e minus the worst's (how much two individuals'
/// difference varies from one experiment to the next): even were the rest to go as well for it as
/// that spread allows, it would not make the cut. Inside a replay the same test runs on the
/// replay's ErrorLowerBound.
bool RunTuning(const std::vector<TuningExperiment>& experiments, TuningState& state, int jobs,
               const TuningCallbacks& callbacks = {});

}  // namespace slam::offline
