#pragma once
// Unbounded log-odds occupancy grid stored in square tiles shared copy-on-write between particles.

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <vector>

#include "engine/cell_encoding.hpp"
#include "engine/grid_geometry.hpp"

namespace slam {

/// Blocks of a tile for the empty-space summary: kTileSize / kBlockSize squared = 64 blocks.
inline constexpr int kBlockSizeLog2 = 3;
inline constexpr int kBlockSize = 1 << kBlockSizeLog2;  // 8 cells
inline constexpr int kBlocksPerSide = kTileSize / kBlockSize;
static_assert(kBlocksPerSide * kBlocksPerSide == 64, "one bit per block in a uint64_t");
/// A summary that says nothing: every block may hold an occupied cell.
inline constexpr uint64_t kUnknownSummary = ~uint64_t{0};
/// The summary marks cells above this (log odds 0: more likely occupied than free).
inline constexpr LogOdds kSummaryThreshold = 0;

/// One square block of cells; `version` identifies its contents (never reused, only grows).
struct Tile {
  std::array<LogOdds, kTileCells> cells{};
  uint64_t version = 0;
  /// Empty-space summary for matching rays (OccupancyGrid::RefreshSummaries): bit
  /// (by * kBlocksPerSide + bx) is clear when no cell of block (bx, by) is above
  /// kSummaryThreshold. kUnknownSummary while the tile is being written: a stale summary only
  /// costs time (blocks are then examined cell by cell), never a wrong answer. Atomic because
  /// grids sharing a tile may refresh it from several threads (with the same value).
  std::atomic<uint64_t> occupied_blocks{kUnknownSummary};

  Tile() = default;
  Tile(const Tile& other)
      : cells(other.cells),
        version(other.version),
        occupied_blocks(other.occupied_blocks.load(std::memory_order_relaxed)) {}
  Tile& operator=(const Tile& other) {
    cells = other.cells;
    version = other.version;
    occupied_blocks.store(other.occupied_blocks.load(std::memory_order_relaxed),
                          std::memory_order_relaxed);
    return *this;
  }
};

/// The summary of a tile's cells (bit per block, see Tile::occupied_blocks).
uint64_t ComputeOccupiedBlocks(const Tile& tile);

/// A tile of a grid as handed to readers (exporters, the server): immutable and shared.
struct TileRef {
  TileIndex index;
  std::shared_ptr<const Tile> tile;
};

/// Source of tile versions shared by every copy of a grid (all particles of one filter).
using VersionClock = std::atomic<uint64_t>;

/// Log-odds occupancy grid. Copying is cheap: tiles are shared until one copy writes to them.
/// A grid is used by one thread at a time; distinct copies may be used by distinct threads.
class OccupancyGrid {
 public:
  /// `limit` clamps every cell to [-limit, +limit] (encoded units, <= kLogOddsLimit).
  OccupancyGrid(const GridGeometry& geometry, int limit,
                std::shared_ptr<VersionClock> clock = std::make_shared<VersionClock>(0));
  OccupancyGrid(const OccupancyGrid& other);
  OccupancyGrid& operator=(const OccupancyGrid& other);
  OccupancyGrid(OccupancyGrid&&) noexcept = default;
  OccupancyGrid& operator=(OccupancyGrid&&) noexcept = default;

  const GridGeometry& geometry() const { return geometry_; }
  int limit() const { return limit_; }

  /// The tile at `t`, or nullptr when nothing was ever written there.
  const Tile* FindTile(TileIndex t) const {
    const int64_t u = int64_t{t.x} - origin_.x, v = int64_t{t.y} - origin_.y;
    if (u < 0 || v < 0 || u >= width_ || v >= height_) return nullptr;
    return slots_[static_cast<size_t>(v * width_ + u)].get();
  }

  /// Log odds of a cell; 0 (unknown) where nothing was written.
  LogOdds At(CellIndex c) const {
    const Tile* tile = FindTile(GridGeometry::TileOf(c));
    return tile ? tile->cells[static_cast<size_t>(GridGeometry::OffsetInTile(c))] : LogOdds{0};
  }

  /// Starts a new write epoch: tiles changed from now on get a fresh version, larger than any
  /// version handed out before by this grid's clock.
  void BeginWrite();

  /// The tile at `t` ready for writing: created if missing, copied if shared, its version
  /// stamped with the current write epoch. Grows the grid as needed.
  Tile& MutableTile(TileIndex t);

  /// Adds `delta` (encoded units) to a cell, clamped to the grid's limit.
  void Add(CellIndex c, int delta) {
    LogOdds& cell = MutableTile(GridGeometry::TileOf(c)).cells[static_cast<size_t>(GridGeometry::OffsetInTile(c))];
    cell = AddLogOdds(cell, delta, limit_);
  }

  /// Recomputes the empty-space summary of every tile written since its last refresh (the
  /// engine calls it after each update phase). Tiles shared with other grids may be refreshed
  /// concurrently by them: they compute the same value from the same immutable cells.
  void RefreshSummaries();

  /// Every tile written so far, as shared immutable references (row-major tile order).
  std::vector<TileRef> Tiles() const;
  /// Number of allocated tiles.
  int TileCount() const;
  /// The largest tile version (0 for an empty grid).
  uint64_t Version() const;
  /// True when both grids hold the very same tile object at `t` (copy-on-write sharing).
  bool SharesTileWith(const OccupancyGrid& other, TileIndex t) const;

 private:
  void EnsureCovers(TileIndex t);

  GridGeometry geometry_;
  int limit_;
  std::shared_ptr<VersionClock> clock_;
  uint64_t write_version_ = 0;  // 0 = no epoch started by this copy
  TileIndex origin_{0, 0};      // tile index of slots_[0]
  int64_t width_ = 0;
  int64_t height_ = 0;
  std::vector<std::shared_ptr<Tile>> slots_;  // width_ x height_ window, row-major
};

}  // namespace slam
