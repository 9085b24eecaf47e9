// The evolution strategy and the tuner: mutation within bounds, convergence on a toy function
// with elitism keeping the best, a reduced study on two short generated experiments that
// improves over generations, independence from the thread count, resuming (from results.json,
// after an interruption, and extending a finished study), and the tables and files slam-tune
// writes, read back.

#include "offline/tuner.hpp"

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <algorithm>
#include <atomic>
#include <barrier>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include "engine/io/params_json.hpp"
#include "offline/evolution.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/tuning_report.hpp"
#include "sim/experiment_writer.hpp"
#include "sim/scenario.hpp"
#include "tests/experiment_support.hpp"
#include "tests/test_support.hpp"

namespace slam {
namespace {

namespace fs = std::filesystem;

/// A smooth toy fitness: squared distance to a target, each parameter in units of its sigma.
double Toy(const SlamParams& p, const SlamParams& target) {
  double sum = 0.0;
  const auto& specs = offline::TunedParameters();
  for (size_t i = 0; i < specs.size(); ++i) {
    sum += std::pow(
        (offline::GetParameter(p, i) - offline::GetParameter(target, i)) / specs[i].sigma, 2);
  }
  return sum;
}

TEST(Evolution, MutationStaysInBoundsRoundsIntegersAndUsesTheSigmas) {
  const auto& specs = offline::TunedParameters();
  ASSERT_EQ(specs.size(), 9u);
  SlamParams middle;  // far from every bound (in sigmas) so that clamping does not bias
  middle.angle_between_scans_deg = 20.0;
  middle.particles = 30;
  middle.resampling_period_scans = 20;
  middle.min_angle_uncertainty_deg = 10.0;
  middle.dist_error_const_m = 0.05;
  middle.angle_error_const_deg = 1.0;
  Rng rng(4);
  std::vector<double> sum_sq(specs.size(), 0.0);
  const int n = 20000;
  for (int k = 0; k < n; ++k) {
    const SlamParams m = offline::Mutate(middle, rng);
    EXPECT_TRUE(Validate(m).empty());
    for (size_t i = 0; i < specs.size(); ++i) {
      const double v = offline::GetParameter(m, i);
      ASSERT_GE(v, specs[i].lo);
      ASSERT_LE(v, specs[i].hi);
      if (specs[i].integer) {
        ASSERT_EQ(v, std::round(v));
      }
      sum_sq[i] += std::pow(v - offline::GetParameter(middle, i), 2);
    }
  }
  for (size_t i = 0; i < specs.size(); ++i) {
    // Rounding adds 1/12 of a unit squared to the integers' variance.
    const double expected = specs[i].sigma * specs[i].sigma + (specs[i].integer ? 1.0 / 12.0 : 0.0);
    EXPECT_NEAR(sum_sq[i] / n, expected, 0.06 * expected) << specs[i].key;
  }
  // At a bound the draws are clamped, never outside.
  SlamParams low;
  low.particles = 1;
  low.angle_between_scans_deg = 0.0;
  for (int k = 0; k < 1000; ++k) {
    const SlamParams m = offline::Mutate(low, rng);
    ASSERT_GE(m.particles, 1);
    ASSERT_GE(m.angle_between_scans_deg, 0.0);
  }
}

TEST(Evolution, TheParticleBoundFollowsTheBudget) {
  offline::EvolutionConfig config;
  EXPECT_EQ(config.MaxParticles(8125), offline::kMaxTunedParticles);  // no bound by default
  config.min_rays_per_particle = 8125;
  EXPECT_EQ(config.MaxParticles(8125), 1);
  EXPECT_EQ(config.MaxParticles(16250), 2);
  EXPECT_EQ(config.MaxParticles(65000), 8);
  EXPECT_EQ(config.MaxParticles(1000), 1);  // a budget below the bound still has one particle
  EXPECT_EQ(config.MaxParticles(int64_t{1} << 40), offline::kMaxTunedParticles);
  config.min_rays_per_particle = -1;
  EXPECT_FALSE(offline::Validate(config).empty());

  // Every individual of every generation stays within the bound, the start included, although
  // the fitness rewards more particles.
  config = offline::EvolutionConfig{};
  config.min_rays_per_particle = 8125;
  SlamParams start;
  start.particles = 10;
  const int most = config.MaxParticles(16250);
  std::vector<offline::Individual> population =
      offline::InitialPopulation(start, config, 16250, most);
  for (int g = 1; g < 6; ++g) {
    int largest = 0;
    for (offline::Individual& i : population) {
      largest = std::max(largest, i.params.particles);
      i = {i.params, -static_cast<double>(i.params.particles), true};
    }
    EXPECT_EQ(largest, most) << "generation " << g;
    population = offline::NextGeneration(population, config, 16250, g, most);
  }
}

TEST(Evolution, ConvergesOnAToyFunctionAndElitismKeepsTheBest) {
  SlamParams target;
  target.dist_error_ratio = 0.12;
  target.dist_error_const_m = 0.02;
  target.angle_error_ratio = 0.02;
  target.angle_error_const_deg = 0.03;
  target.min_pos_uncertainty_m = 0.035;
  target.min_angle_uncertainty_deg = 8.0;
  target.resampling_period_scans = 3;
  target.angle_between_scans_deg = 10.0;
  target.particles = 4;
  const offline::EvolutionConfig config;  // the paper's: 48, 40 generations, 25 %
  ASSERT_EQ(config.elites(), 12);
  std::vector<offline::Individual> population = offline::InitialPopulation(SlamParams{}, config, 7);
  ASSERT_EQ(population.size(), 48u);
  EXPECT_EQ(population[0].params, SlamParams{});  // the start itself comes first
  const auto evaluate = [&](std::vector<offline::Individual>& pop) {
    for (offline::Individual& i : pop) {
      if (!i.evaluated) i = {i.params, Toy(i.params, target), true};
    }
  };
  evaluate(population);
  const double first = offline::Ranked(population).front().fitness;
  double best = first;
  for (int g = 1; g < config.generations; ++g) {
    const offline::Individual previous_best = offline::Ranked(population).front();
    population = offline::NextGeneration(population, config, 7, g);
    ASSERT_EQ(population.size(), 48u);
    // The elites come first, unchanged and already evaluated; the rest are new.
    for (size_t i = 0; i < 48; ++i) EXPECT_EQ(population[i].evaluated, i < 12);
    EXPECT_EQ(population[0].params, previous_best.params);
    evaluate(population);
    const double now = offline::Ranked(population).front().fitness;
    EXPECT_LE(now, best) << "generation " << g;  // elitism: never worse
    best = now;
  }
  EXPECT_GT(first, 100.0);
  EXPECT_LT(best, 0.02 * first);
  const SlamParams found = offline::Ranked(population).front().params;
  EXPECT_EQ(found.particles, 4);
  EXPECT_NEAR(found.angle_between_scans_deg, 10.0, 2.5);
  // The same seed and stream give the same generation; another stream another one.
  EXPECT_EQ(offline::NextGeneration(population, config, 7, 5)[20].params,
            offline::NextGeneration(population, config, 7, 5)[20].params);
  EXPECT_NE(offline::NextGeneration(population, config, 8, 5)[20].params,
            offline::NextGeneration(population, config, 7, 5)[20].params);
}

/// Two short generated experiments, shared by the reduced studies.
class TunerTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fs::path(::testing::TempDir()) / ("slam_tuner_test_" + std::to_string(::getpid()));
    fs::remove_all(root_);
    uint64_t seed = 3;
    for (const char* arena : {"rooms", "cluttered"}) {
      auto experiment =
          testing::GenerateExperiment((root_ / "exp" / arena).string(), arena, 20.0, seed++);
      ASSERT_TRUE(experiment.has_value());
      experiments_->push_back(std::move(*experiment));
    }
  }
  static void TearDownTestSuite() {
    fs::remove_all(root_);
    experiments_->clear();
  }

