#pragma once
// Internal to the engine's matching rays (matching_rays.cpp, match_window.cpp): the fast
// traversal of one matching ray over a field of cells (the grid's tiles or a MatchWindow's
// free squares), and the loop that keeps two rays in flight. In an unnamed namespace: each of
// the two files gets its own copy, which the compiler inlines into its callers; include it
// nowhere else.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "engine/grid_traversal.hpp"
#include "engine/match_window.hpp"
#include "engine/matching_rays.hpp"
#include "engine/occupancy_grid.hpp"

namespace slam {
namespace {

/// floor() as an integer without a library call (baseline x86-64 has no rounding instruction).
inline int32_t FloorToInt(double v) {
  const auto i = static_cast<int32_t>(v);
  return i - (v < static_cast<double>(i) ? 1 : 0);
}

/// What a matching ray learns of the cell it is in: whether it stops there, and how far it may
/// move without looking.
struct Probe {
  bool occupied;         // above the threshold
  int clearance;         // every cell within clearance - 1 (chessboard) is free, up to the limits
  int32_t end_u, end_v;  // the ray's limits (exclusive) of what `clearance` knows about
};

// Rays address cells relative to their first cell, in mirrored coordinates (see FastRay):
// cell (u, v) of a ray is (x, y) = ((u0 + u) ^ flip_x, (v0 + v) ^ flip_y), where (u0, v0) is
// the mirrored first cell. A field gives each ray a cursor with what it needs of that.
struct RayStart {
  int32_t u0, v0, flip_x, flip_y;
};

/// The grid's own tiles: clearance inside the ray's tile, which ends at the tile's edge.
class TileField {
 public:
  using Cursor = RayStart;

  TileField(const OccupancyGrid& grid, LogOdds occupied_above)
      : grid_(grid), occupied_above_(occupied_above) {}

  static Cursor CursorFor(const RayStart& start) { return start; }

  Probe At(const Cursor& c, int32_t u_rel, int32_t v_rel) const {
    // Tiles are aligned in mirrored coordinates too: ~ maps [64a, 64a + 64) onto
    // [64(-a - 1), 64(-a - 1) + 64).
    const int32_t u = c.u0 + u_rel, v = c.v0 + v_rel;
    const int32_t tile_u = u >> kTileSizeLog2, tile_v = v >> kTileSizeLog2;
    const Tile* tile = grid_.FindTileOr({tile_u ^ c.flip_x, tile_v ^ c.flip_y}, &kAbsentTile);
    const uint64_t mask = tile->occupied_blocks.load(std::memory_order_acquire);
    // A missing tile, or one without a cell above the threshold, is crossed in one jump; a
    // tile whose summary is stale, cell by cell.
    const uint8_t* clearance = mask == 0                 ? kNothingNear.data()
                               : mask == kUnknownSummary ? kUnknownNear.data()
                                                         : tile->clearance.data();
    const int32_t x = u ^ c.flip_x, y = v ^ c.flip_y;
    const int offset = ((y & (kTileSize - 1)) << kTileSizeLog2) | (x & (kTileSize - 1));
    const int k = clearance[offset];
    return {k == 0 && tile->cells[static_cast<size_t>(offset)] > occupied_above_, k,
            (tile_u + 1) * kTileSize - c.u0, (tile_v + 1) * kTileSize - c.v0};
  }

 private:
  // Cells "far from anything" (a missing or empty tile) and "maybe occupied" (a stale one).
  static constexpr std::array<uint8_t, kTileCells> kNothingNear = [] {
    std::array<uint8_t, kTileCells> far{};
    far.fill(kClearanceFar);
    return far;
  }();
  static constexpr std::array<uint8_t, kTileCells> kUnknownNear{};
  static const Tile& kAbsentTile;  // what FindTileOr gives where there is no tile (summary 0)

  const OccupancyGrid& grid_;
  LogOdds occupied_above_;
};

/// A MatchWindow's free squares in the ray's quadrant: across tile edges, exact for its
/// threshold, one byte read per step. Only for rays the window covers.
class WindowField {
 public:
  /// Where the ray's first cell is in the window's array, and how far its steps move there.
  struct Cursor {
    int64_t base, step_u, step_v;
  };

  explicit WindowField(const MatchWindow& window)
      : squares_(window.free_squares()), window_(window) {}

  Cursor CursorFor(const RayStart& start) const {
    const int quadrant = (start.flip_x != 0 ? 1 : 0) | (start.flip_y != 0 ? 2 : 0);
    return {quadrant * window_.cells() +
                window_.IndexOf({start.u0 ^ start.flip_x, start.v0 ^ start.flip_y}),
            start.flip_x != 0 ? -1 : 1, start.flip_y != 0 ? -window_.width() : window_.width()};
  }

