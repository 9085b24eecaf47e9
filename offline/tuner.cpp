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

namespace {

/// One replay of a tuning evaluation, on this thread, with the settings' policy and seed.
ReplayResult ReplayFor(const TuningExperiment& e, const SlamParams& params, int64_t budget,
                       const TuningSettings& settings, const std::atomic<bool>* cancel,
                       double stop_above_e = std::numeric_limits<double>::infinity()) {
  ReplayOptions options;
  options.params = ParamsChoice("candidate", params);
  options.config.seed = settings.evolution.seed;
  options.config.parallel = false;  // evaluations are the parallelism
  options.budget.rays_per_scan = budget;
  options.budget.policy = settings.policy;
  options.budget.max_particles = settings.max_particles;
  options.cancel = cancel;
  options.stop_above_e = stop_above_e;
  return Replay(*e.robot, *e.scans, *e.ground_truth, options);
}

/// The e of a finished replay (0, the best, when too little of it matched the ground truth).
double EOf(const ReplayResult& run) { return run.quality ? run.quality->e : 0.0; }

/// Racing's margin on the replays' bound: ErrorLowerBound is the same sums as e in another
/// order, so a bound equal to the cut within rounding must not stop a replay.
double StopAbove(double allowed) { return allowed + 1e-9 * (1.0 + std::abs(allowed)); }

/// An individual's evaluation: every experiment in order, or until racing stops it.
struct Evaluation {
  double sum = 0.0;  // of e over the experiments replayed (the last one's bound when stopped)
  std::vector<double> scores;
  double trail = 0.0;   // the sum of its e minus the worst elite's (racing's test)
  size_t replayed = 0;  // experiments replayed (scores of the others: NaN)
  bool raced_out = false;
  int64_t replays = 0, scans = 0;
};

/// What a generation's new individuals race against.
struct Race {
  double cut = std::numeric_limits<double>::infinity();  // the elites' worst fitness
  // The statistical test: the worst elite's scores (empty: the bound only), the order in which
  // the experiments are replayed (the most telling first), and slack[k], how far an individual
  // may trail that elite after the first k of them and stay in the race.
  std::vector<double> cut_scores;
  std::vector<size_t> order;
  std::vector<double> slack;
};

/// No race: every experiment, in order, to the end.
Race NoRace(size_t n_exp) {
  Race race;
  for (size_t x = 0; x < n_exp; ++x) race.order.push_back(x);
  return race;
}

/// A race against the `elites`-th best of `carried`, the individuals evaluated whole so far.
Race MakeRace(const std::vector<const Individual*>& carried, int elites, size_t n_exp,
              double alpha) {
  Race race = NoRace(n_exp);
  if (carried.size() < static_cast<size_t>(elites) || elites < 1 || n_exp == 0) return race;
  std::vector<const Individual*> ranked = carried;
  std::stable_sort(ranked.begin(), ranked.end(), [](const Individual* a, const Individual* b) {
    return a->fitness < b->fitness;
  });
  const Individual& worst = *ranked[static_cast<size_t>(elites) - 1];
  race.cut = worst.fitness;
  const auto whole = [&](const Individual& i) {
    return i.scores.size() == n_exp &&
           std::all_of(i.scores.begin(), i.scores.end(), [](double e) { return std::isfinite(e); });
  };
  // The spread, per experiment, of the other elites' e minus the worst's.
  const size_t others = static_cast<size_t>(elites) - 1;
  if (!(alpha > 0.0) || n_exp < 2 || others < 2 || !whole(worst)) return race;
  std::vector<double> variance(n_exp, 0.0);
  for (size_t x = 0; x < n_exp; ++x) {
    double mean = 0.0;
    for (size_t m = 0; m < others; ++m) {
      if (!whole(*ranked[m])) return race;  // saved before scores were kept
      mean += ranked[m]->scores[x] - worst.scores[x];
    }
    mean /= static_cast<double>(others);
    for (size_t m = 0; m < others; ++m) {
      const double d = ranked[m]->scores[x] - worst.scores[x] - mean;
      variance[x] += d * d / static_cast<double>(others - 1);
    }
  }
  race.cut_scores = worst.scores;
  std::stable_sort(race.order.begin(), race.order.end(),
                   [&](size_t a, size_t b) { return variance[a] > variance[b]; });
  const double z = NormalQuantile(1.0 - alpha);
  race.slack.assign(n_exp + 1, 0.0);
  double rest = 0.0;
  for (size_t k = n_exp; k-- > 0;) {
    race.slack[k + 1] = z * std::sqrt(rest);
    rest += variance[race.order[k]];
  }
  race.slack[0] = z * std::sqrt(rest);
  return race;
}

/// Every process's evaluations to every process (each owns some items, zeros elsewhere); false
/// when any process was cancelled.
bool ShareEvaluations(const EvaluationSpread& spread, std::vector<Evaluation>& evaluations,
                      size_t n_exp, bool cancelled) {
  constexpr size_t kFixed = 6;  // sum, trail, replayed, raced out, replays, scans; then scores
  const size_t record = kFixed + n_exp;
  std::vector<double> values(evaluations.size() * record + 1, 0.0);
  for (size_t j = 0; j < evaluations.size(); ++j) {
    if (!spread.Mine(j)) continue;
    const Evaluation& ev = evaluations[j];
    double* r = values.data() + j * record;
    r[0] = ev.sum;
    r[1] = ev.trail;
    r[2] = static_cast<double>(ev.replayed);
    r[3] = ev.raced_out ? 1.0 : 0.0;
    r[4] = static_cast<double>(ev.replays);
    r[5] = static_cast<double>(ev.scans);
    for (size_t x = 0; x < n_exp && x < ev.scores.size(); ++x) r[kFixed + x] = ev.scores[x];
  }
  values.back() = cancelled ? 1.0 : 0.0;
  spread.SumAll(values);
  if (values.back() > 0.0) return false;
  for (size_t j = 0; j < evaluations.size(); ++j) {
    Evaluation& ev = evaluations[j];
    const double* r = values.data() + j * record;
    ev.sum = r[0];
    ev.trail = r[1];
    ev.replayed = static_cast<size_t>(r[2]);
    ev.raced_out = r[3] > 0.5;
    ev.replays = static_cast<int64_t>(r[4]);
    ev.scans = static_cast<int64_t>(r[5]);
    ev.scores.assign(r + kFixed, r + record);
  }
  return true;
}

}  // namespace