  static std::vector<offline::TuningExperiment> Experiments() {
    std::vector<offline::TuningExperiment> out;
    for (const offline::Experiment& e : *experiments_)
      out.push_back({e.meta.name, &e.robot, &e.scans, &e.ground_truth});
    return out;
  }
  /// The reduced study; racing by its bound alone unless `race_alpha` > 0 (then the study's
  /// course may differ from one without racing).
  static offline::TuningSettings Reduced(int generations, double race_alpha = 0.0) {
    offline::TuningSettings settings;
    settings.budgets = {4000};
    settings.evolution.population = 12;
    settings.evolution.generations = generations;
    settings.evolution.seed = 5;
    settings.race_alpha = race_alpha;
    return settings;
  }
  /// The full study of the suite, run once: 12 individuals, 8 generations, 2 threads.
  static const offline::TuningState& Full() {
    static const offline::TuningState state = [] {
      offline::TuningState s = offline::NewTuningState(Reduced(8), Experiments());
      EXPECT_TRUE(offline::RunTuning(Experiments(), s, 2));
      return s;
    }();
    return state;
  }

  static inline fs::path root_;
  static inline std::vector<offline::Experiment>* experiments_ =
      new std::vector<offline::Experiment>();
};

void ExpectSameStudy(const offline::TuningState& a, const offline::TuningState& b) {
  EXPECT_EQ(offline::TuningStateToJson(a), offline::TuningStateToJson(b));
}

