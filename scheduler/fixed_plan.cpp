#include "scheduler/fixed_plan.hpp"

#include <algorithm>

namespace slam {

int64_t PlannedRays(const ScanPlan& plan, const ScanSummary& summary) {
  const int64_t particles = std::max(1, plan.particles);
  const int64_t updates = std::min(plan.update_rays, summary.usable_measurements);
  const int64_t matching = std::min(plan.matching_measurements, summary.matching_measurements);
  // The engine skips matching when there is nothing to choose between.
  const bool matches = plan.refine && matching > 0 && (plan.candidates > 1 || particles > 1);
  return particles * (updates + (matches ? int64_t{std::max(1, plan.candidates)} * matching : 0));
}

ScanPlan FixedPlan(const ScanSummary& summary, int64_t rays_per_scan, const SlamParams& params) {
  ScanPlan plan;
  plan.particles = std::max(1, params.particles);
  const int64_t particles = plan.particles;
  const int64_t per_particle = std::max<int64_t>(0, rays_per_scan) / particles;
  const int64_t usable = summary.usable_measurements;
  const int64_t matching = summary.matching_measurements;

  // Updates first: they build the map that every later scan matches against.
  const int64_t updates = std::min(usable, per_particle);
  plan.update_rays = static_cast<int>(updates);
  const int64_t left = per_particle - updates;
  // One candidate only refines nothing: refinement needs at least two (the prediction and one
  // alternative), unless several particles need weights.
  const int64_t min_candidates = particles > 1 ? 1 : 2;
  if (matching == 0 || left < min_candidates) {
    plan.candidates = 1;
    plan.matching_measurements = 0;
    return plan;
  }
  if (left >= min_candidates * matching) {
    plan.matching_measurements = static_cast<int>(matching);
    plan.candidates = static_cast<int>(left / matching);
  } else {
    plan.matching_measurements = static_cast<int>(left / min_candidates);
    plan.candidates = static_cast<int>(min_candidates);
  }
  return plan;
}

}  // namespace slam
