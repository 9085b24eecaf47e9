#include "offline/racing.hpp"

#include <algorithm>
#include <cmath>

#include "offline/statistics.hpp"

namespace slam::offline {
namespace {

/// Racing's margin on the replays' bound: ErrorLowerBound is the same sums as e in another
/// order, so a bound equal to the cut within rounding must not stop a replay.
double StopAbove(double allowed) { return allowed + 1e-9 * (1.0 + std::abs(allowed)); }

}  // namespace

/// One replay of a tuning evaluation, on this thread, with the settings' policy and seed.
ReplayResult ReplayFor(const TuningExperiment& e, const SlamParams& params, int64_t budget,
                       const TuningSettings& settings, const std::atomic<bool>* cancel,
                       double stop_above_e) {
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

void RaceIndividual(const std::vector<TuningExperiment>& experiments, const SlamParams& params,
                    int64_t budget, const TuningSettings& settings, const Race& race,
                    const std::atomic<bool>* cancel, const RaceProgress& progress, Evaluation& ev) {
  const size_t n_exp = experiments.size();
  const double n = static_cast<double>(n_exp);
  const double cut = race.cut;
  double& trail = ev.trail;
  const bool test = !race.cut_scores.empty();
  ev.scores.assign(n_exp, std::numeric_limits<double>::quiet_NaN());
  for (size_t k = 0; k < n_exp; ++k) {
    if (cancel != nullptr && cancel->load()) return;
    const size_t x = race.order[k];
    const TuningExperiment& experiment = experiments[x];
    // Racing: the e this replay may reach before the mean can no longer be under the cut, or
    // (the test) before it trails the worst elite by more than the rest allows.
    double allowed = cut * n - ev.sum;
    if (test) allowed = std::min(allowed, race.cut_scores[x] - trail + race.slack[k + 1]);
    const ReplayResult replay =
        ReplayFor(experiment, params, budget, settings, cancel, StopAbove(allowed));
    if (replay.cancelled) return;  // the generation is dropped
    ++ev.replays;
    ev.scans += replay.scans;
    const double work = static_cast<double>(budget);
    const double e = replay.stopped_early ? replay.e_lower_bound : EOf(replay);
    ev.sum += e;
    ev.scores[x] = e;
    ev.replayed = k + 1;
    if (test) trail += e - race.cut_scores[x];
    ev.raced_out = replay.stopped_early ||
                   (k + 1 < n_exp && (ev.sum / n > cut || (test && trail > race.slack[k + 1])));
    if (ev.raced_out) {
      // What is spared counts as done, so that the progress reaches its end.
      int64_t rest = static_cast<int64_t>(experiment.scans->size()) - replay.scans;
      for (size_t y = k + 1; y < n_exp; ++y)
        rest += static_cast<int64_t>(experiments[race.order[y]].scans->size());
      progress(work * static_cast<double>(replay.scans + rest), 1,
               static_cast<int64_t>(n_exp - k - 1));
      return;
    }
    progress(work * static_cast<double>(replay.scans), 1, 0);
  }
}

void ApplyEvaluation(const Evaluation& ev, const Race& race, size_t n_exp, Individual& individual) {
  const double n = static_cast<double>(n_exp);
  if (ev.raced_out) {
    individual.fitness = ev.sum / n;
    if (!race.cut_scores.empty()) {
      // Stopped by the test: its paired estimate (the worst elite's fitness plus its mean trail
      // so far) when that is above its bound; above the cut either way.
      individual.fitness =
          std::max(individual.fitness, race.cut + ev.trail / static_cast<double>(ev.replayed));
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
}

}  // namespace slam::offline