/// The same study but for what racing reports of generation `g`: its fitness quartiles and cost
/// (a study of g + 1 generations evaluates its last one whole, a longer one races it).
void ExpectSameStudyButRacingOf(const offline::TuningState& a, const offline::TuningState& b,
                                size_t g) {
  nlohmann::json ja = offline::TuningStateToJson(a), jb = offline::TuningStateToJson(b);
  for (nlohmann::json* j : {&ja, &jb}) {
    for (const char* key : {"min", "q1", "median", "q3", "max", "cost"})
      (*j)["budgets"][0]["generations"][g].erase(key);
  }
  EXPECT_EQ(ja, jb);
}

TEST_F(TunerTest, ReducedStudyImprovesOverGenerations) {
  const offline::TuningState& state = Full();
  ASSERT_EQ(state.budgets.size(), 1u);
  const offline::BudgetRun& run = state.budgets[0];
  ASSERT_EQ(run.generations.size(), 8u);
  EXPECT_EQ(run.generations[0].evaluations, 12);
  EXPECT_EQ(run.generations[1].evaluations, 9);  // elites are not evaluated again
  for (size_t g = 1; g < run.generations.size(); ++g) {
    EXPECT_LE(run.generations[g].best.fitness, run.generations[g - 1].best.fitness);
  }
  const offline::FiveNumbers& first = run.generations.front().fitness;
  const offline::FiveNumbers& last = run.generations.back().fitness;
  EXPECT_LT(last.median, first.median);
  EXPECT_LT(run.generations.back().best.fitness, run.generations.front().best.fitness);
  // The defaults are generation 0's first individual; the best beats them.
  EXPECT_LT(run.generations.back().best.fitness, run.generations.front().fitness_values[0]);
  // The best's fitness is what an evaluation of its parameters gives.
  EXPECT_DOUBLE_EQ(
      offline::Fitness(Experiments(), run.generations.back().best.params, 4000, state.settings),
      run.generations.back().best.fitness);
  std::printf("reduced study: median %.4f -> %.4f, best %.4f -> %.4f\n", first.median, last.median,
              run.generations.front().best.fitness, run.generations.back().best.fitness);
}

