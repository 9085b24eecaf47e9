#include "sim/dataset.hpp"

namespace slam::sim {

std::optional<DatasetKind> DatasetKindFromName(std::string_view name) {
  if (name == "arenas") return DatasetKind::kArenas;
  if (name == "training") return DatasetKind::kTraining;
  if (name == "validation") return DatasetKind::kValidation;
  if (name == "reference") return DatasetKind::kReference;
  return std::nullopt;
}

std::string_view DatasetKindName(DatasetKind kind) {
  switch (kind) {
    case DatasetKind::kArenas:
      return "arenas";
    case DatasetKind::kTraining:
      return "training";
    case DatasetKind::kValidation:
      return "validation";
    case DatasetKind::kReference:
      break;
  }
  return "reference";
}

DatasetPlan PlanDataset(DatasetKind kind, int runs_per_world) {
  const std::vector<std::string> arenas = BuiltinArenaNames();
  std::vector<std::string> worlds;
  int runs = 0;
  uint64_t first_seed = 0;
  DatasetPlan plan;
  switch (kind) {
    case DatasetKind::kArenas:
      plan.odometry = OdometryProfile::kGentle;
      worlds = arenas;
      runs = 5;
      first_seed = 1;
      break;
    case DatasetKind::kTraining:
      worlds = arenas;
      worlds.insert(worlds.end(), {"flat", "corridor", "office"});
      runs = 2;
      first_seed = 1001;
      break;
    case DatasetKind::kValidation:
      worlds = arenas;
      worlds.insert(worlds.end(), {"flat", "corridor", "office", "studio"});
      runs = 2;
      first_seed = 2001;
      break;
    case DatasetKind::kReference:
      // Every built-in world but the building, which is sized for a laser's loops (20 x 14 m:
      // scripts/tune-laser runs it for 600 s); the marXbot at 0.12 m/s would see a corner of it.
      worlds = BuiltinWorldNames();
      std::erase(worlds, "building");
      runs = 3;
      first_seed = 3001;
      break;
  }
  if (runs_per_world > 0) runs = runs_per_world;
  for (const std::string& world : worlds) {
    for (int r = 0; r < runs; ++r) {
      plan.runs.push_back({world, first_seed + static_cast<uint64_t>(r)});
    }
  }
  return plan;
}

}  // namespace slam::sim
