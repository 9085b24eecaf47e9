#pragma once
// The simulated experiment sets (docs/design.md section 5): which worlds and seeds each holds.
// Training experiments are for tuning only, validation experiments for choosing between designs,
// the reference set for reporting only; their seeds are disjoint, so no experiment is in two.

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "sim/scenario.hpp"

namespace slam::sim {

enum class DatasetKind {
  kArenas,      // the original reference set: 3 arenas x 5 seeds (1..5), gentle odometry
  kTraining,    // tuning only: arenas and real-size rooms, seeds 1001..
  kValidation,  // choosing between designs: the training worlds and a held-out studio, 2001..
  kReference,   // reporting only: every built-in world (the lab only here), seeds 3001..
};

/// "arenas", "training", "validation", "reference"; nullopt for anything else.
std::optional<DatasetKind> DatasetKindFromName(std::string_view name);
std::string_view DatasetKindName(DatasetKind kind);

struct DatasetRun {
  std::string world;  // a built-in world
  uint64_t seed = 1;
};

struct DatasetPlan {
  OdometryProfile odometry = OdometryProfile::kTracked;
  double duration_s = 300.0;
  std::vector<DatasetRun> runs;  // world by world, seeds in order
};

/// The set's worlds and seeds; `runs_per_world` > 0 replaces the set's own count (the seeds
/// continue in the same series, so a larger set contains the smaller one).
DatasetPlan PlanDataset(DatasetKind kind, int runs_per_world = 0);

}  // namespace slam::sim