TEST_F(TunerTest, SameResultWithOneThreadAndResumedOrExtended) {
  // Three generations on one thread are the first three of the two-thread study.
  offline::TuningState part = offline::NewTuningState(Reduced(3), Experiments());
  ASSERT_TRUE(offline::RunTuning(Experiments(), part, 1));
  ASSERT_EQ(part.budgets[0].generations.size(), 3u);
  for (size_t g = 0; g < 2; ++g) {
    EXPECT_EQ(part.budgets[0].generations[g].fitness_values,
              Full().budgets[0].generations[g].fitness_values);
  }
  // Generation 2, the last of three, is evaluated whole; the longer study raced it: where it
  // stopped an individual, it holds a lower bound.
  const offline::GenerationSummary& whole = part.budgets[0].generations[2];
  const offline::GenerationSummary& raced = Full().budgets[0].generations[2];
  EXPECT_EQ(whole.best.fitness, raced.best.fitness);
  EXPECT_EQ(whole.raced_out, 0);
  int differ = 0;
  for (size_t i = 0; i < whole.fitness_values.size(); ++i) {
    EXPECT_LE(raced.fitness_values[i], whole.fitness_values[i]) << i;
    differ += raced.fitness_values[i] != whole.fitness_values[i] ? 1 : 0;
  }
  EXPECT_LE(differ, raced.raced_out);
  // Saved to JSON, read back and extended to eight generations: the same study.
  auto reread =
      offline::TuningStateFromJson(nlohmann::json::parse(offline::TuningStateToJson(part).dump()));
  ASSERT_TRUE(reread.ok()) << reread.Message();
  offline::TuningState resumed = std::move(reread).value();
  EXPECT_TRUE(
      offline::ResumeConflicts(resumed, Reduced(8), {"rooms-seed3", "cluttered-seed4"}).empty());
  resumed.settings.evolution.generations = 8;
  ASSERT_TRUE(offline::RunTuning(Experiments(), resumed, 2));
  ExpectSameStudyButRacingOf(resumed, Full(), 2);
}

TEST_F(TunerTest, RacingKeepsEveryEliteAndSparesReplays) {
  offline::TuningSettings settings = Reduced(8);
  settings.racing = false;
  offline::TuningState unraced = offline::NewTuningState(settings, Experiments());
  ASSERT_TRUE(offline::RunTuning(Experiments(), unraced, 2));
  const offline::BudgetRun& a = Full().budgets[0];
  const offline::BudgetRun& b = unraced.budgets[0];
  ASSERT_EQ(a.generations.size(), b.generations.size());
  int64_t saved = 0, stopped = 0;
  const size_t elites = static_cast<size_t>(settings.evolution.elites());
  for (size_t g = 0; g < a.generations.size(); ++g) {
    const offline::GenerationSummary& raced = a.generations[g];
    const offline::GenerationSummary& whole = b.generations[g];
    // The same elites, so the same best and the same next generation.
    EXPECT_EQ(raced.best.params, whole.best.params) << g;
    EXPECT_EQ(raced.best.fitness, whole.best.fitness) << g;
    EXPECT_EQ(raced.evaluations, whole.evaluations) << g;
    // Unraced: every new individual on every experiment, to the end.
    EXPECT_EQ(whole.replays, whole.evaluations * 2) << g;
    EXPECT_EQ(whole.replays_saved, 0) << g;
    EXPECT_EQ(whole.scans_saved, 0) << g;
    EXPECT_EQ(raced.replays + raced.replays_saved, whole.replays) << g;
    EXPECT_EQ(raced.scans + raced.scans_saved, whole.scans) << g;
    // A stopped individual's fitness is a lower bound, above the elite's worst.
    std::vector<double> sorted = whole.fitness_values;
    std::sort(sorted.begin(), sorted.end());
    const double cut = sorted[elites - 1];
    for (size_t i = 0; i < whole.fitness_values.size(); ++i) {
      EXPECT_LE(raced.fitness_values[i], whole.fitness_values[i]) << g << " " << i;
      if (raced.fitness_values[i] != whole.fitness_values[i]) {
        EXPECT_GT(raced.fitness_values[i], cut) << g << " " << i;
      }
    }
    if (g + 1 == a.generations.size()) {
      EXPECT_EQ(raced.raced_out, 0) << g;
    }
    saved += raced.scans_saved;
    stopped += raced.raced_out;
  }
  // The last generation is evaluated whole in both: the same population.
  EXPECT_EQ(offline::TuningStateToJson(Full())["budgets"][0]["population"],
            offline::TuningStateToJson(unraced)["budgets"][0]["population"]);
  EXPECT_GT(stopped, 0);
  EXPECT_GT(saved, 0);
  // Generation 0 races too: its second half against its first, evaluated whole.
  EXPECT_GT(a.generations[0].scans_saved, 0);
  EXPECT_EQ(a.generations[0].replays + a.generations[0].replays_saved,
            a.generations[0].evaluations * 2);
  int64_t all = 0;
  for (const offline::GenerationSummary& g : b.generations) all += g.scans;
  std::printf("racing: %lld individuals stopped, %lld of %lld scans spared\n",
              static_cast<long long>(stopped), static_cast<long long>(saved),
              static_cast<long long>(all));
}

