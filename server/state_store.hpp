#pragma once
// slamd's saved state in --state-dir: the map (log odds, exactly), the trajectory, and the map
// in the ROS map_server format for people and other tools.
//
//   state.json              {"format": 1, "version": V, "tiles_file": "map-V.tiles", ...}
//   map-V.tiles             every tile's log odds (binary, checksummed)
//   trajectory-V.tum        the trajectory (one pose per scan end)
//   map.pgm, map.yaml, map.png, trajectory.tum   copies for people and map_server
//   slamd.lock              held by the slamd using the directory (its pid inside)
//
// Saving writes the versioned files first, then state.json (each a temporary file renamed over
// the old one), then removes the files state.json no longer names. state.json is the commit
// point: a crash at any moment leaves the previous or the new state complete and loadable.

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"
#include "engine/result.hpp"

namespace slam::server {

struct SavedTile {
  TileIndex index;
  uint64_t version = 0;        // as reported to clients
  std::vector<LogOdds> cells;  // kTileCells
};

struct SavedState {
  uint64_t version = 0;  // map version at the save
  double resolution_m = 0.01;
  std::vector<SavedTile> tiles;
  std::vector<TimedPose> trajectory;  // scan ends, time-ordered; the last is the robot's pose
};

/// The checksum that ends a tile file: 64-bit FNV-1a of everything before it.
uint64_t TileFileChecksum(std::string_view bytes);
/// The tile file's contents (magic, resolution, tiles, checksum).
std::string EncodeTiles(const SavedState& state);
/// Parses EncodeTiles' output; an error when damaged or implausible (a tile outside the map's
/// bound or twice, a cell beyond kLogOddsLimit, a version of 2^62 or more).
Result<SavedState> DecodeTiles(const std::string& bytes);

struct SaveInputs {
  uint64_t version = 0;
  double resolution_m = 0.01;
  const OccupancyGrid* grid = nullptr;  // the map to save (tile versions already reported)
  uint64_t version_base = 0;            // added to the grid's tile versions
  std::vector<TimedPose> trajectory;
};

/// A committed save.
struct SaveReport {
  std::vector<std::string> warnings;  // copies for people that could not be written
};

/// Saves into `dir` (created if missing) as described above. Files no state.json names (left by
/// a failed or killed save) are removed first, and again if this save fails to commit. An error:
/// nothing new was committed (the previous state stands).
Result<SaveReport> SaveState(const std::string& dir, const SaveInputs& in);

/// One slamd per state directory: holds an exclusive lock on `DIR/slamd.lock` (flock, which the
/// kernel releases when the process ends, however it ends) for the object's life.
class StateDirLock {
 public:
  /// Creates `dir` if missing and takes its lock; the error names the directory and, when it can,
  /// the process holding the lock.
  static Result<StateDirLock> Acquire(const std::string& dir);

  StateDirLock(StateDirLock&& other) noexcept;
  StateDirLock& operator=(StateDirLock&& other) noexcept;
  StateDirLock(const StateDirLock&) = delete;
  StateDirLock& operator=(const StateDirLock&) = delete;
  ~StateDirLock();

 private:
  explicit StateDirLock(int fd) : fd_(fd) {}
  int fd_ = -1;
};

/// Loads the state saved in `dir`: nullopt when nothing is saved there yet; an error when
/// something is saved but damaged.
Result<std::optional<SavedState>> LoadState(const std::string& dir);

}  // namespace slam::server
