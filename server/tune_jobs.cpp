#include "server/tune_jobs.hpp"

#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <utility>

#include "engine/io/atomic_file.hpp"
#include "engine/io/params_json.hpp"
#include "engine/thread_safety.hpp"
#include "offline/evaluation.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/tuning_report.hpp"
#include "scheduler/ray_budget_scheduler.hpp"

namespace slam::server {
namespace {

namespace fs = std::filesystem;

// Bounds of a job request: a job on the robot is a small study (the full one is slam-tune's).
constexpr int kMaxPopulation = 200;
constexpr int kMaxGenerations = 200;

/// Makes `<output_dir>/jobs/<id>/` and its `params/` for a job's outputs: the output folder (the
/// state directory, which may be a link the operator made) is created if missing; what is
/// created or entered below it must be a real directory, never a link planted there to have the
/// outputs written elsewhere. An error (naming the folder) or "".
std::string MakeJobDirs(const fs::path& output_dir, const std::string& id) {
  std::error_code ec;
  fs::create_directories(output_dir, ec);
  if (ec) return "cannot create " + output_dir.string() + ": " + ec.message();
  for (const fs::path& dir :
       {output_dir / "jobs", output_dir / "jobs" / id, output_dir / "jobs" / id / "params"}) {
    if (const Result<void> made = io::MakeRealDirectory(dir.string()); !made.ok()) {
      return made.Message();
    }
  }
  return "";
}

/// Lowest CPU priority for the calling thread: SCHED_IDLE runs only when a core would otherwise
/// idle, so the SLAM thread and the HTTP threads always come first. Falls back to nice 19.
void LowerThisThreadPriority() {
  sched_param param{};
  param.sched_priority = 0;
  if (pthread_setschedparam(pthread_self(), SCHED_IDLE, &param) != 0) {
    setpriority(PRIO_PROCESS, static_cast<id_t>(gettid()), 19);
  }
}

template <typename T>
bool ReadInt(const nlohmann::json& body, const char* key, T lo, T hi, T& out,
             ConfigErrors& errors) {
  const auto it = body.find(key);
  if (it == body.end() || it->is_null()) return true;
  const std::string pointer = std::string("/") + key;
  if (!it->is_number_integer() && !it->is_number_unsigned()) {
    errors.push_back({pointer, "must be an integer", 0});
    return false;
  }
  const auto value = it->get<int64_t>();
  if (value < static_cast<int64_t>(lo) || value > static_cast<int64_t>(hi)) {
    errors.push_back(
        {pointer, "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]", 0});
    return false;
  }
  out = static_cast<T>(value);
  return true;
}

}  // namespace

Result<TuneRequest> ParseTuneRequest(const nlohmann::json& body,
                                     const std::vector<std::string>& available) {
  TuneRequest request;
  ConfigErrors errors;
  if (!body.is_object()) {
    errors.push_back({"", "must be a JSON object", 0});
    return errors;
  }
  static const std::vector<std::string> kKeys{"budget",      "policy", "population",
                                              "generations", "seed",   "experiments"};
  for (const auto& [key, value] : body.items()) {
    if (std::find(kKeys.begin(), kKeys.end(), key) == kKeys.end()) {
      errors.push_back({"/" + key, "unknown field", 0});
    }
  }
  ReadInt<int64_t>(body, "budget", 1, kMaxRaysPerScan, request.budget, errors);
  ReadInt<int>(body, "population", 2, kMaxPopulation, request.population, errors);
  ReadInt<int>(body, "generations", 1, kMaxGenerations, request.generations, errors);
  ReadInt<uint64_t>(body, "seed", 0, uint64_t{1} << 53, request.seed, errors);
  if (const auto it = body.find("policy"); it != body.end() && !it->is_null()) {
    const auto policy = it->is_string() ? ParseBudgetPolicy(it->get<std::string>()) : std::nullopt;
    if (!policy) {
      errors.push_back({"/policy", "must be \"fixed\" or \"adaptive\"", 0});
    } else {
      request.policy = *policy;
    }
  }
  if (const auto it = body.find("experiments"); it != body.end() && !it->is_null()) {
    if (!it->is_array()) {
      errors.push_back({"/experiments", "must be an array of experiment names", 0});
    } else {
      request.experiments.clear();
      for (size_t i = 0; i < it->size(); ++i) {
        const auto& name = (*it)[i];
        const std::string pointer = "/experiments/" + std::to_string(i);
        if (!name.is_string()) {
          errors.push_back({pointer, "must be a string", 0});
        } else if (std::find(available.begin(), available.end(), name.get<std::string>()) ==
                   available.end()) {
          errors.push_back({pointer, "no experiment named \"" + name.get<std::string>() + "\"", 0});
        } else if (std::find(request.experiments.begin(), request.experiments.end(),
                             name.get<std::string>()) != request.experiments.end()) {
          // Each name would be loaded again: thousands of copies fit in a body.
          errors.push_back({pointer, "\"" + name.get<std::string>() + "\" is named twice", 0});
        } else {
          request.experiments.push_back(name.get<std::string>());
        }
      }
      if (it->empty()) errors.push_back({"/experiments", "must name at least one experiment", 0});
    }
  }
  if (!errors.empty()) return errors;
  return request;
}

JobManager::JobManager(std::string experiments_dir, std::string output_dir)
    : experiments_dir_(std::move(experiments_dir)), output_dir_(std::move(output_dir)) {
  // Ids go on from the results an earlier run left in <output>/jobs/<id>/: a new job 1 would
  // write over the old job 1's.
  // symlink_status: a link planted in place of jobs/ is not read (jobs then refuse to use it).
  std::error_code error;
  if (output_dir_.empty() ||
      !fs::is_directory(fs::symlink_status(fs::path(output_dir_) / "jobs", error))) {
    return;
  }
  try {
    for (const auto& entry : fs::directory_iterator(fs::path(output_dir_) / "jobs", error)) {
      const std::string name = entry.path().filename().string();
      if (name.empty() || name.size() > 18 ||
          !std::all_of(name.begin(), name.end(), [](char c) { return c >= '0' && c <= '9'; })) {
        continue;
      }
      next_id_ = std::max<uint64_t>(next_id_, std::stoull(name) + 1);
    }
  } catch (const fs::filesystem_error&) {
    // An unreadable folder: ids start from those found so far.
  }
}

JobManager::~JobManager() {
  decltype(jobs_) jobs;
  {
    MutexLock lock(mutex_);
    jobs.swap(jobs_);
  }
  for (auto& [id, job] : jobs) {
    job->cancel = true;
    if (job->thread.joinable()) job->thread.join();
  }
}

std::vector<std::string> JobManager::Experiments() const {
  std::vector<std::string> names;
  if (experiments_dir_.empty()) return names;
  const Result<std::vector<std::string>> dirs = offline::FindExperimentDirs({experiments_dir_});
  if (!dirs.ok()) return names;
  for (const std::string& dir : dirs.value()) {
    names.push_back(fs::path(dir).filename().string());
  }
  return names;
}

int JobManager::running() const {
  MutexLock lock(mutex_);
  return static_cast<int>(std::count_if(
      jobs_.begin(), jobs_.end(), [](const auto& j) { return j.second->state == "running"; }));
}

Result<nlohmann::json> JobManager::Start(const TuneRequest& request) {
  std::vector<std::string> names =
      request.experiments.empty() ? Experiments() : request.experiments;
  // Threads of finished jobs are joined (and forgotten jobs freed) after the lock is released:
  // a finishing job's thread may still be on its way out.
  std::vector<std::thread> finished_threads;
  std::vector<std::unique_ptr<Job>> forgotten;
  nlohmann::json started;
  {
    MutexLock lock(mutex_);
    for (const auto& [id, job] : jobs_) {
      if (job->state == "running") {
        return Error("job " + id + " is running; cancel it (DELETE /api/v1/jobs/" + id +
                     ") or wait");
      }
    }
    if (names.empty()) {
      return Error("no experiments with ground truth under " + experiments_dir_);
    }
    // No job is running: every kept job is finished. Keep the newest kKeptFinishedJobs - 1 and
    // the one being started.
    while (jobs_.size() >= kKeptFinishedJobs) {
      forgotten.push_back(std::move(jobs_.begin()->second));
      jobs_.erase(jobs_.begin());
    }
    for (auto& [id, job] : jobs_) {
      if (job->thread.joinable()) finished_threads.push_back(std::move(job->thread));
    }
    auto job = std::make_unique<Job>();
    job->id = std::to_string(next_id_++);
    job->request = request;
    job->experiments = std::move(names);
    Job& ref = *job;
    latest_ = job->id;
    jobs_[job->id] = std::move(job);
    ref.thread = std::thread([this, &ref] {
      pthread_setname_np(pthread_self(), "tune-job");
      LowerThisThreadPriority();
      Run(ref);
    });
    started = ToJson(ref);
  }
  for (std::thread& thread : finished_threads) thread.join();
  for (auto& job : forgotten) {
    if (job->thread.joinable()) job->thread.join();
  }
  Touch();
  return started;
}

void JobManager::Run(Job& job) {
  // Load the experiments (on this idle-priority thread: it can take seconds).
  std::vector<offline::Experiment> loaded;
  std::string error;
  for (const std::string& name : job.experiments) {
    if (job.cancel) break;
    Result<offline::Experiment> load =
        offline::LoadExperiment((fs::path(experiments_dir_) / name).string());
    if (!load.ok()) {
      error = load.Message();
      break;
    }
    if (load.value().ground_truth.empty()) {
      error = name + ": no ground truth (groundtruth.tum): it cannot be used for tuning";
      break;
    }
    loaded.push_back(std::move(load).value());
  }
  std::vector<offline::TuningExperiment> experiments;
  for (const offline::Experiment& e : loaded) {
    experiments.push_back(
        {fs::path(e.dir).filename().string(), &e.robot, &e.scans, &e.ground_truth});
  }

  const std::string out_dir =
      output_dir_.empty() ? std::string() : (fs::path(output_dir_) / "jobs" / job.id).string();
  if (error.empty() && !out_dir.empty()) error = MakeJobDirs(output_dir_, job.id);

  bool finished = false;
  if (error.empty() && !job.cancel) {
    offline::TuningSettings settings;
    settings.budgets = {job.request.budget};
    settings.evolution.population = job.request.population;
    settings.evolution.generations = job.request.generations;
    settings.evolution.seed = job.request.seed;
    settings.policy = job.request.policy;
    offline::TuningState state = offline::NewTuningState(settings, experiments);
    offline::TuningCallbacks callbacks;
    callbacks.cancel = &job.cancel;
    callbacks.progress = [&](const offline::TuningProgress& p) {
      {
        MutexLock lock(mutex_);
        job.progress = p.total > 0.0 ? p.done / p.total : 0.0;
      }
      Touch();
    };
    callbacks.generation_done = [&](const offline::TuningState& s, int64_t) {
      {
        MutexLock lock(mutex_);
        job.generations = s.budgets.front().generations;
        job.evaluations_done = 0;
        for (const auto& g : job.generations) job.evaluations_done += g.evaluations;
      }
      if (!out_dir.empty()) {
        // Checked again before each write: the folders may have been replaced meanwhile.
        if (const std::string refused = MakeJobDirs(output_dir_, job.id); !refused.empty()) {
          error += refused + "\n";
        } else {
          for (const std::string& e : offline::WriteTuningOutputs(out_dir, s)) error += e + "\n";
        }
      }
      Touch();
    };
    finished = offline::RunTuning(experiments, state, 1, callbacks);
  }
  {
    MutexLock lock(mutex_);
    if (!error.empty()) {
      job.state = "failed";
      job.error = error;
    } else {
      job.state = finished ? "done" : "cancelled";
      if (finished) job.progress = 1.0;
    }
  }
  Touch();
}

nlohmann::json JobManager::ToJson(const Job& job) const {
  const TuneRequest& r = job.request;
  offline::EvolutionConfig evolution;
  evolution.population = r.population;
  const int64_t total =
      r.population + int64_t{r.generations - 1} * (r.population - evolution.elites());
  nlohmann::json j = {{"id", job.id},
                      {"state", job.state},
                      {"budget", r.budget},
                      {"policy", ToString(r.policy)},
                      {"population", r.population},
                      {"generations", r.generations},
                      {"seed", r.seed},
                      {"generation", static_cast<int>(job.generations.size())},
                      {"evaluations_done", job.evaluations_done},
                      {"evaluations_total", total},
                      {"progress", job.progress},
                      {"experiments", job.experiments},
                      {"error", job.error}};
  nlohmann::json history = nlohmann::json::array();
  for (const offline::GenerationSummary& g : job.generations) {
    history.push_back({{"generation", g.generation + 1},  // 1..N, as the console and table3.md
                       {"min", g.fitness.min},
                       {"q1", g.fitness.q1},
                       {"median", g.fitness.median},
                       {"q3", g.fitness.q3},
                       {"max", g.fitness.max}});
  }
  j["history"] = std::move(history);
  if (!job.generations.empty()) {
    const offline::Individual& best = job.generations.back().best;
    j["best"] = {{"fitness", best.fitness}, {"params", io::ParamsToJson(best.params)}};
  } else {
    j["best"] = nullptr;
  }
  return j;
}

std::optional<nlohmann::json> JobManager::Get(const std::string& id) const {
  MutexLock lock(mutex_);
  const auto it = jobs_.find(id);
  if (it == jobs_.end()) return std::nullopt;
  return ToJson(*it->second);
}

int JobManager::Delete(const std::string& id) {
  std::unique_ptr<Job> finished;
  {
    MutexLock lock(mutex_);
    const auto it = jobs_.find(id);
    if (it == jobs_.end()) return 404;
    if (it->second->state == "running") {
      it->second->cancel = true;
      return 202;
    }
    finished = std::move(it->second);
    jobs_.erase(it);
    if (latest_ == id) latest_.clear();
  }
  if (finished->thread.joinable()) finished->thread.join();
  Touch();
  return 200;
}

nlohmann::json JobManager::List() const {
  MutexLock lock(mutex_);
  nlohmann::json list = nlohmann::json::array();
  for (const auto& [id, job] : jobs_) list.push_back(ToJson(*job));
  return {{"jobs", list}};
}

std::optional<nlohmann::json> JobManager::Latest() const {
  MutexLock lock(mutex_);
  const auto it = jobs_.find(latest_);
  if (it == jobs_.end()) return std::nullopt;
  return ToJson(*it->second);
}

}  // namespace slam::server
