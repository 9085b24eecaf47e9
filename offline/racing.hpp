#pragma once
// Racing in the tuner (TuningSettings::racing, RunTuning): one individual's evaluation, replayed
// on the experiments one after the other until the end or until it can no longer enter the
// elite, what it races against, and its fitness from what was replayed.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <limits>
#include <vector>

#include "engine/params.hpp"
#include "offline/evolution.hpp"
#include "offline/replay.hpp"
#include "offline/tuner.hpp"

namespace slam::offline {

/// One replay of a tuning evaluation, on this thread, with the settings' policy and seed.
ReplayResult ReplayFor(const TuningExperiment& e, const SlamParams& params, int64_t budget,
                       const TuningSettings& settings, const std::atomic<bool>* cancel,
                       double stop_above_e = std::numeric_limits<double>::infinity());

/// The e of a finished replay (0, the best, when too little of it matched the ground truth).
double EOf(const ReplayResult& run);

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
Race NoRace(size_t n_exp);

/// A race against the `elites`-th best of `carried`, the individuals evaluated whole so far.
Race MakeRace(const std::vector<const Individual*>& carried, int elites, size_t n_exp,
              double alpha);

/// What an evaluation reports as it goes: the work its replays did (scans times the budget,
/// racing's savings counted as done), the replays it finished and those racing spared.
using RaceProgress = std::function<void(double work, int64_t replays, int64_t spared)>;

/// Replays `params` at `budget` on the experiments in the race's order into `ev`, until the end
/// or until the race stops it. Returns early, `ev` incomplete, when `cancel` is set.
void RaceIndividual(const std::vector<TuningExperiment>& experiments, const SlamParams& params,
                    int64_t budget, const TuningSettings& settings, const Race& race,
                    const std::atomic<bool>* cancel, const RaceProgress& progress, Evaluation& ev);

/// The individual's fitness, scores and racing state from its evaluation.
void ApplyEvaluation(const Evaluation& ev, const Race& race, size_t n_exp, Individual& individual);

/// Every process's evaluations to every process (each owns some items, zeros elsewhere); false
/// when any process was cancelled.
bool ShareEvaluations(const EvaluationSpread& spread, std::vector<Evaluation>& evaluations,
                      size_t n_exp, bool cancelled);

}  // namespace slam::offline
