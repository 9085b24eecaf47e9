#include "scheduler/fixed_plan.hpp"

#include <algorithm>

namespace slam {

int64_t PlannedRays(const ScanPlan& plan, const ScanSummary& summary) {
  const int64_t particles = std::max(1, plan.particles);
  const int64_t updates = std::min(plan.update_rays, summary.usable_measurements);
  const int64_t matching =
      std::min(plan.matching_measurements, plan.search == SearchMode::kNarrowed
                                               ? summary.matching_available
                                               : summary.matching_measurements);
  // The engine skips matching when there is nothing to choose between.
  const bool matches = plan.refine && matching > 0 && (plan.candidates > 1 || particles > 1);
  return particles * (updates + (matches ? int64_t{std::max(1, plan.candidates)} * matching : 0));
}

bool FillsQuota(const ScanSummary& summary, int64_t quota, int particles) {
  const int64_t n = std::max(1, particles);
  // Each particle's share is rounded down, so the quota also needs room for 20 rays per particle.
  return summary.matching_measurements > 0 && quota >= 20 * n &&
         quota >= n * (summary.usable_measurements + 2 * int64_t{summary.matching_measurements});
}

ScanPlan SplitQuota(const ScanSummary& summary, int64_t quota, int particles) {
  ScanPlan plan;
  plan.particles = std::max(1, particles);
  const int64_t n = plan.particles;
  const int64_t per_particle = std::max<int64_t>(0, quota) / n;
  const int64_t usable = summary.usable_measurements;
  const int64_t matching = summary.matching_measurements;

  // Updates first: they build the map that every later scan matches against.
  const int64_t updates = std::min(usable, per_particle);
  plan.update_rays = static_cast<int>(updates);
  const int64_t left = per_particle - updates;
  // One candidate only refines nothing: refinement needs at least two (the prediction and one
  // alternative), unless several particles need weights.
  const int64_t min_candidates = n > 1 ? 1 : 2;
  if (matching == 0 || left < min_candidates) {
    plan.candidates = 1;
    plan.matching_measurements = 0;
    return plan;
  }
  if (left < min_candidates * matching) {
    plan.matching_measurements = static_cast<int>(left / min_candidates);
    plan.candidates = static_cast<int>(min_candidates);
    return plan;
  }
  int64_t candidates = left / matching;
  int64_t measurements = matching;
  // A range scanner whose heading search has narrowed needs as many times fewer candidates as
  // its thinning keeps more readings (the candidates' density over the search stays), each
  // matching more of them, as long as the peak fit keeps the candidates it needs.
  const int64_t available = summary.matching_available;
  const int64_t least = summary.narrowed_candidates_min;
  if (available > matching && candidates > least) {
    const int64_t wanted = std::max<int64_t>(least, candidates * matching / available);
    measurements = std::min(available, left / wanted);
    candidates = left / measurements;
  }
  if (left - candidates * measurements > per_particle / 20) {
    // Whole candidates leave too much unused: one more candidate, slightly fewer measurements.
    ++candidates;
    measurements = left / candidates;
  }
  plan.candidates = static_cast<int>(candidates);
  plan.matching_measurements = static_cast<int>(measurements);
  // More readings than the set's thinning keeps: the narrowed search's.
  if (measurements > matching) plan.search = SearchMode::kNarrowed;
  return plan;
}

ScanPlan FixedPlan(const ScanSummary& summary, int64_t rays_per_scan, const SlamParams& params) {
  return SplitQuota(summary, rays_per_scan, params.particles);
}

}  // namespace slam