TEST_F(TunerTest, RacingsTestStopsMoreAndResumesExactly) {
  // The statistical test on top of the bound: deterministic (one thread or two, interrupted and
  // resumed from results.json), and it spares more than the bound alone.
  offline::TuningState tested = offline::NewTuningState(Reduced(8, 0.05), Experiments());
  ASSERT_TRUE(offline::RunTuning(Experiments(), tested, 2));
  int64_t spared_bound = 0, spared_test = 0;
  for (const auto& g : Full().budgets[0].generations) spared_bound += g.scans_saved;
  for (const auto& g : tested.budgets[0].generations) spared_test += g.scans_saved;
  EXPECT_GT(spared_test, spared_bound);
  const offline::BudgetRun& run = tested.budgets[0];
  EXPECT_LT(run.generations.back().best.fitness, run.generations.front().best.fitness);
  for (const offline::Individual& i : run.population) {
    ASSERT_EQ(i.scores.size(), 2u);  // the last generation is evaluated whole
    EXPECT_DOUBLE_EQ(i.fitness, (i.scores[0] + i.scores[1]) / 2);
  }
  std::printf("racing's test: %lld scans spared, the bound alone %lld\n",
              static_cast<long long>(spared_test), static_cast<long long>(spared_bound));

  // Interrupted in generation 4, saved as slam-tune saves it, read back and resumed.
  offline::TuningState state = offline::NewTuningState(Reduced(8, 0.05), Experiments());
  std::atomic<bool> cancel{false};
  nlohmann::json saved;
  offline::TuningCallbacks callbacks;
  callbacks.cancel = &cancel;
  callbacks.generation_done = [&](const offline::TuningState& s, int64_t) {
    saved = offline::TuningStateToJson(s);
    if (s.budgets[0].generations.size() == 3) cancel = true;
  };
  EXPECT_FALSE(offline::RunTuning(Experiments(), state, 2, callbacks));
  auto reread = offline::TuningStateFromJson(nlohmann::json::parse(saved.dump()));
  ASSERT_TRUE(reread.ok()) << reread.Message();
  offline::TuningState resumed = std::move(reread).value();
  ASSERT_EQ(resumed.budgets[0].generations.size(), 3u);
  ASSERT_TRUE(offline::RunTuning(Experiments(), resumed, 1));
  ExpectSameStudy(resumed, tested);
}

/// Processes simulated by threads: each runs the same study, owns every third new individual,
/// and sums its results with the others' at each generation's end.
class ThreadSpread final : public offline::EvaluationSpread {
 public:
  struct Shared {
    explicit Shared(int n) : size(n), sync(n) {}
    int size;
    std::barrier<> sync;
    std::mutex mutex;
    std::vector<double> sum;
  };
  ThreadSpread(Shared& shared, int rank) : shared_(shared), rank_(rank) {}
  int size() const override { return shared_.size; }
  bool Mine(size_t item) const override {
    return static_cast<int>(item % static_cast<size_t>(shared_.size)) == rank_;
  }
  void SumAll(std::vector<double>& values) const override {
    {
      std::lock_guard<std::mutex> lock(shared_.mutex);
      if (shared_.sum.empty()) shared_.sum.assign(values.size(), 0.0);
      for (size_t i = 0; i < values.size(); ++i) shared_.sum[i] += values[i];
    }
    shared_.sync.arrive_and_wait();  // every part added
    values = shared_.sum;
    shared_.sync.arrive_and_wait();  // every copy taken
    if (rank_ == 0) shared_.sum.clear();
    shared_.sync.arrive_and_wait();  // cleared before the next generation's
  }

 private:
  Shared& shared_;
  int rank_;
};

