#pragma once
// The online ray-budget scheduler (docs/design.md section 4): before each scan it turns the quota
// (rays per scan, or a share of one core converted through the measured cost per ray) into the
// engine's plan, under the fixed (paper) or adaptive policy; after the scan it records what the
// plan used. Settings may be changed from any thread and apply from the next scan.

#include <cstdint>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

#include "engine/config_error.hpp"
#include "engine/params.hpp"
#include "engine/slam.hpp"
#include "engine/thread_safety.hpp"

namespace slam {

enum class QuotaMode { kRaysPerScan, kCpuShare };
enum class BudgetPolicy { kFixed, kAdaptive };

std::string_view ToString(QuotaMode mode);       // "rays" or "cpu_share"
std::string_view ToString(BudgetPolicy policy);  // "fixed" or "adaptive"
std::optional<QuotaMode> ParseQuotaMode(std::string_view text);
std::optional<BudgetPolicy> ParseBudgetPolicy(std::string_view text);

/// The largest ray budget a scan may be given (slamd, slam-replay, slam-tune): a scan at this
/// budget takes seconds on one core already.
inline constexpr int64_t kMaxRaysPerScan = 100'000'000;
/// The largest particle count the adaptive policy may be allowed.
inline constexpr int kMaxParticlesCap = 1000;

/// What may be spent per scan, and how: changed at run time (REST, command line).
struct BudgetSettings {
  QuotaMode mode = QuotaMode::kRaysPerScan;
  int64_t rays_per_scan = 65000;  // the paper's budgets: 8125, 16250, 32500, 65000
  double cpu_share = 0.25;        // of one core: 0.125, 0.25, 0.5, 1.0 in the paper's spirit
  BudgetPolicy policy = BudgetPolicy::kFixed;
  int max_particles = 16;  // adaptive policy: upper bound on the particle count

  friend bool operator==(const BudgetSettings&, const BudgetSettings&) = default;
};

/// Bounds of the settings; empty when valid. Pointers name the JSON keys ("/rays_per_scan").
ConfigErrors Validate(const BudgetSettings& settings);

/// Constants of the scheduler that are not changed at run time.
struct SchedulerConfig {
  /// Cost per ray assumed before the first measurement (thread CPU time, everything included).
  double initial_ns_per_ray = 300.0;
  /// Weight of the latest scan in the exponentially smoothed cost per ray.
  double cost_smoothing = 0.2;
  /// CPU-share quotas are kept within these bounds.
  int64_t min_quota = 1000;
  int64_t max_quota = 20'000'000;
  /// Scan periods are clamped to this range before converting a CPU share (robot time, s).
  double min_scan_period_s = 0.05;
  double max_scan_period_s = 5.0;
  /// Adaptive policy (see AdaptiveParticles).
  int adaptive_min_candidates = 8;
  double ambiguity_grow = 0.5;
  double ambiguity_shrink = 0.25;
  double ess_shrink = 0.5;
};

/// The filter's state after a scan, as the adaptive policy reads it.
struct FilterState {
  int particles = 1;
  double effective_sample_size = 1.0;
  double refinement_ambiguity = 0.0;  // ScanReport::refinement_ambiguity
  bool refined = false;               // the scan was matched (ambiguity is meaningful)
};

/// The adaptive policy's particle count for the next scan (documented rule, docs/design.md section
/// 4):
/// - the candidates could not tell poses apart (ambiguity >= grow): the belief is spread or
///   multimodal, which only more hypotheses can carry (as KLD-sampling grows the set with the
///   belief's spread), so the count doubles;
/// - the match was sharp (ambiguity < shrink) and the particles agree (effective sample size at
///   least half the count, GMapping's resampling criterion): particles are redundant, one goes
///   and its rays go to candidates;
/// - otherwise the count stays.
/// The result is clamped to [floor, cap], floor being the tuned `particles` parameter and cap the
/// largest count that still leaves every particle `adaptive_min_candidates` candidates.
int AdaptiveParticles(const FilterState& state, int floor, int cap, const SchedulerConfig& config);

/// One scan's plan and what it used.
struct PlanRecord {
  int64_t scan = 0;  // engine scan counter
  QuotaMode mode = QuotaMode::kRaysPerScan;
  BudgetPolicy policy = BudgetPolicy::kFixed;
  int64_t quota = 0;  // rays this scan was allowed
  ScanPlan plan;
  int64_t planned_rays = 0;
  int64_t used_rays = 0;       // as the engine counted them
  bool fills_quota = false;    // the scan offered enough measurements to use the quota
  double cpu_s = 0.0;          // CPU time of the scan, as measured by the caller
  double scan_period_s = 0.0;  // robot time the scan covered
  double ns_per_ray = 0.0;     // smoothed cost per ray after this scan
};

/// Totals since construction, for the metrics.
struct SchedulerTotals {
  int64_t scans = 0;
  int64_t rays_planned = 0;
  int64_t rays_used = 0;
  int64_t quota = 0;
  int64_t over_quota_scans = 0;  // must stay 0: the invariant
  double cpu_s = 0.0;
  double robot_s = 0.0;  // robot time covered by the scans
  std::optional<PlanRecord> last;
};

class RayBudgetScheduler {
 public:
  /// Preconditions: Validate(settings) is empty.
  explicit RayBudgetScheduler(const BudgetSettings& settings, const SchedulerConfig& config = {});

  /// Replaces the settings from the next Plan() on. Thread-safe. Precondition: valid.
  void SetSettings(const BudgetSettings& settings);
  /// The current settings. Thread-safe.
  BudgetSettings settings() const;
  /// Totals and the last record. Thread-safe.
  SchedulerTotals totals() const;
  /// The smoothed cost per ray in nanoseconds. Thread-safe.
  double ns_per_ray() const;

  /// The quota of a scan covering `scan_period_s` of robot time under the current settings: the
  /// one Plan() gives it unless the settings change in between (the parameter set is chosen by
  /// it before planning). Thread-safe.
  int64_t Quota(double scan_period_s) const;

  /// The plan for the next scan (SLAM thread): its summary, the robot time it covers, and the
  /// engine's current parameters. The settings are read once here.
  /// `reserved_rays` of the quota are kept for other work of the scan (the loss detector's
  /// check), the rest planned.
  ScanPlan Plan(const ScanSummary& summary, double scan_period_s, const SlamParams& params,
                int64_t reserved_rays = 0);
  /// Records what the engine did with the planned scan and the CPU time it took (SLAM thread);
  /// updates the cost per ray and the adaptive policy's state. Returns the record.
  PlanRecord Record(const ScanReport& report, double cpu_s);

 private:
  int64_t QuotaFor(const BudgetSettings& settings, double scan_period_s) const;

  const SchedulerConfig config_;
  mutable Mutex mutex_;
  BudgetSettings settings_ SLAM_GUARDED_BY(mutex_);
  double ns_per_ray_ SLAM_GUARDED_BY(mutex_);
  SchedulerTotals totals_ SLAM_GUARDED_BY(mutex_);
  // SLAM thread only.
  PlanRecord pending_;
  ScanSummary pending_summary_;
  std::optional<FilterState> filter_;
  int adaptive_particles_ = 0;  // 0: not started (take the parameter)
};

}  // namespace slam
