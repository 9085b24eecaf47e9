// slam-tune: the offline parameter tuner (docs/design.md sections 4 and 6). For every ray budget on
// its own, the paper's evolution strategy searches the parameters minimising the mean of e = log(1
// - q) over recorded experiments. Writes results.json, table2.md, table3.md, fig10.svg, fig10.png
// and params/<budget>.json after every generation; an interrupted run resumes from its output
// directory.

#include <unistd.h>

#ifdef SLAM_WITH_MPI
#include <mpi.h>
#endif

#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include "engine/io/json_reader.hpp"
#include "engine/io/params_json.hpp"
#include "offline/evaluation.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/tuner.hpp"
#include "offline/tuning_report.hpp"
#include "tools/command_line.hpp"

namespace {

namespace fs = std::filesystem;

std::atomic<bool> g_cancel{false};

extern "C" void OnSignal(int) { g_cancel.store(true); }

// This process's rank among those running the study (MPI), and how many there are: only rank 0
// reports, prints and writes; every rank reads the same inputs and fails the same way.
int g_rank = 0, g_ranks = 1;

int Fail(const std::string& message, int status = 1) {
  if (g_rank == 0) std::cerr << "slam-tune: " << message << "\n";
  return status;
}

/// Whether an MPI launcher (mpirun, srun) started this process: then it is one rank of several.
bool LaunchedByMpi() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK", "PMI_SIZE"}) {
    if (std::getenv(name) != nullptr) return true;
  }
  return false;
}

#ifdef SLAM_WITH_MPI
/// The generation's new individuals dealt round robin over the ranks; results summed over them.
class MpiSpread final : public slam::offline::EvaluationSpread {
 public:
  int size() const override { return g_ranks; }
  bool Mine(size_t item) const override {
    return static_cast<int>(item % static_cast<size_t>(g_ranks)) == g_rank;
  }
  void SumAll(std::vector<double>& values) const override {
    MPI_Allreduce(MPI_IN_PLACE, values.data(), static_cast<int>(values.size()), MPI_DOUBLE, MPI_SUM,
                  MPI_COMM_WORLD);
  }
};
#endif

std::string Duration(double seconds) {
  char text[32];
  const long s = static_cast<long>(seconds + 0.5);
  if (s >= 3600) {
    std::snprintf(text, sizeof(text), "%ldh%02ldm", s / 3600, (s / 60) % 60);
  } else {
    std::snprintf(text, sizeof(text), "%ldm%02lds", s / 60, s % 60);
  }
  return text;
}

/// A progress bar with ETA on stderr: in place on a terminal, every 5 % otherwise.
class ProgressBar {
 public:
  ProgressBar()
      : interactive_(::isatty(STDERR_FILENO) != 0), start_(std::chrono::steady_clock::now()) {}

  void Update(double done, double total, const std::string& status) {
    const auto now = std::chrono::steady_clock::now();
    const double fraction = total > 0.0 ? std::min(1.0, done / total) : 1.0;
    if (interactive_) {
      if (fraction < 1.0 && now - last_ < std::chrono::milliseconds(250)) return;
    } else if (fraction < 1.0 && fraction < next_report_) {
      return;
    }
    next_report_ = std::floor(fraction * 20.0 + 1.0) / 20.0;
    last_ = now;
    const double elapsed = std::chrono::duration<double>(now - start_).count();
    const double eta = fraction > 0.0 ? elapsed * (1.0 - fraction) / fraction : 0.0;
    const int width = 30, filled = static_cast<int>(fraction * width);
    std::fprintf(stderr, "%s[%s%s] %5.1f%%  %s elapsed, ETA %s  %s%s", interactive_ ? "\r" : "",
                 std::string(static_cast<size_t>(filled), '#').c_str(),
                 std::string(static_cast<size_t>(width - filled), '.').c_str(), 100.0 * fraction,
                 Duration(elapsed).c_str(), fraction > 0.0 ? Duration(eta).c_str() : "?",
                 status.c_str(), interactive_ ? "\033[K" : "\n");
    std::fflush(stderr);
  }
  void Line(const std::string& text) {
    std::fprintf(stderr, "%s%s\n", interactive_ ? "\r\033[K" : "", text.c_str());
    std::fflush(stderr);
  }

 private:
  bool interactive_;
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_{};
  double next_report_ = 0.0;
};