TEST_F(TunerTest, SpreadOverProcessesGivesTheOneProcessStudy) {
  // As under MPI, each process evaluating its own share: the same study as one process, racing's
  // test included, and each records how many processes ran it.
  offline::TuningState one = offline::NewTuningState(Reduced(5, 0.05), Experiments());
  ASSERT_TRUE(offline::RunTuning(Experiments(), one, 1));
  constexpr int kProcesses = 3;
  ThreadSpread::Shared shared(kProcesses);
  std::vector<offline::TuningState> states(
      kProcesses, offline::NewTuningState(Reduced(5, 0.05), Experiments()));
  std::vector<int> finished(kProcesses, 0);
  std::vector<std::thread> processes;
  for (int r = 0; r < kProcesses; ++r) {
    processes.emplace_back([&, r] {
      const ThreadSpread spread(shared, r);
      offline::TuningCallbacks callbacks;
      callbacks.spread = &spread;
      finished[static_cast<size_t>(r)] =
          offline::RunTuning(Experiments(), states[static_cast<size_t>(r)], 1, callbacks) ? 1 : 0;
    });
  }
  for (std::thread& t : processes) t.join();
  EXPECT_EQ(one.ranks, 1);
  for (int r = 0; r < kProcesses; ++r) {
    EXPECT_EQ(finished[static_cast<size_t>(r)], 1);
    offline::TuningState state = states[static_cast<size_t>(r)];
    EXPECT_EQ(state.ranks, kProcesses);
    state.ranks = 1;
    ExpectSameStudy(state, one);
  }
  int64_t spared = 0;
  for (const auto& g : one.budgets[0].generations) spared += g.replays_saved;
  EXPECT_GT(spared, 0);  // racing ran, spread over the processes
}

TEST_F(TunerTest, InterruptedRunKeepsFinishedGenerationsAndResumesExactly) {
  offline::TuningState state = offline::NewTuningState(Reduced(8), Experiments());
  std::atomic<bool> cancel{false};
  int saved = 0, calls = 0;
  offline::TuningCallbacks callbacks;
  callbacks.cancel = &cancel;
  callbacks.generation_done = [&](const offline::TuningState&, int64_t budget) {
    EXPECT_EQ(budget, 4000);
    ++saved;
  };
  double last_done = 0.0;
  int64_t last_replays = 0;
  callbacks.progress = [&](const offline::TuningProgress& p) {
    EXPECT_GT(p.done, last_done);
    EXPECT_LE(p.done, p.total * (1 + 1e-12));
    EXPECT_EQ(p.budget, 4000);
    EXPECT_EQ(p.replays, last_replays + 1);  // one call per replay
    last_done = p.done;
    last_replays = p.replays;
    // Stop in the middle of generation 3 (the fourth), after 5 of its replays.
    if (p.generation == 3 && ++calls == 5) cancel = true;
  };
  EXPECT_FALSE(offline::RunTuning(Experiments(), state, 2, callbacks));
  EXPECT_EQ(saved, 3);
  EXPECT_EQ(state.budgets[0].generations.size(), 3u);
  cancel = false;
  ASSERT_TRUE(offline::RunTuning(Experiments(), state, 1));
  ExpectSameStudy(state, Full());
}

TEST_F(TunerTest, BudgetsSideBySideGiveTheBudgetByBudgetStudy) {
  // Two threads run the budgets side by side; one thread runs them one after the other. The
  // same study, and the callbacks are never called at once.
  offline::TuningSettings settings = Reduced(3, 0.05);
  settings.budgets = {2000, 4000};
  settings.evolution.population = 8;
  offline::TuningState side = offline::NewTuningState(settings, Experiments());
  std::atomic<int> inside{0};
  std::map<int64_t, int> saved;
  std::set<int64_t> seen;
  double last_done = 0.0;
  offline::TuningCallbacks callbacks;
  callbacks.generation_done = [&](const offline::TuningState& s, int64_t budget) {
    EXPECT_EQ(inside++, 0);
    ++saved[budget];
    EXPECT_EQ(offline::TuningStateToJson(s)["budgets"].size(), 2u);
    --inside;
  };
  callbacks.progress = [&](const offline::TuningProgress& p) {
    EXPECT_EQ(inside++, 0);
    EXPECT_GT(p.done, last_done);
    EXPECT_LE(p.done, p.total * (1 + 1e-12));
    last_done = p.done;
    seen.insert(p.budget);
    --inside;
  };
  ASSERT_TRUE(offline::RunTuning(Experiments(), side, 2, callbacks));
  EXPECT_EQ(saved, (std::map<int64_t, int>{{2000, 3}, {4000, 3}}));
  EXPECT_EQ(seen, (std::set<int64_t>{2000, 4000}));
  offline::TuningState one = offline::NewTuningState(settings, Experiments());
  ASSERT_TRUE(offline::RunTuning(Experiments(), one, 1));
  ExpectSameStudy(side, one);
  EXPECT_GT(side.budgets[0].generations[1].scans_saved + side.budgets[1].generations[1].scans_saved,
            0);  // raced
}

