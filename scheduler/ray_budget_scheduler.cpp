#include "scheduler/ray_budget_scheduler.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "engine/thread_safety.hpp"
#include "scheduler/fixed_plan.hpp"

namespace slam {

std::string_view ToString(QuotaMode mode) {
  return mode == QuotaMode::kCpuShare ? "cpu_share" : "rays";
}

std::string_view ToString(BudgetPolicy policy) {
  return policy == BudgetPolicy::kAdaptive ? "adaptive" : "fixed";
}

std::optional<QuotaMode> ParseQuotaMode(std::string_view text) {
  if (text == "rays") return QuotaMode::kRaysPerScan;
  if (text == "cpu_share") return QuotaMode::kCpuShare;
  return std::nullopt;
}

std::optional<BudgetPolicy> ParseBudgetPolicy(std::string_view text) {
  if (text == "fixed") return BudgetPolicy::kFixed;
  if (text == "adaptive") return BudgetPolicy::kAdaptive;
  return std::nullopt;
}

ConfigErrors Validate(const BudgetSettings& settings) {
  ConfigErrors errors;
  if (settings.rays_per_scan < 1 || settings.rays_per_scan > kMaxRaysPerScan) {
    errors.push_back({"/rays_per_scan", std::to_string(settings.rays_per_scan) +
                                            " is outside [1, " + std::to_string(kMaxRaysPerScan) +
                                            "]"});
  }
  // Written so that NaN fails too.
  if (!(settings.cpu_share > 0.0 && settings.cpu_share <= 1.0)) {
    std::ostringstream detail;
    detail << settings.cpu_share << " is outside (0, 1]";
    errors.push_back({"/cpu_share", detail.str()});
  }
  if (settings.max_particles < 1 || settings.max_particles > kMaxParticlesCap) {
    errors.push_back({"/max_particles", std::to_string(settings.max_particles) +
                                            " is outside [1, " + std::to_string(kMaxParticlesCap) +
                                            "]"});
  }
  return errors;
}

int AdaptiveParticles(const FilterState& state, int floor, int cap, const SchedulerConfig& config) {
  int n = std::max(1, state.particles);
  if (state.refined) {
    if (state.refinement_ambiguity >= config.ambiguity_grow) {
      n *= 2;
    } else if (state.refinement_ambiguity < config.ambiguity_shrink &&
               state.effective_sample_size >= config.ess_shrink * n) {
      n -= 1;
    }
  }
  cap = std::max(1, cap);
  return std::clamp(n, std::clamp(floor, 1, cap), cap);
}

RayBudgetScheduler::RayBudgetScheduler(const BudgetSettings& settings,
                                       const SchedulerConfig& config)
    : config_(config), settings_(settings), ns_per_ray_(config.initial_ns_per_ray) {}

void RayBudgetScheduler::SetSettings(const BudgetSettings& settings) {
  MutexLock lock(mutex_);
  settings_ = settings;
}

BudgetSettings RayBudgetScheduler::settings() const {
  MutexLock lock(mutex_);
  return settings_;
}

SchedulerTotals RayBudgetScheduler::totals() const {
  MutexLock lock(mutex_);
  return totals_;
}

double RayBudgetScheduler::ns_per_ray() const {
  MutexLock lock(mutex_);
  return ns_per_ray_;
}

int64_t RayBudgetScheduler::QuotaFor(const BudgetSettings& settings, double scan_period_s) const {
  if (settings.mode == QuotaMode::kRaysPerScan) return settings.rays_per_scan;
  const double period =
      std::clamp(scan_period_s, config_.min_scan_period_s, config_.max_scan_period_s);
  double ns_per_ray;
  {
    MutexLock lock(mutex_);
    ns_per_ray = ns_per_ray_;
  }
  const double rays = settings.cpu_share * period * 1e9 / std::max(ns_per_ray, 1e-3);
  return static_cast<int64_t>(std::clamp(rays, static_cast<double>(config_.min_quota),
                                         static_cast<double>(config_.max_quota)));
}

int64_t RayBudgetScheduler::Quota(double scan_period_s) const {
  return QuotaFor(settings(), scan_period_s);
}

ScanPlan RayBudgetScheduler::Plan(const ScanSummary& summary, double scan_period_s,
                                  const SlamParams& params, int64_t reserved_rays) {
  const BudgetSettings settings = this->settings();
  const int64_t quota =
      std::max<int64_t>(1, QuotaFor(settings, scan_period_s) - std::max<int64_t>(0, reserved_rays));

  int particles = params.particles;
  if (settings.policy == BudgetPolicy::kAdaptive) {
    const int64_t per_particle = std::max<int64_t>(
        1, summary.usable_measurements +
               int64_t{config_.adaptive_min_candidates} * summary.matching_measurements);
    const int cap =
        static_cast<int>(std::clamp<int64_t>(quota / per_particle, 1, settings.max_particles));
    if (adaptive_particles_ == 0) adaptive_particles_ = params.particles;
    FilterState state = filter_.value_or(FilterState{});
    state.particles = adaptive_particles_;
    // A scan with nothing to match says nothing new about the belief: keep the count.
    if (summary.matching_measurements == 0) state.refined = false;
    adaptive_particles_ = AdaptiveParticles(state, params.particles, cap, config_);
    particles = adaptive_particles_;
  } else {
    adaptive_particles_ = 0;
  }

  const ScanPlan plan = SplitQuota(summary, quota, particles);
  pending_ = PlanRecord{};
  pending_.mode = settings.mode;
  pending_.policy = settings.policy;
  pending_.quota = quota;
  pending_.plan = plan;
  pending_.planned_rays = PlannedRays(plan, summary);
  pending_.fills_quota = FillsQuota(summary, quota, particles);
  pending_.scan_period_s = scan_period_s;
  pending_summary_ = summary;
  return plan;
}

PlanRecord RayBudgetScheduler::Record(const ScanReport& report, double cpu_s) {
  PlanRecord record = pending_;
  record.scan = report.scan;
  record.used_rays = report.rays.total();
  record.cpu_s = cpu_s;
  filter_ = FilterState{report.particles, report.effective_sample_size, report.refinement_ambiguity,
                        report.rays.matching > 0};

  MutexLock lock(mutex_);
  if (record.used_rays > 0 && cpu_s > 0.0) {
    const double sample = cpu_s * 1e9 / static_cast<double>(record.used_rays);
    ns_per_ray_ += config_.cost_smoothing * (sample - ns_per_ray_);
  }
  record.ns_per_ray = ns_per_ray_;
  ++totals_.scans;
  totals_.rays_planned += record.planned_rays;
  totals_.rays_used += record.used_rays;
  totals_.quota += record.quota;
  totals_.over_quota_scans += record.used_rays > record.quota ? 1 : 0;
  totals_.cpu_s += cpu_s;
  totals_.robot_s += record.scan_period_s;
  totals_.last = record;
  return record;
}

}  // namespace slam
