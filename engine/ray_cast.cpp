#include "engine/ray_cast.hpp"

#include <algorithm>
#include <array>

namespace slam {

std::vector<CellIndex> CellsOnRay(const GridGeometry& geometry, const Vec2& from, const Vec2& to) {
  std::vector<CellIndex> cells;
  const Vec2 d = to - from;
  const double length = d.norm();
  const Vec2 direction = length > 0 ? Vec2(d / length) : Vec2(1.0, 0.0);
  TraverseCells(geometry, from, direction, length, [&](CellIndex c, double, double) {
    cells.push_back(c);
    return true;
  });
  return cells;
}

RayHit CastToObstaclePlain(const OccupancyGrid& grid, const Vec2& origin, const Vec2& direction,
                           double max_range_m, LogOdds occupied_above) {
  RayHit result{max_range_m, max_range_m, false, 0, 0};
  // Cache the current tile: consecutive cells of a ray almost always share it.
  TileIndex cached_index{std::numeric_limits<int32_t>::min(), 0};
  const Tile* cached = nullptr;
  result.cells = TraverseCells(grid.geometry(), origin, direction, max_range_m,
                               [&](CellIndex c, double enter_m, double exit_m) {
                                 const TileIndex t = GridGeometry::TileOf(c);
                                 if (!(t == cached_index)) {
                                   cached_index = t;
                                   cached = grid.FindTile(t);
                                 }
                                 if (cached != nullptr &&
                                     cached->cells[static_cast<size_t>(GridGeometry::OffsetInTile(c))] >
                                         occupied_above) {
                                   result.distance_m = enter_m;
                                   result.exit_m = exit_m;
                                   result.hit = true;
                                   return false;
                                 }
                                 return true;
                               });
  return result;
}

namespace {

/// floor() as an integer without a library call (baseline x86-64 has no rounding instruction).
inline int32_t FloorToInt(double v) {
  const auto i = static_cast<int32_t>(v);
  return i - (v < static_cast<double>(i) ? 1 : 0);
}

// The fast traversal of one matching ray, as a state advanced one jump or one cell at a time,
// so that CastToObstacles can interleave several independent rays (one ray is a chain of
// dependent loads and conversions; the processor overlaps the chains of several).
//
// It runs in mirrored cell coordinates, in which the ray moves towards +u and +v: u = x where
// the ray goes towards +x (or along the axis), u = ~x = -x - 1 where it goes towards -x. Cell x
// covers [x, x + 1), so its mirror covers [u, u + 1) of the coordinate -x, and a ray leaving a
// grid line backwards is in the cell below it, as in GridWalk. Crossing times are GridWalk's
// expressions (up to an exact negation), each from the origin in closed form.
class FastRay {
 public:
  /// Preconditions: direction has unit length; max_range_m > 0.
  FastRay(const GridGeometry& geometry, const Vec2& origin, const Vec2& direction, double max_range_m)
      : res_(geometry.resolution()), length_(max_range_m / res_) {
    result_ = RayHit{max_range_m, max_range_m, false, 0, 0};
    const Vec2 g = geometry.ToGrid(origin);
    const bool back_x = direction.x() < 0, back_y = direction.y() < 0;
    flip_x_ = back_x ? -1 : 0;
    flip_y_ = back_y ? -1 : 0;
    ox_ = back_x ? -g.x() : g.x();
    oy_ = back_y ? -g.y() : g.y();
    ax_ = std::abs(direction.x());
    ay_ = std::abs(direction.y());
    ix_ = 1.0 / ax_;  // infinite along an axis the ray does not move on
    iy_ = 1.0 / ay_;
    // GridWalk's first cell (it may be left at once, over zero length, as GridWalk does).
    u_ = FloorToInt(g.x()) ^ flip_x_;
    v_ = FloorToInt(g.y()) ^ flip_y_;
  }

  const RayHit& result() const { return result_; }