  Probe At(const Cursor& c, int32_t u_rel, int32_t v_rel) const {
    const int k = squares_[c.base + c.step_u * u_rel + c.step_v * v_rel];
    return {k == 0, k, std::numeric_limits<int32_t>::max(), std::numeric_limits<int32_t>::max()};
  }

 private:
  const uint8_t* squares_;
  const MatchWindow& window_;
};

// The fast traversal of one matching ray, as a state advanced one jump or one cell at a time,
// so that CastToObstacles can interleave several independent rays (one ray is a chain of
// dependent loads and conversions; the processor overlaps the chains of several).
//
// It runs in mirrored cell coordinates, in which the ray moves towards +u and +v: u = x where
// the ray goes towards +x (or along the axis), u = ~x = -x - 1 where it goes towards -x. Cell x
// covers [x, x + 1), so its mirror covers [u, u + 1) of the coordinate -x, and a ray leaving a
// grid line backwards is in the cell below it, as in GridWalk. Crossing times are GridWalk's
// expressions (up to an exact negation), each from the origin in closed form. Coordinates are
// relative to the ray's first cell: they never go negative, so floor is a truncation, and the
// crossing times are the very same doubles (origin and cell boundary differ by the same
// integer, exactly).
template <typename Field>
class FastRay {
 public:
  /// Preconditions: direction has unit length; max_range_m > 0.
  FastRay(const Field& field, const GridGeometry& geometry, const Vec2& origin,
          const Vec2& direction, double max_range_m)
      : res_(geometry.resolution()), length_(max_range_m / res_) {
    result_ = RayHit{max_range_m, max_range_m, false, 0, 0};
    const Vec2 g = geometry.ToGrid(origin);
    const bool back_x = direction.x() < 0, back_y = direction.y() < 0;
    const int32_t flip_x = back_x ? -1 : 0, flip_y = back_y ? -1 : 0;
    // GridWalk's first cell (it may be left at once, over zero length, as GridWalk does).
    const int32_t u0 = FloorToInt(g.x()) ^ flip_x, v0 = FloorToInt(g.y()) ^ flip_y;
    cursor_ = field.CursorFor({u0, v0, flip_x, flip_y});
    // The origin within the first cell, in [0, 1] (exact: an integer apart from the origin).
    ox_ = (back_x ? -g.x() : g.x()) - u0;
    oy_ = (back_y ? -g.y() : g.y()) - v0;
    ax_ = std::abs(direction.x());
    ay_ = std::abs(direction.y());
    ix_ = 1.0 / ax_;  // infinite along an axis the ray does not move on
    iy_ = 1.0 / ay_;
  }

  const RayHit& result() const { return result_; }

  /// One jump or one cell through `field` (the one the ray was made for); true once the ray
  /// has its answer. No branches but at the end of the ray: which tile comes next, whether the
  /// clearance allows a jump, which side of a box the ray leaves by are all coin tosses, and
  /// each mispredicted branch would cost as much as a jump.
  bool Advance(const Field& field) {
    const Probe probe = field.At(cursor_, u_, v_);
    if (probe.occupied) {
      // A hit, unless the ray only touches the cell (crosses it over zero length).
      const double t_leave =
          std::min(std::min((u_ + 1 - ox_) * ix_, (v_ + 1 - oy_) * iy_), length_);
      if (t_leave > t_) {
        result_.distance_m = t_ * res_;
        result_.exit_m = t_leave * res_;
        result_.hit = true;
        return true;
      }
    }
    // Every cell within k - 1 of this one (up to the field's limits) is free: out of that
    // square at once (out of this cell when k <= 1).
    const int reach = std::max(probe.clearance, 1);
    return !LeaveBox(std::min(u_ + reach, probe.end_u), std::min(v_ + reach, probe.end_v),
                     probe.clearance >= 2);
  }

