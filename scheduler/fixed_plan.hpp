#pragma once
// The paper's budget policy ("fixed"): the particle count is a parameter, every usable reading
// updates the map, and pose candidates take the rest of the scan's ray quota.

#include <cstdint>

#include "engine/params.hpp"
#include "engine/slam.hpp"

namespace slam {

/// A plan for one scan that never casts more than `rays_per_scan` rays:
/// particles * (candidates * matching + updates) <= rays_per_scan. When not even two candidates
/// per particle fit, matching measurements are thinned first, then update rays.
ScanPlan FixedPlan(const ScanSummary& summary, int64_t rays_per_scan, const SlamParams& params);

/// The rays a plan will cast on a scan with this summary (the engine's own accounting).
int64_t PlannedRays(const ScanPlan& plan, const ScanSummary& summary);

}  // namespace slam
