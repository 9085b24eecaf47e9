#pragma once
// All world <-> cell <-> tile arithmetic of the occupancy grid lives here.
//
// Cell (i, j) covers [i*r, (i+1)*r) x [j*r, (j+1)*r) in metres, r being the resolution, with
// cell (0, 0) touching the world origin. Cells are grouped in square tiles of kTileSize x
// kTileSize; tile (u, v) holds cells i in [u*kTileSize, (u+1)*kTileSize). The map is bounded:
// only tiles within kMapTileBound of the origin (where mapping starts) are ever written.

#include <cmath>
#include <cstdint>
#include <functional>

#include "engine/pose.hpp"

namespace slam {

inline constexpr int kTileSizeLog2 = 6;
inline constexpr int kTileSize = 1 << kTileSizeLog2;  // 64 cells
inline constexpr int kTileCells = kTileSize * kTileSize;

/// Tiles (u, v) with -kMapTileBound <= u, v < kMapTileBound make the map: a square of
/// 2 * 128 * 64 cells a side, 164 m at 1 cm cells, centred on where mapping starts. Nothing is
/// written beyond it, so that no input (odometry gone wild, a crafted saved map) can make a grid
/// or an export of it grow without bound: a grid's tile table is at most 256 x 256 entries (1 MiB).
inline constexpr int32_t kMapTileBound = 128;
/// The same bound in cells: cells (i, j) with -kMapCellBound <= i, j < kMapCellBound make the
/// map; in grid coordinates (GridGeometry::ToGrid), the square [-kMapCellBound, kMapCellBound]^2.
inline constexpr int32_t kMapCellBound = kMapTileBound * kTileSize;

/// Integer coordinates of a cell.
struct CellIndex {
  int32_t x = 0;
  int32_t y = 0;
  friend bool operator==(const CellIndex&, const CellIndex&) = default;
};

/// Integer coordinates of a tile.
struct TileIndex {
  int32_t x = 0;
  int32_t y = 0;
  friend bool operator==(const TileIndex&, const TileIndex&) = default;
};

/// Whether tile `t` is inside the map's bound (kMapTileBound).
inline bool InMapBound(TileIndex t) {
  return t.x >= -kMapTileBound && t.x < kMapTileBound && t.y >= -kMapTileBound &&
         t.y < kMapTileBound;
}

/// Resolution and the conversions between metres, cells and tiles.
class GridGeometry {
 public:
  /// Precondition: resolution_m > 0 (SlamConfig::Validate checks it).
  explicit GridGeometry(double resolution_m)
      : resolution_(resolution_m), inv_(1.0 / resolution_m) {}

  double resolution() const { return resolution_; }

  /// Continuous grid coordinates (cells as unit squares) of a world point.
  Vec2 ToGrid(const Vec2& p) const { return p * inv_; }
  /// The cell containing a world point; beyond kCellSaturation cells from the origin (and for
  /// NaN), the cell at that distance on the point's side (0 for NaN): never an int32 overflow.
  CellIndex CellOf(const Vec2& p) const {
    return {SaturatedFloor(p.x() * inv_), SaturatedFloor(p.y() * inv_)};
  }
  /// Far beyond the map's bound, far within int32: where CellOf saturates.
  static constexpr int32_t kCellSaturation = int32_t{1} << 30;
  /// Whether a world point is finite and inside the map's bound (the cells kMapCellBound
  /// defines): where the engine accepts a pose.
  bool InMapBound(const Vec2& p) const {
    const double x = p.x() * inv_, y = p.y() * inv_;
    constexpr double b = kMapCellBound;
    return x >= -b && x < b && y >= -b && y < b;  // false for NaN
  }
  /// The world position of a cell's centre.
  Vec2 CellCenter(CellIndex c) const {
    return {(c.x + 0.5) * resolution_, (c.y + 0.5) * resolution_};
  }
  /// The world position of a cell's lower-left corner.
  Vec2 CellCorner(CellIndex c) const { return {c.x * resolution_, c.y * resolution_}; }

  /// The tile holding a cell (floor division, correct for negative cells).
  static TileIndex TileOf(CellIndex c) { return {c.x >> kTileSizeLog2, c.y >> kTileSizeLog2}; }
  /// The first (lower-left) cell of a tile.
  static CellIndex TileOrigin(TileIndex t) { return {t.x * kTileSize, t.y * kTileSize}; }
  /// Index of a cell inside its tile's row-major array (row = y).
  static int OffsetInTile(CellIndex c) {
    return ((c.y & (kTileSize - 1)) << kTileSizeLog2) | (c.x & (kTileSize - 1));
  }

 private:
  static int32_t SaturatedFloor(double v) {
    constexpr double limit = kCellSaturation;
    if (!(v > -limit)) return v < 0 ? -kCellSaturation : 0;  // NaN: 0
    if (!(v < limit)) return kCellSaturation;
    return static_cast<int32_t>(std::floor(v));
  }

  double resolution_;
  double inv_;
};

}  // namespace slam
