#include "offline/tuner.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>
#include <numeric>

#include "engine/thread_safety.hpp"
#include "offline/racing.hpp"
#include "offline/replay.hpp"
#include "offline/statistics.hpp"

namespace slam::offline {
namespace {

/// Replays of one budget cost about budget rays per scan: the unit of progress.
double Work(const std::vector<TuningExperiment>& experiments, int64_t budget) {
  double scans = 0.0;
  for (const TuningExperiment& e : experiments) scans += static_cast<double>(e.scans->size());
  return scans * static_cast<double>(budget);
}

GenerationSummary Summarize(const std::vector<Individual>& population, int generation,
                            int evaluations) {
  GenerationSummary summary;
  summary.generation = generation;
  summary.evaluations = evaluations;
  for (const Individual& i : population) summary.fitness_values.push_back(i.fitness);
  summary.fitness = SummarizeFive(summary.fitness_values);
  summary.best = Ranked(population).front();
  return summary;
}

}  // namespace

TuningState NewTuningState(const TuningSettings& settings,
                           const std::vector<TuningExperiment>& experiments) {
  TuningState state;
  state.settings = settings;
  for (const TuningExperiment& e : experiments) state.experiments.push_back(e.name);
  for (int64_t budget : settings.budgets) state.budgets.push_back(BudgetRun{budget, {}, {}});
  return state;
}

double Fitness(const std::vector<TuningExperiment>& experiments, const SlamParams& params,
               int64_t budget, const TuningSettings& settings, const std::atomic<bool>* cancel) {
  double sum = 0.0;
  for (const TuningExperiment& e : experiments) {
    if (cancel != nullptr && cancel->load()) break;
    sum += EOf(ReplayFor(e, params, budget, settings, cancel));
  }
  return experiments.empty() ? 0.0 : sum / static_cast<double>(experiments.size());
}

namespace {

/// The progress of a study whose budgets may run side by side: exact at every generation's start
/// (`base_`); within a generation, this process's own replays (`local_[slot]`, the generation in
/// progress of the budget in that slot), times the processes when the evaluations are spread.
/// Racing's savings count as done.
class ProgressTracker {
 public:
  ProgressTracker(const std::vector<TuningExperiment>& experiments, const TuningState& state,
                  const TuningCallbacks& callbacks, double processes)
      : callbacks_(callbacks), processes_(processes), local_(state.budgets.size()) {
    // The work left without racing.
    const EvolutionConfig& es = state.settings.evolution;
    const int generations = es.generations;
    double total = 0.0;
    for (const BudgetRun& run : state.budgets) {
      const int done = static_cast<int>(run.generations.size());
      if (done >= generations) continue;
      const int fresh = done == 0
                            ? es.population + (generations - 1) * (es.population - es.elites())
                            : (generations - done) * (es.population - es.elites());
      total += fresh * Work(experiments, run.budget);
    }
    base_.total = total;
  }

  void StartGeneration(size_t slot, int64_t budget, int generation) {
    MutexLock lock(mutex_);
    local_[slot] = TuningProgress{};
    local_[slot].budget = budget;
    local_[slot].generation = generation;
  }

  /// A replay's work done (racing's savings with it), and the replays it finished or spared.
  void Report(size_t slot, double work, int64_t replays, int64_t saved) {
    if (!callbacks_.progress) return;
    MutexLock lock(mutex_);
    local_[slot].done += work;
    local_[slot].replays += replays;
    local_[slot].replays_saved += saved;
    TuningProgress p = base_;
    p.budget = local_[slot].budget;
    p.generation = local_[slot].generation;
    for (const TuningProgress& l : local_) {
      p.done += processes_ * l.done;
      p.replays += static_cast<int64_t>(processes_ * static_cast<double>(l.replays));
      p.replays_saved += static_cast<int64_t>(processes_ * static_cast<double>(l.replays_saved));
    }
    p.done = std::min(p.done, p.total);
    callbacks_.progress(p);
  }

  /// Exact again at a generation's end: every process's replays.
  void FinishGeneration(size_t slot, int64_t replays, int64_t saved, double work) {
    MutexLock lock(mutex_);
    base_.replays += replays;
    base_.replays_saved += saved;
    base_.done += work;
    local_[slot] = TuningProgress{};
  }