TEST_F(TunerTest, TablesAndFilesReadBack) {
  offline::TuningState state = Full();
  // A second budget from the same run, shifted, so that Table III has a pair.
  offline::BudgetRun other = state.budgets[0];
  other.budget = 8125;
  for (double& f : other.generations.back().fitness_values) f += 0.5;
  state.settings.budgets.push_back(8125);
  state.budgets.push_back(other);

  const std::string table2 = offline::Table2Markdown(state);
  for (const offline::ParameterSpec& spec : offline::TunedParameters()) {
    EXPECT_NE(table2.find("| `" + std::string(spec.key) + "` |"), std::string::npos) << spec.key;
  }
  EXPECT_NE(table2.find("| parameter | default | 4000 | 8125 |"), std::string::npos);
  const std::string table3 = offline::Table3Markdown(state);
  const offline::MannWhitneyResult expected = offline::MannWhitneyU(
      state.budgets[0].generations.back().fitness_values, other.generations.back().fitness_values);
  char p[32];
  std::snprintf(p, sizeof(p), expected.p_value < 1e-4 ? "%.1e" : "%.4f", expected.p_value);
  EXPECT_NE(table3.find("| 4000 | " + std::string(p) + " |"), std::string::npos) << table3;
  EXPECT_LT(expected.p_value, 0.01);  // shifted by far more than the spread

  const testing::TempDir dir("tuning_outputs");
  ASSERT_TRUE(offline::WriteTuningOutputs(dir.path().string(), state).empty());
  for (const char* name : {"results.json", "table2.md", "table3.md", "fig10.svg", "fig10.png",
                           "params/4000.json", "params/8125.json"}) {
    EXPECT_TRUE(fs::exists(dir.path() / name)) << name;
  }
  const auto best = io::LoadParams((dir.path() / "params/4000.json").string());
  ASSERT_TRUE(best.ok()) << best.Message();
  EXPECT_EQ(best.value(), state.budgets[0].generations.back().best.params);
  std::ifstream in(dir.path() / "results.json");
  std::stringstream text;
  text << in.rdbuf();
  const nlohmann::json results = nlohmann::json::parse(text.str());
  EXPECT_EQ(results["budgets"][0]["last_generation"]["fitness"].size(), 12u);
  EXPECT_EQ(results["budgets"][0]["generations"].size(), 8u);
  EXPECT_TRUE(results["budgets"][0]["generations"][7].contains("median"));
  auto reread = offline::TuningStateFromJson(results);
  ASSERT_TRUE(reread.ok()) << reread.Message();
  ExpectSameStudy(reread.value(), state);
}