double Fitness(const std::vector<TuningExperiment>& experiments, const SlamParams& params,
               int64_t budget, const TuningSettings& settings, const std::atomic<bool>* cancel) {
  double sum = 0.0;
  for (const TuningExperiment& e : experiments) {
    if (cancel != nullptr && cancel->load()) break;
    sum += EOf(ReplayFor(e, params, budget, settings, cancel));
  }
  return experiments.empty() ? 0.0 : sum / static_cast<double>(experiments.size());
}

bool RunTuning(const std::vector<TuningExperiment>& experiments, TuningState& state, int jobs,
               const TuningCallbacks& callbacks) {
  const TuningSettings& settings = state.settings;
  const EvolutionConfig& es = settings.evolution;
  const int generations = es.generations;

  // The work left without racing, for the progress callback (racing's savings count as done).
  double total = 0.0;
  for (const BudgetRun& run : state.budgets) {
    const int done = static_cast<int>(run.generations.size());
    if (done >= generations) continue;
    const int fresh = done == 0 ? es.population + (generations - 1) * (es.population - es.elites())
                                : (generations - done) * (es.population - es.elites());
    total += fresh * Work(experiments, run.budget);
  }
  // Progress: exact at every generation's start (`base`); within a generation, this process's
  // own replays (`local`), times the processes when the evaluations are spread.
  const EvaluationSpread* spread = callbacks.spread;
  const double processes = spread != nullptr ? spread->size() : 1;
  state.ranks = spread != nullptr ? spread->size() : 1;
  // `local[b]`: budget b's generation in progress (budgets may run side by side).
  TuningProgress base;
  std::vector<TuningProgress> local(state.budgets.size());
  base.total = total;
  Mutex progress_mutex;
  const auto cancelled = [&] { return callbacks.cancel && callbacks.cancel->load(); };
  // A replay's work done (racing's savings with it), and the replays it finished or spared.
  const auto report = [&](size_t slot, double work, int64_t replays, int64_t saved) {
    if (!callbacks.progress) return;
    MutexLock lock(progress_mutex);
    local[slot].done += work;
    local[slot].replays += replays;
    local[slot].replays_saved += saved;
    TuningProgress p = base;
    p.budget = local[slot].budget;
    p.generation = local[slot].generation;
    for (const TuningProgress& l : local) {
      p.done += processes * l.done;
      p.replays += static_cast<int64_t>(processes * static_cast<double>(l.replays));
      p.replays_saved += static_cast<int64_t>(processes * static_cast<double>(l.replays_saved));
    }
    p.done = std::min(p.done, p.total);
    callbacks.progress(p);
  };
  int64_t all_scans = 0;
  for (const TuningExperiment& e : experiments) all_scans += static_cast<int64_t>(e.scans->size());
  const size_t n_exp = experiments.size();
  const double n = static_cast<double>(n_exp);

  tbb::task_arena arena(jobs > 0 ? jobs : tbb::task_arena::automatic);
  // Guards the state's budget runs while budgets run side by side (and the callback's reading).
  Mutex state_mutex;
  // One budget's study, from where it stands to its last generation; false when cancelled.
  const auto study = [&](size_t slot) {
    BudgetRun& run = state.budgets[slot];
    while (static_cast<int>(run.generations.size()) < generations) {
      const int generation = static_cast<int>(run.generations.size());
      {
        MutexLock lock(progress_mutex);
        local[slot] = TuningProgress{};
        local[slot].budget = run.budget;
        local[slot].generation = generation;
      }
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
      int64_t replays = 0, scans = 0;
      int raced_out = 0;
      // Evaluates population[items[j]] for every j, in parallel, each racing `race`; false when
      // cancelled (the generation is then dropped).
      const auto evaluate = [&](const std::vector<size_t>& items, const Race& race) {
        const double cut = race.cut;
        std::vector<Evaluation> evaluations(items.size());
        arena.execute([&] {
          // One individual a task, so that a core that finishes early takes the next one.
          const auto one = [&](size_t j) {
            if (spread != nullptr && !spread->Mine(j)) return;  // another process's
            Evaluation& ev = evaluations[j];
            const SlamParams& params = population[items[j]].params;
            double& trail = ev.trail;
            const bool test = !race.cut_scores.empty();
            ev.scores.assign(n_exp, std::numeric_limits<double>::quiet_NaN());
            for (size_t k = 0; k < n_exp; ++k) {
              if (cancelled()) return;
              const size_t x = race.order[k];
              const TuningExperiment& experiment = experiments[x];
              // Racing: the e this replay may reach before the mean can no longer be under the
              // cut, or (the test) before it trails the worst elite by more than the rest allows.
              double allowed = cut * n - ev.sum;
              if (test) allowed = std::min(allowed, race.cut_scores[x] - trail + race.slack[k + 1]);
              const ReplayResult replay = ReplayFor(experiment, params, run.budget, settings,
                                                    callbacks.cancel, StopAbove(allowed));
              if (replay.cancelled) return;  // the generation is dropped
              ++ev.replays;
              ev.scans += replay.scans;
              const double work = static_cast<double>(run.budget);
              const double e = replay.stopped_early ? replay.e_lower_bound : EOf(replay);
              ev.sum += e;
              ev.scores[x] = e;
              ev.replayed = k + 1;
              if (test) trail += e - race.cut_scores[x];
              ev.raced_out =
                  replay.stopped_early ||
                  (k + 1 < n_exp && (ev.sum / n > cut || (test && trail > race.slack[k + 1])));
              if (ev.raced_out) {
                // What is spared counts as done, so that the progress reaches its end.
                int64_t rest = static_cast<int64_t>(experiment.scans->size()) - replay.scans;
                for (size_t y = k + 1; y < n_exp; ++y)
                  rest += static_cast<int64_t>(experiments[race.order[y]].scans->size());
                report(slot, work * static_cast<double>(replay.scans + rest), 1,
                       static_cast<int64_t>(n_exp - k - 1));
                return;
              }
              report(slot, work * static_cast<double>(replay.scans), 1, 0);
            }
          };
          tbb::parallel_for(
              tbb::blocked_range<size_t>(0, items.size(), 1),
              [&](const tbb::blocked_range<size_t>& r) {
                for (size_t j = r.begin(); j != r.end(); ++j) one(j);
              },
              tbb::simple_partitioner());
        });
        if (spread != nullptr) {
          // Every process's results (and whether any was cancelled) to every process.
          if (!ShareEvaluations(*spread, evaluations, n_exp, cancelled())) return false;
        } else if (cancelled()) {
          return false;
        }
        for (size_t j = 0; j < items.size(); ++j) {
          const Evaluation& ev = evaluations[j];
          Individual& individual = population[items[j]];
          if (ev.raced_out) {
            individual.fitness = ev.sum / n;
            if (!race.cut_scores.empty()) {
              // Stopped by the test: its paired estimate (the worst elite's fitness plus its
              // mean trail so far) when that is above its bound; above the cut either way.
              individual.fitness =
                  std::max(individual.fitness, cut + ev.trail / static_cast<double>(ev.replayed));
            }
          } else {
            // In the experiments' order, whatever order they ran in: as without racing.
            double sum = 0.0;
            for (const double e : ev.scores) sum += e;
            individual.fitness = n_exp > 0 ? sum / n : 0.0;
          }
          individual.evaluated = true;
          individual.raced_out = ev.raced_out;
          individual.scores = ev.scores;
          replays += ev.replays;
          scans += ev.scans;
          raced_out += ev.raced_out ? 1 : 0;
        }
        return true;
      };

      // The race, in every generation but the last, against the worst of the best `elites`
      // individuals evaluated whole so far: the elites carried over, and the new individuals of
      // the generation's first half that finished. An individual that cannot beat the worst of
      // them cannot be among the generation's best `elites`. The second half races against a
      // cut that the first half's good individuals made tighter. Generation 0 has no elite yet:
      // its first half is evaluated whole.
      const bool racing = settings.racing && generation + 1 < generations;
      if (!racing) {
        if (!evaluate(pending, NoRace(n_exp))) return false;
      } else {
        const auto half = static_cast<std::ptrdiff_t>(pending.size() / 2);
        const std::vector<size_t> first(pending.begin(), pending.begin() + half),
            second(pending.begin() + half, pending.end());
        if (!evaluate(first, MakeRace(carried, es.elites(), n_exp, settings.race_alpha)))
          return false;
        for (size_t i : first) {
          if (!population[i].raced_out) carried.push_back(&population[i]);
        }
        if (!evaluate(second, MakeRace(carried, es.elites(), n_exp, settings.race_alpha)))
          return false;
      }
      GenerationSummary summary =
          Summarize(population, generation, static_cast<int>(pending.size()));
      summary.replays = replays;
      summary.scans = scans;
      summary.replays_saved = static_cast<int64_t>(pending.size() * n_exp) - replays;
      summary.scans_saved = static_cast<int64_t>(pending.size()) * all_scans - scans;
      summary.raced_out = raced_out;
      {
        MutexLock lock(progress_mutex);  // exact again: every process's replays
        base.replays += replays;
        base.replays_saved += summary.replays_saved;
        base.done += static_cast<double>(pending.size()) * Work(experiments, run.budget);
        local[slot] = TuningProgress{};
      }
      MutexLock lock(state_mutex);
      run.generations.push_back(std::move(summary));
      run.population = std::move(population);
      if (callbacks.generation_done) {
        MutexLock serial(progress_mutex);  // never at once with the progress callback
        callbacks.generation_done(state, run.budget);
      }
    }
    return true;
  };

  // One budget after the other when spread over processes (every process must share its
  // evaluations in the same order) or on one thread. Otherwise the budgets run side by side,
  // the dearest first, so that a core idle at the end of one budget's generation (or half of
  // one) takes the other's individuals: the same study, without the waits.
  const size_t budgets = state.budgets.size();
  const auto workers = static_cast<size_t>(arena.max_concurrency());
  if (spread != nullptr || workers < 2 || budgets < 2) {
    for (size_t slot = 0; slot < budgets; ++slot) {
      if (!study(slot)) return false;
    }
    return true;
  }
  std::vector<size_t> order(budgets);
  std::iota(order.begin(), order.end(), size_t{0});
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    return state.budgets[a].budget > state.budgets[b].budget;
  });
  std::atomic<size_t> next{0};
  std::atomic<bool> finished{true};
  arena.execute([&] {
    tbb::task_group group;
    for (size_t w = 0; w < std::min(workers, budgets); ++w) {
      group.run([&] {
        for (size_t k = next++; k < budgets && finished.load(); k = next++) {
          if (!study(order[k])) finished = false;
        }
      });
    }
    group.wait();
  });
  return finished.load();
}

}  // namespace slam::offline
