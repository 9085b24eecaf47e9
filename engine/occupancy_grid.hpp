#pragma once
// Unbounded log-odds occupancy grid stored in square tiles shared copy-on-write between particles.

#include <array>
#include <atomic>
#include <cstddef>
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
  /// costs time (the tile is then examined cell by cell), never a wrong answer. Written only
  /// by a grid that holds the tile alone; atomic (release / acquire) because it publishes
  /// `clearance` to the threads that read the tile afterwards.
  std::atomic<uint64_t> occupied_blocks{kUnknownSummary};
  /// Valid when occupied_blocks is neither kUnknownSummary nor 0: for each cell (row-major, as
  /// `cells`), the chessboard distance in cells to the nearest cell of this tile above
  /// kSummaryThreshold (0 on such a cell). A ray in a cell of clearance k crosses only cells
  /// of clearance >= 1 while it moves less than k - 1 cells along both axes (or leaves the
  /// tile, whose neighbours hold their own distances).
  std::array<uint8_t, kTileCells> clearance;
  /// The cells above kSummaryThreshold (bit x of row y) that `clearance` was computed from,
  /// when has_clearance: a refresh that finds the same cells keeps it (most writes only make
  /// free cells freer and occupied ones more occupied).
  std::array<uint64_t, kTileSize> clearance_rows;
  bool has_clearance = false;
  /// Set by a refresh without clearance that found `clearance` stale, cleared by every write
  /// (OccupancyGrid::MutableTile): the next such refresh skips the tile unless it was written.
  bool clearance_known_stale = false;

  Tile() = default;
  /// A copy of the cells and of the clearance with what it was computed from; its summary
  /// starts unknown (copies are made to be written).
  Tile(const Tile& other)
      : cells(other.cells),
        version(other.version),
        clearance(other.clearance),
        clearance_rows(other.clearance_rows),
        has_clearance(other.has_clearance) {}
  Tile& operator=(const Tile&) = delete;
};

/// Far more than any distance inside a tile.
inline constexpr uint8_t kClearanceFar = 127;

/// The cells of a tile above kSummaryThreshold, bit x of row y.
std::array<uint64_t, kTileSize> ComputeOccupiedRows(const Tile& tile);
/// The summary of those cells (bit per block, see Tile::occupied_blocks).
uint64_t OccupiedBlocks(const std::array<uint64_t, kTileSize>& rows);
/// In place on a row of `width` bytes no greater than kClearanceFar: row[x] = min over j of
/// row[j] + |x - j|, over the j below x (from_below), above x (from_above) or both, for
/// |x - j| < 128 (a farther j never lowers a value). `scratch` is working memory, grown as
/// needed (keep it across calls). Shared by the tiles' clearance and the MatchWindow's free
/// squares.
void RelaxRow(uint8_t* row, size_t width, bool from_below, bool from_above,
              std::vector<uint8_t>& scratch);
/// The chessboard distance of every cell to the nearest of those cells (kClearanceFar when
/// there is none), see Tile::clearance.
void ComputeClearance(const std::array<uint64_t, kTileSize>& rows,
                      std::array<uint8_t, kTileCells>& clearance);

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

  /// The same, with `absent` where there is no tile, and without branches (for the ray
  /// caster, where whether the next tile exists is a coin toss). Precondition: HasTiles().
  const Tile* FindTileOr(TileIndex t, const Tile* absent) const {
    const auto u = static_cast<uint64_t>(int64_t{t.x} - origin_.x);
    const auto v = static_cast<uint64_t>(int64_t{t.y} - origin_.y);
    const bool inside = (u < static_cast<uint64_t>(width_)) & (v < static_cast<uint64_t>(height_));
    const Tile* tile = slots_[inside ? v * static_cast<uint64_t>(width_) + u : 0].get();
    return (inside & (tile != nullptr)) ? tile : absent;
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
  /// stamped with the current write epoch. Grows the grid as needed. Throws std::out_of_range
  /// when `t` is outside the map's bound (InMapBound); writers skip such tiles first.
  Tile& MutableTile(TileIndex t);

  /// Adds `delta` (encoded units) to a cell, clamped to the grid's limit; nothing outside the
  /// map's bound. Returns whether the cell is inside it.
  bool Add(CellIndex c, int delta) {
    const TileIndex t = GridGeometry::TileOf(c);
    if (!InMapBound(t)) return false;
    LogOdds& cell = MutableTile(t).cells[static_cast<size_t>(GridGeometry::OffsetInTile(c))];
    cell = AddLogOdds(cell, delta, limit_);
    return true;
  }

  /// Recomputes the empty-space summary and clearance of every tile written since its last
  /// refresh (the engine calls it after each update phase). A stale tile shared with another
  /// holder (a grid, a reader) is first copied, so that no reader ever sees it change. With
  /// `clearance` false, a tile whose cells above kSummaryThreshold changed since its clearance
  /// was computed stays stale (the clearance costs more than the rest of the refresh, and only
  /// rays cast through the tiles use it); the others get their summary.
  void RefreshSummaries(bool clearance = true);

  /// Every tile written so far, as shared immutable references (row-major tile order).
  std::vector<TileRef> Tiles() const;
  /// Whether any tile was ever written (O(1)).
  bool HasTiles() const { return !slots_.empty(); }
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