  /// Runs `f` never at once with the progress callback.
  template <typename F>
  void Serialised(const F& f) {
    MutexLock lock(mutex_);
    f();
  }

 private:
  const TuningCallbacks& callbacks_;
  const double processes_;
  Mutex mutex_;
  TuningProgress base_ SLAM_GUARDED_BY(mutex_);
  std::vector<TuningProgress> local_ SLAM_GUARDED_BY(mutex_);
};

/// One call of RunTuning: each budget's study from where it stands to its last generation.
class Tuner {
 public:
  Tuner(const std::vector<TuningExperiment>& experiments, TuningState& state, int jobs,
        const TuningCallbacks& callbacks)
      : experiments_(experiments),
        state_(state),
        callbacks_(callbacks),
        spread_(callbacks.spread),
        progress_(experiments, state, callbacks, spread_ != nullptr ? spread_->size() : 1),
        arena_(jobs > 0 ? jobs : tbb::task_arena::automatic) {
    state_.ranks = spread_ != nullptr ? spread_->size() : 1;
    for (const TuningExperiment& e : experiments_)
      all_scans_ += static_cast<int64_t>(e.scans->size());
  }

  /// One budget after the other when spread over processes (every process must share its
  /// evaluations in the same order) or on one thread. Otherwise the budgets run side by side,
  /// the dearest first, so that a core idle at the end of one budget's generation (or half of
  /// one) takes the other's individuals: the same study, without the waits. False when
  /// cancelled.
  bool Run() {
    const size_t budgets = state_.budgets.size();
    const auto workers = static_cast<size_t>(arena_.max_concurrency());
    if (spread_ != nullptr || workers < 2 || budgets < 2) {
      for (size_t slot = 0; slot < budgets; ++slot) {
        if (!Study(slot)) return false;
      }
      return true;
    }
    std::vector<size_t> order(budgets);
    std::iota(order.begin(), order.end(), size_t{0});
    std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
      return state_.budgets[a].budget > state_.budgets[b].budget;
    });
    std::atomic<size_t> next{0};
    std::atomic<bool> finished{true};
    arena_.execute([&] {
      tbb::task_group group;
      for (size_t w = 0; w < std::min(workers, budgets); ++w) {
        group.run([&] {
          for (size_t k = next++; k < budgets && finished.load(); k = next++) {
            if (!Study(order[k])) finished = false;
          }
        });
      }
      group.wait();
    });
    return finished.load();
  }

 private:
  // What a generation's evaluations cost.
  struct Tally {
    int64_t replays = 0, scans = 0;
    int raced_out = 0;
  };

  bool Cancelled() const { return callbacks_.cancel != nullptr && callbacks_.cancel->load(); }