/// slam-tune's command line, as parsed.
struct TuneConfig {
  std::vector<std::string> inputs;
  std::string out_dir, start_path;
  slam::offline::TuningSettings settings;
  std::string policy_name = "fixed";
  int jobs = 0;
  bool restart = false, quiet = false, no_racing = false;
};

void AddOptions(CLI::App& app, TuneConfig& c) {
  slam::offline::TuningSettings& settings = c.settings;
  app.add_option("--experiments", c.inputs,
                 "experiment directories with ground truth, or datasets of them")
      ->required();
  app.add_option("--out", c.out_dir, "output directory (created; holds the state to resume from)")
      ->required();
  app.add_option("--budgets", settings.budgets, "rays per scan, each evolved on its own")
      ->delimiter(',')
      ->capture_default_str()
      ->check(CLI::Range(int64_t{1}, int64_t{100'000'000}));
  app.add_option("--population", settings.evolution.population, "individuals per generation")
      ->capture_default_str()
      ->check(CLI::Range(2, 100000));
  app.add_option("--generations", settings.evolution.generations,
                 "generations per budget (a finished study can be extended)")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  app.add_option("--elite", settings.evolution.elite_fraction,
                 "share of the population kept unchanged")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 0.99));
  app.add_option("--seed", settings.evolution.seed, "seed of the mutations and of every replay")
      ->capture_default_str();
  app.add_option("--policy", c.policy_name, "budget policy of the replays: fixed or adaptive")
      ->capture_default_str()
      ->check(CLI::IsMember({"fixed", "adaptive"}));
  app.add_option("--min-rays-per-particle", settings.evolution.min_rays_per_particle,
                 "tune the particle count within [1, budget / N] (0: up to 64); the shipped sets "
                 "use 8125")
      ->capture_default_str()
      ->check(CLI::Range(int64_t{0}, int64_t{100'000'000}));
  app.add_option("--max-particles", settings.max_particles, "adaptive policy: most particles")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  app.add_option("--start", c.start_path,
                 "parameters of the first generation's first individual [Table II defaults]");
  app.add_option(
         "--jobs", c.jobs,
         "evaluations at once, one thread each (0: one per core); results do not depend on it")
      ->capture_default_str()
      ->check(CLI::Range(0, 256));
  app.add_flag("--no-racing", c.no_racing,
               "evaluate every new individual on every experiment to the end (racing stops those "
               "that can no longer enter the elite; it never changes the elites or the best sets)");
  app.add_option("--race-alpha", settings.race_alpha,
                 "racing's statistical test: one-sided level at which an individual trailing "
                 "the elite's worst on the experiments so far is stopped (0: only stop those "
                 "that provably cannot enter the elite)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 0.5));
  app.add_flag("--restart", c.restart, "discard a saved study in --out instead of resuming it");
  app.add_flag("--quiet", c.quiet, "no progress on stderr");
  app.set_version_flag("--version", std::string("slam-tune ") + SLAM_VERSION);
}

/// Completes the settings from the options (policy, racing, budgets sorted and unique, the start
/// set); an exit status when that fails.
std::optional<int> CompleteSettings(TuneConfig& c) {
  slam::offline::TuningSettings& settings = c.settings;
  settings.policy = *slam::ParseBudgetPolicy(c.policy_name);
  settings.racing = !c.no_racing;
  std::sort(settings.budgets.begin(), settings.budgets.end());
  settings.budgets.erase(std::unique(settings.budgets.begin(), settings.budgets.end()),
                         settings.budgets.end());
  if (!c.start_path.empty()) {
    const auto loaded = slam::io::LoadParams(c.start_path);
    if (!loaded.ok()) return Fail(loaded.Message());
    settings.start = loaded.value();
  }
  return std::nullopt;
}

/// The experiments, decoded once and held in memory for every evaluation; each needs its ground
/// truth. An exit status when one cannot be read.
std::optional<int> LoadExperiments(const TuneConfig& c,
                                   std::vector<slam::offline::Experiment>& experiments) {
  const slam::Result<std::vector<std::string>> found = slam::offline::FindExperimentDirs(c.inputs);
  if (!found.ok()) return Fail(found.Message());
  for (const std::string& dir : found.value()) {
    slam::Result<slam::offline::Experiment> load = slam::offline::LoadExperiment(dir);
    if (!load.ok()) return Fail("cannot read " + dir + ":\n" + load.Message());
    if (load.value().ground_truth.empty()) {
      return Fail(dir + ": no groundtruth.tum: the fitness needs the ground-truth trajectory");
    }
    if (!c.quiet) {
      std::fprintf(stderr, "%s: %zu scans, %.0f s\n", load.value().meta.name.c_str(),
                   load.value().scans.size(), load.value().duration_s());
    }
    experiments.push_back(std::move(load).value());
  }
  return std::nullopt;
}

