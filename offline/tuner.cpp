#include "offline/tuner.hpp"

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <mutex>

#include "engine/thread_safety.hpp"
#include "offline/replay.hpp"

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
    ReplayOptions options;
    options.params = ParamsChoice("candidate", params);
    options.config.seed = settings.evolution.seed;
    options.config.parallel = false;  // evaluations are the parallelism
    options.budget.rays_per_scan = budget;
    options.budget.policy = settings.policy;
    options.budget.max_particles = settings.max_particles;
    options.cancel = cancel;
    const ReplayResult run = Replay(*e.robot, *e.scans, *e.ground_truth, options);
    sum += run.quality ? run.quality->e : 0.0;
  }
  return experiments.empty() ? 0.0 : sum / static_cast<double>(experiments.size());
}

bool RunTuning(const std::vector<TuningExperiment>& experiments, TuningState& state, int jobs,
               const TuningCallbacks& callbacks) {
  const TuningSettings& settings = state.settings;
  const EvolutionConfig& es = settings.evolution;
  const int generations = es.generations;

  // The work left, for the progress callback.
  double total = 0.0;
  for (const BudgetRun& run : state.budgets) {
    const int done = static_cast<int>(run.generations.size());
    if (done >= generations) continue;
    const int fresh = done == 0 ? es.population + (generations - 1) * (es.population - es.elites())
                                : (generations - done) * (es.population - es.elites());
    total += fresh * Work(experiments, run.budget);
  }
  double done_work = 0.0;
  Mutex progress_mutex;
  const auto cancelled = [&] { return callbacks.cancel && callbacks.cancel->load(); };

  tbb::task_arena arena(jobs > 0 ? jobs : tbb::task_arena::automatic);
  for (BudgetRun& run : state.budgets) {
    while (static_cast<int>(run.generations.size()) < generations) {
      const int generation = static_cast<int>(run.generations.size());
      const auto stream = static_cast<uint64_t>(run.budget);
      std::vector<Individual> population =
          generation == 0
              ? InitialPopulation(settings.start, es, stream, es.MaxParticles(run.budget))
              : NextGeneration(run.population, es, stream, generation, es.MaxParticles(run.budget));

      // Every (individual, experiment) pair not evaluated yet, in parallel; each writes its slot.
      std::vector<size_t> pending;
      for (size_t i = 0; i < population.size(); ++i) {
        if (!population[i].evaluated) pending.push_back(i);
      }
      const size_t n_exp = experiments.size();
      std::vector<double> e(pending.size() * n_exp, 0.0);
      const double item_work = static_cast<double>(run.budget);
      arena.execute([&] {
        tbb::parallel_for(size_t{0}, e.size(), [&](size_t k) {
          if (cancelled()) return;
          const TuningExperiment& experiment = experiments[k % n_exp];
          e[k] = Fitness({experiment}, population[pending[k / n_exp]].params, run.budget, settings,
                         callbacks.cancel);
          if (callbacks.progress) {
            MutexLock lock(progress_mutex);
            done_work += item_work * static_cast<double>(experiment.scans->size());
            callbacks.progress(done_work, total);
          }
        });
      });
      if (cancelled()) return false;
      for (size_t j = 0; j < pending.size(); ++j) {
        double sum = 0.0;
        for (size_t x = 0; x < n_exp; ++x) sum += e[j * n_exp + x];
        Individual& individual = population[pending[j]];
        individual.fitness = n_exp > 0 ? sum / static_cast<double>(n_exp) : 0.0;
        individual.evaluated = true;
      }
      run.generations.push_back(
          Summarize(population, generation, static_cast<int>(pending.size())));
      run.population = std::move(population);
      if (callbacks.generation_done) callbacks.generation_done(state, run.budget);
    }
  }
  return true;
}

}  // namespace slam::offline