  /// The budget in `slot`, generation after generation; false when cancelled.
  bool Study(size_t slot) {
    BudgetRun& run = state_.budgets[slot];
    const TuningSettings& settings = state_.settings;
    const EvolutionConfig& es = settings.evolution;
    const size_t n_exp = experiments_.size();
    while (static_cast<int>(run.generations.size()) < es.generations) {
      const int generation = static_cast<int>(run.generations.size());
      progress_.StartGeneration(slot, run.budget, generation);
      const auto stream = static_cast<uint64_t>(run.budget);
      std::vector<Individual> population =
          generation == 0
              ? InitialPopulation(settings.start, es, stream, es.MaxParticles(run.budget))
              : NextGeneration(run.population, es, stream, generation, es.MaxParticles(run.budget));
      std::vector<size_t> pending;
      std::vector<const Individual*> carried;
      for (size_t i = 0; i < population.size(); ++i) {
        if (!population[i].evaluated) {
          pending.push_back(i);
        } else {
          carried.push_back(&population[i]);
        }
      }
      Tally tally;
      // The race, in every generation but the last, against the worst of the best `elites`
      // individuals evaluated whole so far: the elites carried over, and the new individuals of
      // the generation's first half that finished. An individual that cannot beat the worst of
      // them cannot be among the generation's best `elites`. The second half races against a
      // cut that the first half's good individuals made tighter. Generation 0 has no elite yet:
      // its first half is evaluated whole.
      const bool racing = settings.racing && generation + 1 < es.generations;
      if (!racing) {
        if (!Evaluate(slot, population, pending, NoRace(n_exp), tally)) return false;
      } else {
        const auto half = static_cast<std::ptrdiff_t>(pending.size() / 2);
        const std::vector<size_t> first(pending.begin(), pending.begin() + half),
            second(pending.begin() + half, pending.end());
        if (!Evaluate(slot, population, first,
                      MakeRace(carried, es.elites(), n_exp, settings.race_alpha), tally))
          return false;
        for (size_t i : first) {
          if (!population[i].raced_out) carried.push_back(&population[i]);
        }
        if (!Evaluate(slot, population, second,
                      MakeRace(carried, es.elites(), n_exp, settings.race_alpha), tally))
          return false;
      }
      GenerationSummary summary =
          Summarize(population, generation, static_cast<int>(pending.size()));
      summary.replays = tally.replays;
      summary.scans = tally.scans;
      summary.replays_saved = static_cast<int64_t>(pending.size() * n_exp) - tally.replays;
      summary.scans_saved = static_cast<int64_t>(pending.size()) * all_scans_ - tally.scans;
      summary.raced_out = tally.raced_out;
      progress_.FinishGeneration(
          slot, tally.replays, summary.replays_saved,
          static_cast<double>(pending.size()) * Work(experiments_, run.budget));
      MutexLock lock(state_mutex_);
      run.generations.push_back(std::move(summary));
      run.population = std::move(population);
      if (callbacks_.generation_done) {
        progress_.Serialised([&] { callbacks_.generation_done(state_, run.budget); });
      }
    }
    return true;
  }

  /// Evaluates population[items[j]] for every j, in parallel (this process's share of them when
  /// spread), each racing `race`; false when cancelled (the generation is then dropped).
  bool Evaluate(size_t slot, std::vector<Individual>& population, const std::vector<size_t>& items,
                const Race& race, Tally& tally) {
    const int64_t budget = state_.budgets[slot].budget;
    const size_t n_exp = experiments_.size();
    std::vector<Evaluation> evaluations(items.size());
    const RaceProgress report = [&](double work, int64_t replays, int64_t spared) {
      progress_.Report(slot, work, replays, spared);
    };
    arena_.execute([&] {
      // One individual a task, so that a core that finishes early takes the next one.
      tbb::parallel_for(
          tbb::blocked_range<size_t>(0, items.size(), 1),
          [&](const tbb::blocked_range<size_t>& r) {
            for (size_t j = r.begin(); j != r.end(); ++j) {
              if (spread_ != nullptr && !spread_->Mine(j)) continue;  // another process's
              RaceIndividual(experiments_, population[items[j]].params, budget, state_.settings,
                             race, callbacks_.cancel, report, evaluations[j]);
            }
          },
          tbb::simple_partitioner());
    });
    if (spread_ != nullptr) {
      // Every process's results (and whether any was cancelled) to every process.
      if (!ShareEvaluations(*spread_, evaluations, n_exp, Cancelled())) return false;
    } else if (Cancelled()) {
      return false;
    }
    for (size_t j = 0; j < items.size(); ++j) {
      const Evaluation& ev = evaluations[j];
      ApplyEvaluation(ev, race, n_exp, population[items[j]]);
      tally.replays += ev.replays;
      tally.scans += ev.scans;
      tally.raced_out += ev.raced_out ? 1 : 0;
    }
    return true;
  }

  const std::vector<TuningExperiment>& experiments_;
  TuningState& state_;
  const TuningCallbacks& callbacks_;
  const EvaluationSpread* spread_;
  ProgressTracker progress_;
  tbb::task_arena arena_;
  int64_t all_scans_ = 0;
  // Guards the state's budget runs while budgets run side by side (and the callback's reading).
  Mutex state_mutex_;
};

}  // namespace

bool RunTuning(const std::vector<TuningExperiment>& experiments, TuningState& state, int jobs,
               const TuningCallbacks& callbacks) {
  return Tuner(experiments, state, jobs, callbacks).Run();
}

}  // namespace slam::offline