/// A fresh study in --out, or the one saved there when its settings and experiments are these
/// (its generation count, racing and race level taken from the options). An exit status when
/// the saved study cannot be read or differs.
std::optional<int> StartOrResume(const TuneConfig& c,
                                 const std::vector<slam::offline::TuningExperiment>& tuning,
                                 const std::vector<std::string>& names,
                                 slam::offline::TuningState& state) {
  std::error_code ec;
  fs::create_directories(c.out_dir, ec);
  if (ec) return Fail("cannot create " + c.out_dir + ": " + ec.message());
  state = slam::offline::NewTuningState(c.settings, tuning);
  const std::string results_path = (fs::path(c.out_dir) / "results.json").string();
  if (c.restart || !fs::exists(results_path, ec)) return std::nullopt;
  const auto json = slam::io::detail::ReadJsonFile(results_path);
  if (!json.ok())
    return Fail("cannot resume: " + json.Message() + "\n(use --restart to start over)");
  auto saved = slam::offline::TuningStateFromJson(json.value());
  if (!saved.ok()) {
    return Fail("cannot resume from " + results_path + ":\n" + saved.Message() +
                "\n(use --restart to start over)");
  }
  const auto conflicts = slam::offline::ResumeConflicts(saved.value(), c.settings, names);
  if (!conflicts.empty()) {
    std::string text = c.out_dir + " holds a study with other settings:";
    for (const std::string& conflict : conflicts) text += "\n  " + conflict;
    return Fail(text + "\nuse another --out, the same settings, or --restart", 2);
  }
  state = std::move(saved).value();
  state.settings.evolution.generations = c.settings.evolution.generations;
  state.settings.racing = c.settings.racing;
  state.settings.race_alpha = c.settings.race_alpha;
  size_t finished = 0;
  for (const slam::offline::BudgetRun& run : state.budgets) finished += run.generations.size();
  if (!c.quiet)
    std::fprintf(stderr, "resuming %s: %zu generations already done\n", c.out_dir.c_str(),
                 finished);
  return std::nullopt;
}

/// The line that reports a budget's finished generation.
std::string GenerationLine(const slam::offline::TuningState& s, int64_t budget,
                           const slam::offline::GenerationSummary& g) {
  char text[240];
  std::snprintf(text, sizeof(text),
                "budget %lld generation %d/%d: median %.4f, IQR %.4f-%.4f, best %.4f; "
                "%lld replays, %lld saved by racing (%d individuals stopped, %.0f %% of "
                "the scans spared)",
                static_cast<long long>(budget), g.generation + 1, s.settings.evolution.generations,
                g.fitness.median, g.fitness.q1, g.fitness.q3, g.best.fitness,
                static_cast<long long>(g.replays), static_cast<long long>(g.replays_saved),
                g.raced_out,
                g.scans + g.scans_saved > 0 ? 100.0 * static_cast<double>(g.scans_saved) /
                                                  static_cast<double>(g.scans + g.scans_saved)
                                            : 0.0);
  return text;
}

}  // namespace

int Run(int argc, char** argv) {
  CLI::App app{
      "Tunes the SLAM parameters for each ray budget with the paper's evolution strategy "
      "(fitness: mean of e = log(1 - q) over the experiments, lower is better). Writes "
      "results.json, table2.md, table3.md, fig10.svg, fig10.png and params/<budget>.json into "
      "--out after every generation; run the same command again to resume an interrupted study."};
  TuneConfig config;
  AddOptions(app, config);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (g_rank == 0) return slam::cli::ReportParseError(app, e);
    return e.get_exit_code();
  }
  config.quiet = config.quiet || g_rank != 0;            // rank 0 alone reports
  if (g_ranks > 1 && config.jobs == 0) config.jobs = 1;  // one rank per core
  const bool quiet = config.quiet;
  const std::string& out_dir = config.out_dir;
  if (const auto status = CompleteSettings(config)) return *status;

  std::vector<slam::offline::Experiment> experiments;
  if (const auto status = LoadExperiments(config, experiments)) return *status;
  std::vector<slam::offline::TuningExperiment> tuning;
  std::vector<std::string> names;
  for (const slam::offline::Experiment& e : experiments) {
    tuning.push_back({e.meta.name, &e.robot, &e.scans, &e.ground_truth});
    names.push_back(e.meta.name);
  }
  slam::offline::TuningState state;
  if (const auto status = StartOrResume(config, tuning, names, state)) return *status;

  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  ProgressBar bar;
  std::string status;
  slam::offline::TuningCallbacks callbacks;
  callbacks.cancel = &g_cancel;
  bool write_failed = false;