TEST(TuningReport, DamagedResultsAreRejectedWithTheReason) {
  offline::TuningState state;
  state.settings.budgets = {8125};
  state.budgets.push_back(offline::BudgetRun{8125, {}, {}});
  const nlohmann::json good = offline::TuningStateToJson(state);
  ASSERT_TRUE(offline::TuningStateFromJson(good).ok());
  nlohmann::json bad = good;
  bad["format"] = "something else";
  EXPECT_NE(offline::TuningStateFromJson(bad).Message().find("not a slam-tune result"),
            std::string::npos);
  bad = good;
  bad["settings"].erase("seed");
  EXPECT_NE(offline::TuningStateFromJson(bad).Message().find("not a complete slam-tune result"),
            std::string::npos);
  bad = good;
  bad["settings"]["start"]["particles"] = 0;
  EXPECT_NE(offline::TuningStateFromJson(bad).Message().find("particles"), std::string::npos);
  bad = good;
  bad["budgets"][0]["budget"] = 16250;
  EXPECT_FALSE(offline::TuningStateFromJson(bad).ok());
  bad = good;
  bad["budgets"] = nlohmann::json::array();
  EXPECT_FALSE(offline::TuningStateFromJson(bad).ok());
  EXPECT_FALSE(offline::TuningStateFromJson(nlohmann::json::array()).ok());

  // Resuming with other settings names each difference; more generations are allowed.
  offline::TuningSettings asked = state.settings;
  asked.evolution.generations = 100;
  EXPECT_TRUE(offline::ResumeConflicts(state, asked, {}).empty());
  asked.evolution.seed = 9;
  asked.budgets = {8125, 65000};
  const auto conflicts = offline::ResumeConflicts(state, asked, {"other"});
  ASSERT_EQ(conflicts.size(), 3u);
  EXPECT_EQ(conflicts[0].rfind("budgets:", 0), 0u);
  EXPECT_EQ(conflicts[1].rfind("seed:", 0), 0u);
  EXPECT_EQ(conflicts[2].rfind("experiments:", 0), 0u);
}

/// Runs a shell command; returns its exit status and its standard error.
std::pair<int, std::string> Shell(const std::string& command) {
  const std::string err =
      (fs::path(::testing::TempDir()) / ("slam_tune_stderr_" + std::to_string(::getpid())))
          .string();
  const int status = std::system((command + " 2>" + err + " >/dev/null").c_str());
  std::ifstream in(err);
  std::stringstream text;
  text << in.rdbuf();
  fs::remove(err);
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, text.str()};
}

TEST_F(TunerTest, CommandLineRunsResumesAndRefusesOtherSettings) {
  const std::string bin = SLAM_TUNE_BIN;
  EXPECT_EQ(Shell(bin + " --help").first, 0);
  const testing::TempDir dir("tune_cli");
  const std::string exp = (root_ / "exp" / "rooms").string();
  const std::string out = (dir.path() / "out").string();
  const std::string base =
      bin + " --experiments " + exp + " --budgets 2000 --population 4 --quiet --out " + out;
  auto [status, err] = Shell(base + " --generations 1");
  ASSERT_EQ(status, 0) << err;
  EXPECT_TRUE(fs::exists(fs::path(out) / "fig10.png"));
  // Extending resumes: generation 0 is kept.
  const std::string before = [&] {
    std::ifstream in(fs::path(out) / "results.json");
    return nlohmann::json::parse(in)["budgets"][0]["generations"][0].dump();
  }();
  std::tie(status, err) = Shell(base + " --generations 2");
  ASSERT_EQ(status, 0) << err;
  std::ifstream in(fs::path(out) / "results.json");
  const nlohmann::json results = nlohmann::json::parse(in);
  EXPECT_EQ(results["budgets"][0]["generations"].size(), 2u);
  EXPECT_EQ(results["budgets"][0]["generations"][0].dump(), before);
  // Another seed in the same directory is refused, with the difference named.
  std::tie(status, err) = Shell(base + " --generations 2 --seed 9");
  EXPECT_EQ(status, 2);
  EXPECT_NE(err.find("seed: saved 1, asked 9"), std::string::npos) << err;
  // A damaged results.json is an error, not a crash or a silent restart.
  {
    std::ofstream(fs::path(out) / "results.json")
        << "{\"format\": \"slam-tune results 1\", \"settings\": ";
  }
  std::tie(status, err) = Shell(base + " --generations 2");
  EXPECT_EQ(status, 1);
  EXPECT_NE(err.find("results.json"), std::string::npos) << err;
  EXPECT_NE(err.find("--restart"), std::string::npos) << err;
  // No ground truth: refused before any work.
  const fs::path no_gt = dir.path() / "no_gt";
  fs::copy(exp, no_gt);
  fs::remove(no_gt / "groundtruth.tum");
  std::tie(status, err) =
      Shell(bin + " --experiments " + no_gt.string() + " --out " + out + "2 --quiet");
  EXPECT_EQ(status, 1);
  EXPECT_NE(err.find("groundtruth.tum"), std::string::npos) << err;
}

}  // namespace
}  // namespace slam
