#pragma once
// Tuning jobs of slamd (POST /api/v1/jobs/tune): the evolution strategy of slam-tune for one
// budget, over recorded experiments with ground truth from --experiments, on one thread at idle
// scheduling priority so that the real-time SLAM always runs first. One job at a time.

#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "engine/config_error.hpp"
#include "engine/result.hpp"
#include "engine/thread_safety.hpp"
#include "offline/tuner.hpp"
#include "scheduler/ray_budget_scheduler.hpp"

namespace slam::server {

struct TuneRequest {
  int64_t budget = 8125;
  BudgetPolicy policy = BudgetPolicy::kFixed;
  int population = 12;
  int generations = 8;
  uint64_t seed = 1;
  std::vector<std::string> experiments;  // names under the experiments folder; empty = all
};

/// Reads a job request (every key optional); errors carry JSON pointers. `available` are the
/// experiment names that exist.
Result<TuneRequest> ParseTuneRequest(const nlohmann::json& body,
                                     const std::vector<std::string>& available);

class JobManager {
 public:
  /// `experiments_dir`: where experiments are (empty: none, jobs are refused); `output_dir`:
  /// where each job's results go (<output_dir>/jobs/<id>/), empty for none.
  JobManager(std::string experiments_dir, std::string output_dir);
  ~JobManager();  // cancels and joins a running job
  JobManager(const JobManager&) = delete;
  JobManager& operator=(const JobManager&) = delete;

  /// Experiment names available (subfolders of the experiments folder holding a can.log).
  std::vector<std::string> Experiments() const;
  bool configured() const { return !experiments_dir_.empty(); }

  /// Finished jobs (done, cancelled, failed) kept for GET; starting a job forgets the oldest
  /// beyond this, so that a client starting job after job cannot grow slamd's memory.
  static constexpr size_t kKeptFinishedJobs = 16;

  /// Starts a job and returns its JSON; an error (a conflict) when one is already running.
  Result<nlohmann::json> Start(const TuneRequest& request);
  /// The job's JSON, if it exists.
  std::optional<nlohmann::json> Get(const std::string& id) const;
  /// Cancels a running job (returns 202) or forgets a finished one (200); 404 if unknown.
  int Delete(const std::string& id);
  /// Every job kept, oldest first.
  nlohmann::json List() const;
  /// Increases whenever any job changes (for the event stream).
  uint64_t revision() const { return revision_.load(); }
  /// The most recently started job, if any.
  std::optional<nlohmann::json> Latest() const;
  int running() const;

 private:
  struct Job {
    std::string id;
    TuneRequest request;
    std::string state = "running";  // running, done, cancelled, failed
    std::string error;
    std::vector<std::string> experiments;
    double progress = 0.0;
    int64_t evaluations_done = 0;
    std::vector<offline::GenerationSummary> generations;
    std::atomic<bool> cancel{false};
    std::thread thread;
  };

  /// Orders ids (decimal numbers without leading zeros) as numbers: oldest job first.
  struct ByNumber {
    bool operator()(const std::string& a, const std::string& b) const {
      return a.size() != b.size() ? a.size() < b.size() : a < b;
    }
  };

  void Run(Job& job);
  nlohmann::json ToJson(const Job& job) const SLAM_REQUIRES(mutex_);
  void Touch() { revision_.fetch_add(1); }

  std::string experiments_dir_;
  std::string output_dir_;
  mutable Mutex mutex_;
  std::map<std::string, std::unique_ptr<Job>, ByNumber> jobs_ SLAM_GUARDED_BY(mutex_);
  uint64_t next_id_ SLAM_GUARDED_BY(mutex_) = 1;
  std::string latest_ SLAM_GUARDED_BY(mutex_);
  std::atomic<uint64_t> revision_{0};
};

}  // namespace slam::server