#ifdef SLAM_WITH_MPI
  const MpiSpread spread;
  if (g_ranks > 1) callbacks.spread = &spread;
#endif
  callbacks.generation_done = [&](const slam::offline::TuningState& s, int64_t budget) {
    if (g_rank != 0) return;  // rank 0 writes
    for (const std::string& e : slam::offline::WriteTuningOutputs(out_dir, s)) {
      std::cerr << "slam-tune: " << e << "\n";
      write_failed = true;
    }
    for (const slam::offline::BudgetRun& run : s.budgets) {
      if (run.budget != budget || run.generations.empty()) continue;
      const slam::offline::GenerationSummary& g = run.generations.back();
      status = "budget " + std::to_string(budget) + ", best " +
               std::to_string(g.best.fitness).substr(0, 6);
      if (!quiet) bar.Line(GenerationLine(s, budget, g));
    }
  };
  if (!quiet)
    callbacks.progress = [&](const slam::offline::TuningProgress& p) {
      char line[160];
      std::snprintf(line, sizeof(line), "budget %lld gen %d/%d, %lld replays done, %lld saved%s%s",
                    static_cast<long long>(p.budget), p.generation + 1,
                    state.settings.evolution.generations, static_cast<long long>(p.replays),
                    static_cast<long long>(p.replays_saved), status.empty() ? "" : "; ",
                    status.c_str());
      bar.Update(p.done, p.total, line);
    };

  const auto start = std::chrono::steady_clock::now();
  const bool finished = slam::offline::RunTuning(tuning, state, config.jobs, callbacks);
  if (g_rank == 0) {
    for (const std::string& e : slam::offline::WriteTuningOutputs(out_dir, state)) {
      std::cerr << "slam-tune: " << e << "\n";
      write_failed = true;
    }
  }
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!finished) {
    return Fail("interrupted after " + Duration(wall) + "; finished generations are saved in " +
                    out_dir + ": run the same command again to resume",
                130);
  }
  if (g_rank != 0) return 0;
  std::cout << slam::offline::Table2Markdown(state) << "\n" << slam::offline::Table3Markdown(state);
  std::fprintf(stderr, "slam-tune: done in %s (%.0f s) with %d process%s; results in %s\n",
               Duration(wall).c_str(), wall, g_ranks, g_ranks == 1 ? "" : "es", out_dir.c_str());
  return write_failed ? 1 : 0;
}

int main(int argc, char** argv) {
  if (!LaunchedByMpi()) return Run(argc, argv);
#ifdef SLAM_WITH_MPI
  // Only the main thread calls MPI (between generations); oneTBB's workers never do.
  int provided = 0;
  if (MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided) != MPI_SUCCESS) {
    std::cerr << "slam-tune: MPI_Init_thread failed\n";
    return 1;
  }
  MPI_Comm_rank(MPI_COMM_WORLD, &g_rank);
  MPI_Comm_size(MPI_COMM_WORLD, &g_ranks);
  const int status = Run(argc, argv);
  // Every rank reads the same inputs, so all fail or succeed alike (an unreadable file on one
  // machine only would leave the others waiting in the study); each exits with the worst status.
  int worst = status;
  MPI_Allreduce(&status, &worst, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
  MPI_Finalize();
  return worst;
#else
  const char* size = std::getenv("OMPI_COMM_WORLD_SIZE");
  if (size != nullptr && std::string(size) != "1") {
    std::cerr << "slam-tune: started by an MPI launcher, but built without MPI: every process "
                 "would run the whole study and write the same files. Install libopenmpi-dev "
                 "(scripts/deps) and rebuild, or run slam-tune without mpirun.\n";
    return 1;
  }
  return Run(argc, argv);
#endif
}
