#pragma once
// Splitting one scan's ray quota into the engine's plan. The paper's budget policy ("fixed"):
// the particle count is a parameter, every usable reading updates the map, and pose candidates
// take the rest of the quota.

#include <cstdint>

#include "engine/params.hpp"
#include "engine/slam.hpp"

namespace slam {

/// A plan for `particles` particles that never casts more than `quota` rays:
/// particles * (candidates * matching + updates) <= quota. Updates come first, candidates take
/// the rest; when whole candidates would leave more than 5 % of a particle's share unused, the
/// matching measurements are thinned so that one more candidate fits. When not even two
/// candidates per particle fit, matching measurements are thinned first, then update rays.
/// A range scanner whose heading search has narrowed (summary.matching_available above
/// summary.matching_measurements) gets as many times fewer candidates as it has more readings,
/// each matching more of them (SearchMode::kNarrowed), down to summary.narrowed_candidates_min.
ScanPlan SplitQuota(const ScanSummary& summary, int64_t quota, int particles);

/// The paper's policy: SplitQuota with the particle count of `params`.
ScanPlan FixedPlan(const ScanSummary& summary, int64_t rays_per_scan, const SlamParams& params);

/// The rays a plan will cast on a scan with this summary (the engine's own accounting).
int64_t PlannedRays(const ScanPlan& plan, const ScanSummary& summary);

/// Whether a scan can absorb `quota` rays with `particles` particles: it has matching
/// measurements, room for the updates and two candidates per particle, and at least 20 rays per
/// particle. Plans for such scans
/// use at least 90 % of the quota.
bool FillsQuota(const ScanSummary& summary, int64_t quota, int particles);

}  // namespace slam