  /// One jump or one cell; true once the ray has its answer. Precondition: grid.HasTiles().
  /// No branches but at the end of the ray: which tile comes next, whether its clearance
  /// allows a jump, which side of a box the ray leaves by are all coin tosses, and each
  /// mispredicted branch would cost as much as a jump.
  bool Advance(const OccupancyGrid& grid, LogOdds occupied_above) {
    // Tiles are aligned in mirrored coordinates too: ~ maps [64a, 64a + 64) onto
    // [64(-a - 1), 64(-a - 1) + 64).
    const int32_t tile_u = u_ >> kTileSizeLog2, tile_v = v_ >> kTileSizeLog2;
    const Tile* tile = grid.FindTileOr({tile_u ^ flip_x_, tile_v ^ flip_y_}, &kAbsentTile);
    const uint64_t mask = tile->occupied_blocks.load(std::memory_order_acquire);
    // A missing tile, or one without a cell above the threshold, is crossed in one jump; a
    // tile whose summary is stale, cell by cell.
    const uint8_t* clearance = mask == 0                  ? kNothingNear.data()
                               : mask == kUnknownSummary ? kUnknownNear.data()
                                                         : tile->clearance.data();
    const int32_t x = u_ ^ flip_x_, y = v_ ^ flip_y_;
    const int offset = ((y & (kTileSize - 1)) << kTileSizeLog2) | (x & (kTileSize - 1));
    const int k = clearance[offset];
    if (k == 0 && tile->cells[static_cast<size_t>(offset)] > occupied_above) {
      // A hit, unless the ray only touches the cell (crosses it over zero length).
      const double t_leave = std::min(std::min((u_ + 1 - ox_) * ix_, (v_ + 1 - oy_) * iy_), length_);
      if (t_leave > t_) {
        result_.distance_m = t_ * res_;
        result_.exit_m = t_leave * res_;
        result_.hit = true;
        return true;
      }
    }
    // Every cell of the tile within k - 1 of this one is free: out of that square at once
    // (out of this cell when k <= 1).
    const int reach = std::max(k, 1);
    return !LeaveBox(std::min(u_ + reach, (tile_u + 1) * kTileSize), std::min(v_ + reach, (tile_v + 1) * kTileSize),
                     k >= 2);
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

  /// Leaves the box of mirrored cells [.., end_u) x [.., end_v), which holds the current cell
  /// and nothing the ray may stop at, into the first cell beyond it; false when the ray ends
  /// inside it. Without branches on the way out: which side comes first is a coin toss.
  /// Counts a jump, or a cell crossed over a positive length (as the plain traversal counts).
  bool LeaveBox(int32_t end_u, int32_t end_v, bool jump) {
    const double exit_u = (end_u - ox_) * ix_, exit_v = (end_v - oy_) * iy_;
    const double t_exit = std::min(exit_u, exit_v);
    result_.jumps += jump ? 1 : 0;
    result_.cells += !jump && std::min(t_exit, length_) > t_ ? 1 : 0;
    if (t_exit >= length_) return false;
    // Across the nearer side, or both at a corner (GridWalk's tolerance). Along the other
    // axis, the boundaries crossed by then, those within the same tolerance after included.
    const double slack = GridWalk::kCornerEpsilon * (1.0 + t_exit);
    const bool corner = std::abs(exit_u - exit_v) <= slack;
    const int32_t along_u = std::clamp(FloorToInt(ox_ + ax_ * (t_exit + slack)), u_, end_u - 1);
    const int32_t along_v = std::clamp(FloorToInt(oy_ + ay_ * (t_exit + slack)), v_, end_v - 1);
    u_ = corner || exit_u < exit_v ? end_u : along_u;
    v_ = corner || exit_v < exit_u ? end_v : along_v;
    t_ = std::max(t_, t_exit);
    return true;
  }

  double res_, length_;
  double ox_ = 0, oy_ = 0, ax_ = 0, ay_ = 0, ix_ = 0, iy_ = 0;
  int32_t flip_x_ = 0, flip_y_ = 0;  // x = u ^ flip_x
  int32_t u_ = 0, v_ = 0;
  double t_ = 0.0;  // when the ray entered cell (u, v)
  RayHit result_;
};

// A tile with nothing above the threshold (its summary is 0, not unknown).
struct AbsentTile : Tile {
  AbsentTile() { occupied_blocks.store(0, std::memory_order_relaxed); }
};
const AbsentTile kAbsentTileStorage;
const Tile& FastRay::kAbsentTile = kAbsentTileStorage;

bool UsesFastPath(double max_range_m, LogOdds occupied_above) {
  return occupied_above >= kSummaryThreshold && max_range_m > 0;
}

}  // namespace

RayHit CastToObstacle(const OccupancyGrid& grid, const Vec2& origin, const Vec2& direction,
                      double max_range_m, LogOdds occupied_above) {
  if (!UsesFastPath(max_range_m, occupied_above)) {
    return CastToObstaclePlain(grid, origin, direction, max_range_m, occupied_above);
  }
  if (!grid.HasTiles()) return RayHit{max_range_m, max_range_m, false, 0, 0};  // nothing to hit
  FastRay ray(grid.geometry(), origin, direction, max_range_m);
  while (!ray.Advance(grid, occupied_above)) {
  }
  return ray.result();
}

void CastToObstacles(const OccupancyGrid& grid, const std::vector<RayQuery>& rays, LogOdds occupied_above,
                     std::vector<RayHit>& hits) {
  hits.resize(rays.size());
  const auto fast = [&](const RayQuery& q) { return grid.HasTiles() && UsesFastPath(q.max_range_m, occupied_above); };
  const auto single = [&](const RayQuery& q) {
    return CastToObstacle(grid, q.origin, q.direction, q.max_range_m, occupied_above);
  };
  // Two rays in flight: the processor overlaps their independent chains (more lanes cost more
  // in bookkeeping than they gain, measured with BM_MatchingRayBatch).
  size_t i = 0;
  for (; i + 1 < rays.size(); i += 2) {
    const RayQuery& qa = rays[i];
    const RayQuery& qb = rays[i + 1];
    if (!fast(qa) || !fast(qb)) {
      hits[i] = single(qa);
      hits[i + 1] = single(qb);
      continue;
    }
    FastRay a(grid.geometry(), qa.origin, qa.direction, qa.max_range_m);
    FastRay b(grid.geometry(), qb.origin, qb.direction, qb.max_range_m);
    bool done_a = false, done_b = false;
    while (!done_a && !done_b) {
      done_a = a.Advance(grid, occupied_above);
      done_b = b.Advance(grid, occupied_above);
    }
    while (!done_a) done_a = a.Advance(grid, occupied_above);
    while (!done_b) done_b = b.Advance(grid, occupied_above);
    hits[i] = a.result();
    hits[i + 1] = b.result();
  }
  if (i < rays.size()) hits[i] = single(rays[i]);
}

int ApplyUpdateRay(OccupancyGrid& grid, const Vec2& origin, double angle, const UpdateProfile& profile) {
  if (profile.delta.empty() || profile.step_m <= 0) return 0;
  const Vec2 direction(std::cos(angle), std::sin(angle));
  const double inv_step = 1.0 / profile.step_m;
  const int limit = grid.limit();
  TileIndex cached_index{std::numeric_limits<int32_t>::min(), 0};
  Tile* cached = nullptr;
  int changed = 0;
  TraverseCells(grid.geometry(), origin, direction, profile.length_m(),
                [&](CellIndex c, double enter_m, double exit_m) {
                  const size_t size = profile.delta.size();
                  if (static_cast<size_t>(enter_m * inv_step) >= size) return false;
                  const int delta = profile.delta[std::min(static_cast<size_t>(exit_m * inv_step), size - 1)];
                  if (delta == 0) return true;
                  const TileIndex t = GridGeometry::TileOf(c);
                  if (cached == nullptr || !(t == cached_index)) {
                    cached_index = t;
                    cached = &grid.MutableTile(t);
                  }
                  LogOdds& cell = cached->cells[static_cast<size_t>(GridGeometry::OffsetInTile(c))];
                  cell = AddLogOdds(cell, delta, limit);
                  ++changed;
                  return true;
                });
  return changed;
}

}  // namespace slam