 private:
  /// Leaves the box of cells [.., end_u) x [.., end_v), which holds the current cell and
  /// nothing the ray may stop at, into the first cell beyond it; false when the ray ends
  /// inside it. Without branches on the way out: which side comes first is a coin toss.
  /// Counts a jump, or a cell crossed over a positive length (as the plain traversal counts).
  bool LeaveBox(int32_t end_u, int32_t end_v, bool jump) {
    const double exit_u = (end_u - ox_) * ix_, exit_v = (end_v - oy_) * iy_;
    const double t_exit = std::min(exit_u, exit_v);
    result_.jumps += jump ? 1 : 0;
    result_.cells += !jump && std::min(t_exit, length_) > t_ ? 1 : 0;
    if (t_exit >= length_) return false;
    // Across the nearer side, or both at a corner (GridWalk's tolerance). Along the other
    // axis, the boundaries crossed by then, those within the same tolerance after included
    // (positions are >= 0: truncation is floor).
    const double slack = GridWalk::kCornerEpsilon * (1.0 + t_exit);
    const bool corner = std::abs(exit_u - exit_v) <= slack;
    const int32_t along_u =
        std::clamp(static_cast<int32_t>(ox_ + ax_ * (t_exit + slack)), u_, end_u - 1);
    const int32_t along_v =
        std::clamp(static_cast<int32_t>(oy_ + ay_ * (t_exit + slack)), v_, end_v - 1);
    // Selected with masks: written as conditionals, the compiler branches around the
    // computation of along_u or along_v, and the branch is mispredicted half the time.
    const int32_t across_u = -static_cast<int32_t>(corner | (exit_u < exit_v));  // all ones or 0
    const int32_t across_v = -static_cast<int32_t>(corner | (exit_v < exit_u));
    u_ = (end_u & across_u) | (along_u & ~across_u);
    v_ = (end_v & across_v) | (along_v & ~across_v);
    t_ = std::max(t_, t_exit);
    return true;
  }

  double res_, length_;
  double ox_ = 0, oy_ = 0, ax_ = 0, ay_ = 0, ix_ = 0, iy_ = 0;
  typename Field::Cursor cursor_{};
  int32_t u_ = 0, v_ = 0;  // relative to the first cell
  double t_ = 0.0;         // when the ray entered cell (u, v)
  RayHit result_;
};

// A tile with nothing above the threshold (its summary is 0, not unknown).
struct AbsentTile : Tile {
  AbsentTile() { occupied_blocks.store(0, std::memory_order_relaxed); }
};
const AbsentTile kAbsentTileStorage;
const Tile& TileField::kAbsentTile = kAbsentTileStorage;

/// Whether FastRay may cast the ray: a threshold the summaries serve, a positive range, and both
/// ends within kFastRayBound cells of the origin, where its int32 cells and its crossing times
/// (relative to the first cell) are exact. Rays beyond (never in a map, which ends at
/// kMapCellBound, but a caller may ask) go cell by cell through TraverseCells, which clips them
/// to the map's bound: the same answers, in bounded time.
inline constexpr double kFastRayBound = 1 << 24;
inline bool UsesFastPath(const GridGeometry& geometry, const Vec2& origin, const Vec2& direction,
                         double max_range_m, LogOdds occupied_above) {
  if (!(occupied_above >= kSummaryThreshold && max_range_m > 0)) return false;
  const Vec2 a = geometry.ToGrid(origin), b = geometry.ToGrid(origin + direction * max_range_m);
  const auto near = [](const Vec2& p) {
    return std::abs(p.x()) <= kFastRayBound && std::abs(p.y()) <= kFastRayBound;  // not NaN
  };
  return near(a) && near(b);
}

}  // namespace

namespace {

template <typename Field>
RayHit CastOne(const Field& field, const GridGeometry& geometry, const RayQuery& q) {
  FastRay<Field> ray(field, geometry, q.origin, q.direction, q.max_range_m);
  while (!ray.Advance(field)) {
  }
  return ray.result();
}

/// hits[i] for every rays[i]: two at a time through `field` where fast(rays[i]) holds for
/// both, else one at a time by single(rays[i]). Two rays in flight: the processor overlaps
/// their independent chains (more lanes cost more in bookkeeping than they gain: see
/// BM_MatchingRayBatch).
template <typename Field, typename Fast, typename Single>
void CastInPairs(const Field& field, const GridGeometry& geometry,
                 const std::vector<RayQuery>& rays, std::vector<RayHit>& hits, const Fast& fast,
                 const Single& single) {
  hits.resize(rays.size());
  size_t i = 0;
  for (; i + 1 < rays.size(); i += 2) {
    const RayQuery& qa = rays[i];
    const RayQuery& qb = rays[i + 1];
    if (!fast(qa) || !fast(qb)) {
      hits[i] = single(qa);
      hits[i + 1] = single(qb);
      continue;
    }
    FastRay<Field> a(field, geometry, qa.origin, qa.direction, qa.max_range_m);
    FastRay<Field> b(field, geometry, qb.origin, qb.direction, qb.max_range_m);
    bool done_a = false, done_b = false;
    while (!done_a && !done_b) {
      done_a = a.Advance(field);
      done_b = b.Advance(field);
    }
    while (!done_a) done_a = a.Advance(field);
    while (!done_b) done_b = b.Advance(field);
    hits[i] = a.result();
    hits[i + 1] = b.result();
  }
  if (i < rays.size()) hits[i] = single(rays[i]);
}

}  // namespace

}  // namespace slam
