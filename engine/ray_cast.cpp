#include "engine/ray_cast.hpp"

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdlib>
#include <string>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#endif

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

/// What a matching ray learns of the cell it is in: whether it stops there, and how far it may
/// move without looking.
struct Probe {
  bool occupied;  // above the threshold
  int clearance;  // every cell within clearance - 1 (chessboard) is free, up to the limits
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

  TileField(const OccupancyGrid& grid, LogOdds occupied_above) : grid_(grid), occupied_above_(occupied_above) {}

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
    const uint8_t* clearance = mask == 0                  ? kNothingNear.data()
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

/// How far (cells) a ray a MatchWindow covers stays inside the window's edge at its ends: the
/// cells a ray crosses lie between the cells of its ends, and FastRay may step one cell beyond
/// (a crossing within its corner tolerance of the end).
constexpr double kWindowMargin = 2.0;

/// A MatchWindow's free squares in the ray's quadrant: across tile edges, exact for its
/// threshold, one byte read per step. Only for rays the window covers.
class WindowField {
 public:
  /// Where the ray's first cell is in the window's array, and how far its steps move there.
  struct Cursor {
    int64_t base, step_u, step_v;
  };

  explicit WindowField(const MatchWindow& window) : squares_(window.free_squares()), window_(window) {}

  Cursor CursorFor(const RayStart& start) const {
    const int quadrant = (start.flip_x != 0 ? 1 : 0) | (start.flip_y != 0 ? 2 : 0);
    return {quadrant * window_.cells() + window_.IndexOf({start.u0 ^ start.flip_x, start.v0 ^ start.flip_y}),
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
  FastRay(const Field& field, const GridGeometry& geometry, const Vec2& origin, const Vec2& direction,
          double max_range_m)
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

  /// The ray as the wide kernel starts it: origin within its first cell, |direction| and its
  /// inverse, length in cells, and where its first cell is in the field.
  struct Start {
    double ox, oy, ax, ay, ix, iy, length;
    typename Field::Cursor cursor;
  };
  Start start() const { return {ox_, oy_, ax_, ay_, ix_, iy_, length_, cursor_}; }

  /// One jump or one cell through `field` (the one the ray was made for); true once the ray
  /// has its answer. No branches but at the end of the ray: which tile comes next, whether the
  /// clearance allows a jump, which side of a box the ray leaves by are all coin tosses, and
  /// each mispredicted branch would cost as much as a jump.
  bool Advance(const Field& field) {
    const Probe probe = field.At(cursor_, u_, v_);
    if (probe.occupied) {
      // A hit, unless the ray only touches the cell (crosses it over zero length).
      const double t_leave = std::min(std::min((u_ + 1 - ox_) * ix_, (v_ + 1 - oy_) * iy_), length_);
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
    return !LeaveBox(std::min(u_ + reach, probe.end_u), std::min(v_ + reach, probe.end_v), probe.clearance >= 2);
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
    const int32_t along_u = std::clamp(static_cast<int32_t>(ox_ + ax_ * (t_exit + slack)), u_, end_u - 1);
    const int32_t along_v = std::clamp(static_cast<int32_t>(oy_ + ay_ * (t_exit + slack)), v_, end_v - 1);
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

bool UsesFastPath(double max_range_m, LogOdds occupied_above) {
  return occupied_above >= kSummaryThreshold && max_range_m > 0;
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
/// their independent chains (more lanes cost more in bookkeeping than they gain, measured
/// with BM_MatchingRayBatch).
template <typename Field, typename Fast, typename Single>
void CastInPairs(const Field& field, const GridGeometry& geometry, const std::vector<RayQuery>& rays,
                 std::vector<RayHit>& hits, const Fast& fast, const Single& single) {
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

RayHit CastToObstacle(const OccupancyGrid& grid, const Vec2& origin, const Vec2& direction,
                      double max_range_m, LogOdds occupied_above) {
  if (!UsesFastPath(max_range_m, occupied_above)) {
    return CastToObstaclePlain(grid, origin, direction, max_range_m, occupied_above);
  }
  if (!grid.HasTiles()) return RayHit{max_range_m, max_range_m, false, 0, 0};  // nothing to hit
  return CastOne(TileField(grid, occupied_above), grid.geometry(), {origin, direction, max_range_m});
}

void CastToObstacles(const OccupancyGrid& grid, const std::vector<RayQuery>& rays, LogOdds occupied_above,
                     std::vector<RayHit>& hits) {
  CastInPairs(
      TileField(grid, occupied_above), grid.geometry(), rays, hits,
      [&](const RayQuery& q) { return grid.HasTiles() && UsesFastPath(q.max_range_m, occupied_above); },
      [&](const RayQuery& q) { return CastToObstacle(grid, q.origin, q.direction, q.max_range_m, occupied_above); });
}

MatchWindow::MatchWindow(const OccupancyGrid& grid, LogOdds occupied_above, CellIndex lo, CellIndex hi)
    : grid_(&grid),
      occupied_above_(occupied_above),
      x0_(lo.x),
      y0_(lo.y),
      width_(std::max<int64_t>(0, int64_t{hi.x} - lo.x + 1)),
      height_(std::max<int64_t>(0, int64_t{hi.y} - lo.y + 1)) {
  const auto w = static_cast<size_t>(width_), h = static_cast<size_t>(height_);
  if (w == 0 || h == 0) return;
  // Free cells (kClearanceFar) and occupied ones (0) from the tiles the window overlaps;
  // cells of missing tiles hold 0 (unknown).
  std::vector<uint8_t> free(w * h, kClearanceFar);
  const bool unknown_occupied = LogOdds{0} > occupied_above;
  const TileIndex t_lo = GridGeometry::TileOf(lo), t_hi = GridGeometry::TileOf(hi);
  for (int32_t ty = t_lo.y; ty <= t_hi.y; ++ty) {
    for (int32_t tx = t_lo.x; tx <= t_hi.x; ++tx) {
      const Tile* tile = grid.FindTile({tx, ty});
      if (tile == nullptr && !unknown_occupied) continue;
      // A tile whose (fresh) summary has no cell above kSummaryThreshold has none above a
      // higher threshold either.
      if (tile != nullptr && occupied_above >= kSummaryThreshold &&
          tile->occupied_blocks.load(std::memory_order_acquire) == 0) {
        continue;
      }
      const CellIndex origin = GridGeometry::TileOrigin({tx, ty});
      const int32_t x_begin = std::max(origin.x, lo.x), x_end = std::min(origin.x + kTileSize - 1, hi.x);
      const int32_t y_begin = std::max(origin.y, lo.y), y_end = std::min(origin.y + kTileSize - 1, hi.y);
      for (int32_t y = y_begin; y <= y_end; ++y) {
        uint8_t* out = free.data() + IndexOf({x_begin, y});
        if (tile == nullptr) {
          std::fill(out, out + (x_end - x_begin + 1), uint8_t{0});
          continue;
        }
        const LogOdds* cells = tile->cells.data() + GridGeometry::OffsetInTile({x_begin, y});
        for (int32_t i = 0; i <= x_end - x_begin; ++i) {
          out[i] = cells[i] > occupied_above ? uint8_t{0} : kClearanceFar;
        }
      }
    }
  }
  // Each quadrant's free squares, rows from the far side: q = 0 on an occupied cell, else
  // 1 + min(q of the next cell along the row, of the next row's cell and of its next), capped
  // at kClearanceFar (cells beyond the window count as free: no ray the window covers gets
  // there). Along the row, as the minimum of a + j over the cells j further (a the value
  // from the next row alone, 0 where occupied).
  squares_.assign(4 * w * h + kFreeSquaresPadding, kClearanceFar);
  std::vector<uint8_t> scratch;
  for (size_t quadrant = 0; quadrant < 4; ++quadrant) {
    const bool back_x = (quadrant & 1) != 0, back_y = (quadrant & 2) != 0;
    uint8_t* q = squares_.data() + quadrant * w * h;
    for (size_t i = 0; i < h; ++i) {
      const size_t y = back_y ? i : h - 1 - i;
      uint8_t* row = q + y * w;
      const uint8_t* occupancy = free.data() + y * w;
      if (i == 0) {
        for (size_t x = 0; x < w; ++x) row[x] = occupancy[x] == 0 ? uint8_t{0} : kClearanceFar;
      } else {
        const uint8_t* next = q + (back_y ? y - 1 : y + 1) * w;
        // a = min(next[x], next[x +- 1], 126) + 1 on free cells (the edge's beyond is free).
        if (back_x) {
          row[0] = std::min(next[0], static_cast<uint8_t>(kClearanceFar - 1));
          for (size_t x = 1; x < w; ++x) row[x] = std::min(std::min(next[x], next[x - 1]), static_cast<uint8_t>(kClearanceFar - 1));
        } else {
          for (size_t x = 0; x + 1 < w; ++x) row[x] = std::min(std::min(next[x], next[x + 1]), static_cast<uint8_t>(kClearanceFar - 1));
          row[w - 1] = std::min(next[w - 1], static_cast<uint8_t>(kClearanceFar - 1));
        }
        for (size_t x = 0; x < w; ++x) row[x] = occupancy[x] == 0 ? uint8_t{0} : static_cast<uint8_t>(row[x] + 1);
      }
      RelaxRow(row, w, back_x, !back_x, scratch);  // from the far side only
    }
  }
}

bool MatchWindow::Covers(const RayQuery& q) const {
  if (!(q.max_range_m > 0) || !std::isfinite(q.max_range_m)) return false;
  const GridGeometry& geometry = grid_->geometry();
  const Vec2 a = geometry.ToGrid(q.origin), b = geometry.ToGrid(q.origin + q.direction * q.max_range_m);
  const double margin = kWindowMargin;
  const auto inside = [&](const Vec2& p) {
    return p.x() >= static_cast<double>(x0_) + margin && p.y() >= static_cast<double>(y0_) + margin &&
           p.x() <= static_cast<double>(x0_ + width_) - margin && p.y() <= static_cast<double>(y0_ + height_) - margin;
  };
  return inside(a) && inside(b);
}

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define SLAM_WIDE_WINDOW_KERNEL 1
#endif

namespace {

#ifdef SLAM_WIDE_WINDOW_KERNEL

/// The window's rays, started as FastRay starts them, one array per quantity (eight
/// consecutive rays' values are loaded at once); reused per thread.
struct WideRays {
  std::vector<double> px, py, dx, dy, range;  // the queries, one array per quantity
  std::vector<double> ox, oy, ax, ay, ix, iy, length, max_range;
  std::vector<int32_t> base, step_u, step_v;
  std::vector<uint32_t> index;     // in the caller's rays
  std::vector<uint32_t> uncovered;  // the caller's rays the window does not cover
  // The answers, in the order the rays finish: which ray (in these arrays), and what it found.
  std::vector<int32_t> finished, hit, cells, jumps;
  std::vector<double> distance, exit;

  /// Room for n rays and the eight lanes' reads past them (grows only: no refill of zeros).
  void Reserve(size_t n) {
    if (index.size() >= n + 8) return;
    for (auto* v : {&px, &py, &dx, &dy, &range, &ox, &oy, &ax, &ay, &ix, &iy, &length, &max_range, &distance, &exit}) {
      v->resize(n + 8);
    }
    for (auto* v : {&base, &step_u, &step_v, &finished, &hit, &cells, &jumps}) v->resize(n + 8);
    for (auto* v : {&index, &uncovered}) v->resize(n + 8);
  }
};


/// The queries one array per quantity (plain loads and stores, done with before a kernel's
/// vector loads read them: gathering them from the RayQuery vector cost as much as the rays).
void CopyQueries(const std::vector<RayQuery>& rays, WideRays& in) {
  for (size_t i = 0; i < rays.size(); ++i) {
    const RayQuery& q = rays[i];
    in.px[i] = q.origin.x();
    in.py[i] = q.origin.y();
    in.dx[i] = q.direction.x();
    in.dy[i] = q.direction.y();
    in.range[i] = q.max_range_m;
  }
}

/// What a wide kernel leaves to others: the rays the window does not cover, through the grid;
/// and the covered rays' answers, packed in finishing order, put in place.
void FinishWindowRays(const MatchWindow& window, const std::vector<RayQuery>& rays, const WideRays& in,
                      size_t covered, size_t uncovered, std::vector<RayHit>& hits) {
  for (size_t j = 0; j < uncovered; ++j) {
    const RayQuery& q = rays[in.uncovered[j]];
    hits[in.uncovered[j]] = CastToObstacle(window.grid(), q.origin, q.direction, q.max_range_m, window.occupied_above());
  }
  for (size_t j = 0; j < covered; ++j) {
    const auto r = static_cast<size_t>(in.finished[j]);
    RayHit& h = hits[in.index[r]];
    h.hit = in.hit[j] != 0;
    h.distance_m = h.hit ? in.distance[j] : in.max_range[r];
    h.exit_m = h.hit ? in.exit[j] : in.max_range[r];
    h.cells = in.cells[j];
    h.jumps = in.jumps[j];
  }
}

#define SLAM_WIDE_TARGET __attribute__((target("avx2,bmi2,avx512f,avx512vl")))
#define SLAM_WIDE_INLINE __attribute__((target("avx2,bmi2,avx512f,avx512vl"), always_inline)) inline
// GCC 12's AVX-512 headers start some results from _mm512_undefined_pd(), a variable initialised
// from itself, which -Wmaybe-uninitialized reports once inlined here (a known false positive).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif

/// The `n` lowest set bits of `mask`.
SLAM_WIDE_INLINE __mmask8 LowestBits(__mmask8 mask, int n) {
  return static_cast<__mmask8>(_pdep_u32((1u << std::min(n, 8)) - 1, mask));
}

/// FloorToInt on each lane (a truncation, one less where that rounded up).
SLAM_WIDE_TARGET inline __m256i FloorLanes(__m512d g) {
  const __m256i truncated = _mm512_cvttpd_epi32(g);
  const __mmask8 below = _mm512_cmp_pd_mask(g, _mm512_cvtepi32_pd(truncated), _CMP_LT_OQ);
  return _mm256_mask_sub_epi32(truncated, below, truncated, _mm256_set1_epi32(1));
}

/// -g on the lanes of `where` (the sign bit flipped, as the scalar negation does).
SLAM_WIDE_TARGET inline __m512d NegateLanes(__m512d g, __mmask8 where) {
  const __m512i bits = _mm512_castpd_si512(g);
  return _mm512_castsi512_pd(_mm512_mask_xor_epi64(bits, where, bits, _mm512_set1_epi64(INT64_MIN)));
}

/// What every lane's step reads.
struct WideStep {
  const uint8_t* squares;  // the window's free squares
  __m512d res;             // the grid's resolution
};

/// Eight lanes, each advancing one ray as FastRay<WindowField> does, and taking the next ray
/// as soon as its own has its answer. Every operation is the scalar one on each lane (IEEE
/// double arithmetic without contraction, the same comparisons, std::min(a, b) as min(b, a),
/// which keeps the scalar choice for equal values and NaN), so each answer is FastRay's, bit
/// for bit.
struct WideLanes {
  __m512d ox, oy, ax, ay, ix, iy, length, t;
  __m256i base, step_u, step_v, u, v, cells, jumps, ray;
  __mmask8 active = 0, free_lanes = 0xff;

  SLAM_WIDE_INLINE WideLanes() {
    ox = oy = ax = ay = ix = iy = length = t = _mm512_setzero_pd();
    base = step_u = step_v = u = v = cells = jumps = ray = _mm256_setzero_si256();
  }

  /// Lanes without a ray take the next ones (consecutive in `in`, expanded into the lanes).
  SLAM_WIDE_INLINE void Fill(const WideRays& in, int32_t& next, int32_t count) {
    if (free_lanes == 0 || next >= count) return;
    const __mmask8 fill = LowestBits(free_lanes, count - next);
    free_lanes = static_cast<__mmask8>(free_lanes & ~fill);
    ox = _mm512_mask_expand_pd(ox, fill, _mm512_loadu_pd(in.ox.data() + next));
    oy = _mm512_mask_expand_pd(oy, fill, _mm512_loadu_pd(in.oy.data() + next));
    ax = _mm512_mask_expand_pd(ax, fill, _mm512_loadu_pd(in.ax.data() + next));
    ay = _mm512_mask_expand_pd(ay, fill, _mm512_loadu_pd(in.ay.data() + next));
    ix = _mm512_mask_expand_pd(ix, fill, _mm512_loadu_pd(in.ix.data() + next));
    iy = _mm512_mask_expand_pd(iy, fill, _mm512_loadu_pd(in.iy.data() + next));
    length = _mm512_mask_expand_pd(length, fill, _mm512_loadu_pd(in.length.data() + next));
    base = _mm256_mask_expand_epi32(base, fill, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(in.base.data() + next)));
    step_u = _mm256_mask_expand_epi32(step_u, fill, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(in.step_u.data() + next)));
    step_v = _mm256_mask_expand_epi32(step_v, fill, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(in.step_v.data() + next)));
    ray = _mm256_mask_expand_epi32(ray, fill, _mm256_add_epi32(_mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7), _mm256_set1_epi32(next)));
    const __m256i zero_i = _mm256_setzero_si256();
    t = _mm512_mask_mov_pd(t, fill, _mm512_setzero_pd());
    u = _mm256_mask_mov_epi32(u, fill, zero_i);
    v = _mm256_mask_mov_epi32(v, fill, zero_i);
    cells = _mm256_mask_mov_epi32(cells, fill, zero_i);
    jumps = _mm256_mask_mov_epi32(jumps, fill, zero_i);
    active = static_cast<__mmask8>(active | fill);
    next += _mm_popcnt_u32(fill);
  }

  /// One jump or one cell of every active lane; the finished lanes' answers packed into
  /// `answers`' arrays from `finished` on.
  SLAM_WIDE_INLINE void Advance(const WideStep& step, WideRays& answers, int32_t& finished) {
    if (active == 0) return;
    const __m512d one = _mm512_set1_pd(1.0);
    const __m256i zero_i = _mm256_setzero_si256(), one_i = _mm256_set1_epi32(1);
    // WindowField::At: the free square of the ray's quadrant at its cell (a 4-byte load at
    // each byte's address, the padding after the squares keeps it inside).
    const __m256i at = _mm256_add_epi32(
        base, _mm256_add_epi32(_mm256_mullo_epi32(step_u, u), _mm256_mullo_epi32(step_v, v)));
    const __m256i k = _mm256_and_si256(_mm256_mmask_i32gather_epi32(zero_i, active, at, step.squares, 1),
                                       _mm256_set1_epi32(0xff));
    const __mmask8 occupied = _mm256_cmpeq_epi32_mask(k, zero_i);
    // A hit, unless the ray only touches the cell.
    const __m512d leave_u = _mm512_mul_pd(_mm512_sub_pd(_mm512_cvtepi32_pd(_mm256_add_epi32(u, one_i)), ox), ix);
    const __m512d leave_v = _mm512_mul_pd(_mm512_sub_pd(_mm512_cvtepi32_pd(_mm256_add_epi32(v, one_i)), oy), iy);
    const __m512d t_leave = _mm512_min_pd(length, _mm512_min_pd(leave_v, leave_u));
    const __mmask8 hit = static_cast<__mmask8>(occupied & _mm512_cmp_pd_mask(t_leave, t, _CMP_GT_OQ));
    // LeaveBox: out of the free square (of this cell when k <= 1).
    const __m256i reach = _mm256_max_epi32(k, one_i);
    const __m256i end_u = _mm256_add_epi32(u, reach), end_v = _mm256_add_epi32(v, reach);
    const __mmask8 jump = _mm256_cmpgt_epi32_mask(k, one_i);
    const __m512d exit_u = _mm512_mul_pd(_mm512_sub_pd(_mm512_cvtepi32_pd(end_u), ox), ix);
    const __m512d exit_v = _mm512_mul_pd(_mm512_sub_pd(_mm512_cvtepi32_pd(end_v), oy), iy);
    const __m512d t_exit = _mm512_min_pd(exit_v, exit_u);
    const auto counted = static_cast<__mmask8>(active & ~hit);
    jumps = _mm256_mask_add_epi32(jumps, static_cast<__mmask8>(counted & jump), jumps, one_i);
    const __mmask8 crossed = _mm512_cmp_pd_mask(_mm512_min_pd(length, t_exit), t, _CMP_GT_OQ);
    cells = _mm256_mask_add_epi32(cells, static_cast<__mmask8>(counted & ~jump & crossed), cells, one_i);
    const __mmask8 out = _mm512_cmp_pd_mask(t_exit, length, _CMP_GE_OQ);
    const __m512d slack = _mm512_mul_pd(_mm512_set1_pd(GridWalk::kCornerEpsilon), _mm512_add_pd(one, t_exit));
    const __mmask8 corner = _mm512_cmp_pd_mask(_mm512_abs_pd(_mm512_sub_pd(exit_u, exit_v)), slack, _CMP_LE_OQ);
    const __m512d ahead = _mm512_add_pd(t_exit, slack);
    const __m256i along_u = _mm256_min_epi32(
        _mm256_max_epi32(_mm512_cvttpd_epi32(_mm512_add_pd(ox, _mm512_mul_pd(ax, ahead))), u),
        _mm256_sub_epi32(end_u, one_i));
    const __m256i along_v = _mm256_min_epi32(
        _mm256_max_epi32(_mm512_cvttpd_epi32(_mm512_add_pd(oy, _mm512_mul_pd(ay, ahead))), v),
        _mm256_sub_epi32(end_v, one_i));
    const auto across_u = static_cast<__mmask8>(corner | _mm512_cmp_pd_mask(exit_u, exit_v, _CMP_LT_OQ));
    const auto across_v = static_cast<__mmask8>(corner | _mm512_cmp_pd_mask(exit_v, exit_u, _CMP_LT_OQ));
    const __m512d t_hit = t;
    u = _mm256_mask_blend_epi32(across_u, along_u, end_u);
    v = _mm256_mask_blend_epi32(across_v, along_v, end_v);
    t = _mm512_max_pd(t_exit, t);

    const auto done = static_cast<__mmask8>(active & (hit | out));
    if (done == 0) return;
    // The finished lanes' answers, packed, then their lanes are free for the next rays.
    const auto at_out = static_cast<size_t>(finished);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(answers.finished.data() + at_out), _mm256_maskz_compress_epi32(done, ray));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(answers.hit.data() + at_out),
                        _mm256_maskz_compress_epi32(done, _mm256_maskz_mov_epi32(hit, one_i)));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(answers.cells.data() + at_out), _mm256_maskz_compress_epi32(done, cells));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(answers.jumps.data() + at_out), _mm256_maskz_compress_epi32(done, jumps));
    _mm512_storeu_pd(answers.distance.data() + at_out, _mm512_maskz_compress_pd(done, _mm512_mul_pd(t_hit, step.res)));
    _mm512_storeu_pd(answers.exit.data() + at_out, _mm512_maskz_compress_pd(done, _mm512_mul_pd(t_leave, step.res)));
    finished += _mm_popcnt_u32(done);
    active = static_cast<__mmask8>(active & ~done);
    free_lanes = static_cast<__mmask8>(free_lanes | done);
  }
};

/// CastToObstacles(window, rays, hits) eight rays at a time: rays start eight at a time
/// (MatchWindow::Covers and FastRay's constructor on each lane, the same operations), the
/// covered ones are packed, then advance in WideLanes.
SLAM_WIDE_TARGET void CastWide(const MatchWindow& window, const std::vector<RayQuery>& rays, std::vector<RayHit>& hits) {
  const GridGeometry& geometry = window.grid().geometry();
  const size_t n = rays.size();
  hits.resize(n);
  thread_local WideRays in;
  in.Reserve(n);

  const __m512d zero = _mm512_setzero_pd(), one = _mm512_set1_pd(1.0);
  const __m256i zero_i = _mm256_setzero_si256(), one_i = _mm256_set1_epi32(1);
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);

  // Starting the rays: the queries one array per quantity, then eight at a time.
  CopyQueries(rays, in);
  const __m512d inv = _mm512_set1_pd(1.0 / geometry.resolution());
  const __m512d res = _mm512_set1_pd(geometry.resolution());
  const __m512d margin = _mm512_set1_pd(kWindowMargin);
  const CellIndex lo = window.lo();
  const __m512d x_min = _mm512_add_pd(_mm512_set1_pd(static_cast<double>(lo.x)), margin);
  const __m512d y_min = _mm512_add_pd(_mm512_set1_pd(static_cast<double>(lo.y)), margin);
  const __m512d x_max = _mm512_sub_pd(_mm512_set1_pd(static_cast<double>(lo.x + window.width())), margin);
  const __m512d y_max = _mm512_sub_pd(_mm512_set1_pd(static_cast<double>(lo.y + window.height())), margin);
  const __m512d infinity = _mm512_set1_pd(std::numeric_limits<double>::infinity());
  const __m256i width = _mm256_set1_epi32(static_cast<int32_t>(window.width()));
  const __m256i cells_per_quadrant = _mm256_set1_epi32(static_cast<int32_t>(window.cells()));
  const __m256i x0 = _mm256_set1_epi32(lo.x), y0 = _mm256_set1_epi32(lo.y);
  size_t covered = 0, uncovered = 0;
  for (size_t i = 0; i < n; i += 8) {
    const auto lanes = static_cast<__mmask8>(n - i >= 8 ? 0xff : (1u << (n - i)) - 1);
    const __m512d px = _mm512_maskz_loadu_pd(lanes, in.px.data() + i), py = _mm512_maskz_loadu_pd(lanes, in.py.data() + i);
    const __m512d dx = _mm512_maskz_loadu_pd(lanes, in.dx.data() + i), dy = _mm512_maskz_loadu_pd(lanes, in.dy.data() + i);
    const __m512d range = _mm512_maskz_loadu_pd(lanes, in.range.data() + i);
    // MatchWindow::Covers: a positive, finite range, both ends inside the window's margin.
    const __m512d gx = _mm512_mul_pd(px, inv), gy = _mm512_mul_pd(py, inv);
    const __m512d ex = _mm512_mul_pd(_mm512_add_pd(px, _mm512_mul_pd(dx, range)), inv);
    const __m512d ey = _mm512_mul_pd(_mm512_add_pd(py, _mm512_mul_pd(dy, range)), inv);
    __mmask8 inside = static_cast<__mmask8>(lanes & _mm512_cmp_pd_mask(range, zero, _CMP_GT_OQ) &
                                            _mm512_cmp_pd_mask(range, infinity, _CMP_LT_OQ));
    inside = static_cast<__mmask8>(inside & _mm512_cmp_pd_mask(gx, x_min, _CMP_GE_OQ) &
                                   _mm512_cmp_pd_mask(gx, x_max, _CMP_LE_OQ) &
                                   _mm512_cmp_pd_mask(ex, x_min, _CMP_GE_OQ) & _mm512_cmp_pd_mask(ex, x_max, _CMP_LE_OQ));
    inside = static_cast<__mmask8>(inside & _mm512_cmp_pd_mask(gy, y_min, _CMP_GE_OQ) &
                                   _mm512_cmp_pd_mask(gy, y_max, _CMP_LE_OQ) &
                                   _mm512_cmp_pd_mask(ey, y_min, _CMP_GE_OQ) & _mm512_cmp_pd_mask(ey, y_max, _CMP_LE_OQ));
    const __m256i ray = _mm256_add_epi32(lane, _mm256_set1_epi32(static_cast<int32_t>(i)));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(in.uncovered.data() + uncovered),
                        _mm256_maskz_compress_epi32(static_cast<__mmask8>(lanes & ~inside), ray));
    uncovered += static_cast<size_t>(_mm_popcnt_u32(static_cast<__mmask8>(lanes & ~inside)));
    if (inside == 0) continue;
    // FastRay's constructor: the first cell (FloorToInt), mirrored where the ray goes back.
    const __mmask8 back_x = _mm512_cmp_pd_mask(dx, zero, _CMP_LT_OQ), back_y = _mm512_cmp_pd_mask(dy, zero, _CMP_LT_OQ);
    const __m256i cx = FloorLanes(gx), cy = FloorLanes(gy);
    const __m256i all_ones = _mm256_set1_epi32(-1);
    const __m256i u0 = _mm256_mask_xor_epi32(cx, back_x, cx, all_ones);
    const __m256i v0 = _mm256_mask_xor_epi32(cy, back_y, cy, all_ones);
    const __m512d ox = _mm512_sub_pd(NegateLanes(gx, back_x), _mm512_cvtepi32_pd(u0));
    const __m512d oy = _mm512_sub_pd(NegateLanes(gy, back_y), _mm512_cvtepi32_pd(v0));
    const __m512d ax = _mm512_abs_pd(dx), ay = _mm512_abs_pd(dy);
    // WindowField::CursorFor: the first cell in the ray's quadrant, and how far steps move.
    const __m256i quadrant = _mm256_add_epi32(_mm256_maskz_mov_epi32(back_x, one_i),
                                              _mm256_maskz_mov_epi32(back_y, _mm256_set1_epi32(2)));
    const __m256i base = _mm256_add_epi32(
        _mm256_mullo_epi32(quadrant, cells_per_quadrant),
        _mm256_add_epi32(_mm256_mullo_epi32(_mm256_sub_epi32(cy, y0), width), _mm256_sub_epi32(cx, x0)));
    const __m256i step_u = _mm256_mask_sub_epi32(one_i, back_x, zero_i, one_i);
    const __m256i step_v = _mm256_mask_sub_epi32(width, back_y, zero_i, width);
    // Packed: the covered lanes' values one after another.
    _mm512_storeu_pd(in.ox.data() + covered, _mm512_maskz_compress_pd(inside, ox));
    _mm512_storeu_pd(in.oy.data() + covered, _mm512_maskz_compress_pd(inside, oy));
    _mm512_storeu_pd(in.ax.data() + covered, _mm512_maskz_compress_pd(inside, ax));
    _mm512_storeu_pd(in.ay.data() + covered, _mm512_maskz_compress_pd(inside, ay));
    _mm512_storeu_pd(in.ix.data() + covered, _mm512_maskz_compress_pd(inside, _mm512_div_pd(one, ax)));
    _mm512_storeu_pd(in.iy.data() + covered, _mm512_maskz_compress_pd(inside, _mm512_div_pd(one, ay)));
    _mm512_storeu_pd(in.length.data() + covered, _mm512_maskz_compress_pd(inside, _mm512_div_pd(range, res)));
    _mm512_storeu_pd(in.max_range.data() + covered, _mm512_maskz_compress_pd(inside, range));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(in.base.data() + covered), _mm256_maskz_compress_epi32(inside, base));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(in.step_u.data() + covered), _mm256_maskz_compress_epi32(inside, step_u));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(in.step_v.data() + covered), _mm256_maskz_compress_epi32(inside, step_v));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(in.index.data() + covered), _mm256_maskz_compress_epi32(inside, ray));
    covered += static_cast<size_t>(_mm_popcnt_u32(inside));
  }

  // Advancing them (one group of eight lanes: two groups side by side measured slower).
  const WideStep step{window.free_squares(), res};
  WideLanes lanes;
  const auto count = static_cast<int32_t>(covered);
  int32_t next = 0, finished = 0;
  while (true) {
    lanes.Fill(in, next, count);
    if (lanes.active == 0) break;
    lanes.Advance(step, in, finished);
  }
  FinishWindowRays(window, rays, in, covered, uncovered, hits);
}

#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif
#undef SLAM_WIDE_INLINE
#undef SLAM_WIDE_TARGET

// The AVX2 kernel: WideLanes' plan on four lanes, with vector masks where AVX-512 has mask
// registers, and tables where it has compress and expand.
#define SLAM_AVX2_TARGET __attribute__((target("avx2")))
#define SLAM_AVX2_INLINE __attribute__((target("avx2"), always_inline)) inline

/// For each set of four lanes (bit j: lane j): the lanes as masks of 64-bit and 32-bit lanes,
/// and permutations (of 32-bit elements, _mm256_permutevar8x32) that expand consecutive values
/// into those lanes (lane j takes the value of its rank among them) or compress those lanes'
/// values into consecutive ones, for doubles (two elements a value) and 32-bit integers.
struct FourLanes {
  int64_t mask64[16][4];
  int32_t mask32[16][4];
  int32_t expand64[16][8], expand32[16][8], compress64[16][8], compress32[16][8];
};

constexpr FourLanes MakeFourLanes() {
  FourLanes t{};
  for (int m = 0; m < 16; ++m) {
    int rank = 0;
    for (int j = 0; j < 4; ++j) {
      const bool in = ((m >> j) & 1) != 0;
      t.mask64[m][j] = in ? -1 : 0;
      t.mask32[m][j] = in ? -1 : 0;
      const int from = in ? rank : j;  // lanes outside the set are blended away
      t.expand64[m][2 * j] = 2 * from;
      t.expand64[m][2 * j + 1] = 2 * from + 1;
      t.expand32[m][j] = from;
      t.expand32[m][j + 4] = j + 4;
      if (in) {
        t.compress64[m][2 * rank] = 2 * j;
        t.compress64[m][2 * rank + 1] = 2 * j + 1;
        t.compress32[m][rank] = j;
        ++rank;
      }
    }
    for (int k = rank; k < 4; ++k) {
      t.compress64[m][2 * k] = 2 * k;
      t.compress64[m][2 * k + 1] = 2 * k + 1;
      t.compress32[m][k] = k;
    }
    for (int k = 4; k < 8; ++k) t.compress32[m][k] = k;
  }
  return t;
}

alignas(64) constexpr FourLanes kFourLanes = MakeFourLanes();

SLAM_AVX2_INLINE __m256i Row8(const int32_t (&row)[8]) {
  return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(row));
}
SLAM_AVX2_INLINE __m256d Mask64(unsigned lanes) {
  return _mm256_castsi256_pd(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(kFourLanes.mask64[lanes])));
}
SLAM_AVX2_INLINE __m128i Mask32(unsigned lanes) {
  return _mm_loadu_si128(reinterpret_cast<const __m128i*>(kFourLanes.mask32[lanes]));
}
SLAM_AVX2_INLINE __m128i Load32(const int32_t* p) { return _mm_loadu_si128(reinterpret_cast<const __m128i*>(p)); }
SLAM_AVX2_INLINE void Store32(int32_t* p, __m128i value) { _mm_storeu_si128(reinterpret_cast<__m128i*>(p), value); }
/// The lanes of a mask of 64-bit lanes as bits.
SLAM_AVX2_INLINE unsigned Bits(__m256d mask) { return static_cast<unsigned>(_mm256_movemask_pd(mask)); }
SLAM_AVX2_INLINE __m256d PermutePd(__m256d v, __m256i order) {
  return _mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(v), order));
}
SLAM_AVX2_INLINE __m128i PermuteEpi32(__m128i v, __m256i order) {
  return _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(_mm256_castsi128_si256(v), order));
}
/// A mask of 64-bit lanes as a mask of 32-bit lanes (each lane's low half: all ones or zero).
SLAM_AVX2_INLINE __m128i Narrow(__m256d mask) {
  return _mm256_castsi256_si128(
      _mm256_permutevar8x32_epi32(_mm256_castpd_si256(mask), _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6)));
}
/// A mask of 32-bit lanes as a mask of 64-bit lanes.
SLAM_AVX2_INLINE __m256d Widen(__m128i mask) { return _mm256_castsi256_pd(_mm256_cvtepi32_epi64(mask)); }

/// The AVX2 kernel's start, four rays at a time: MatchWindow::Covers and FastRay's start on
/// each lane (the same operations), the covered rays packed into `in`, the others listed in
/// in.uncovered. Returns how many rays are covered.
SLAM_AVX2_TARGET size_t StartAvx2(const MatchWindow& window, const std::vector<RayQuery>& rays, WideRays& in,
                                  size_t& uncovered) {
  const GridGeometry& geometry = window.grid().geometry();
  const size_t n = rays.size();
  CopyQueries(rays, in);
  const __m256d zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0), sign = _mm256_set1_pd(-0.0);
  const __m128i one_i = _mm_set1_epi32(1);
  const __m256d inv = _mm256_set1_pd(1.0 / geometry.resolution()), res = _mm256_set1_pd(geometry.resolution());
  const __m256d margin = _mm256_set1_pd(kWindowMargin);
  const CellIndex lo = window.lo();
  const __m256d x_min = _mm256_add_pd(_mm256_set1_pd(static_cast<double>(lo.x)), margin);
  const __m256d y_min = _mm256_add_pd(_mm256_set1_pd(static_cast<double>(lo.y)), margin);
  const __m256d x_max = _mm256_sub_pd(_mm256_set1_pd(static_cast<double>(lo.x + window.width())), margin);
  const __m256d y_max = _mm256_sub_pd(_mm256_set1_pd(static_cast<double>(lo.y + window.height())), margin);
  const __m256d infinity = _mm256_set1_pd(std::numeric_limits<double>::infinity());
  const __m128i width = _mm_set1_epi32(static_cast<int32_t>(window.width()));
  const __m128i cells_per_quadrant = _mm_set1_epi32(static_cast<int32_t>(window.cells()));
  const __m128i x0 = _mm_set1_epi32(lo.x), y0 = _mm_set1_epi32(lo.y);
  size_t covered = 0;
  uncovered = 0;
  for (size_t i = 0; i < n; i += 4) {
    const unsigned lanes = n - i >= 4 ? 0xfu : (1u << (n - i)) - 1;  // past n: stale values, never used
    const __m256d px = _mm256_loadu_pd(in.px.data() + i), py = _mm256_loadu_pd(in.py.data() + i);
    const __m256d dx = _mm256_loadu_pd(in.dx.data() + i), dy = _mm256_loadu_pd(in.dy.data() + i);
    const __m256d range = _mm256_loadu_pd(in.range.data() + i);
    // MatchWindow::Covers: a positive, finite range, both ends inside the window's margin.
    const __m256d gx = _mm256_mul_pd(px, inv), gy = _mm256_mul_pd(py, inv);
    const __m256d ex = _mm256_mul_pd(_mm256_add_pd(px, _mm256_mul_pd(dx, range)), inv);
    const __m256d ey = _mm256_mul_pd(_mm256_add_pd(py, _mm256_mul_pd(dy, range)), inv);
    __m256d inside = _mm256_and_pd(_mm256_cmp_pd(range, zero, _CMP_GT_OQ), _mm256_cmp_pd(range, infinity, _CMP_LT_OQ));
    for (const __m256d* g : {&gx, &ex}) {
      inside = _mm256_and_pd(inside, _mm256_and_pd(_mm256_cmp_pd(*g, x_min, _CMP_GE_OQ), _mm256_cmp_pd(*g, x_max, _CMP_LE_OQ)));
    }
    for (const __m256d* g : {&gy, &ey}) {
      inside = _mm256_and_pd(inside, _mm256_and_pd(_mm256_cmp_pd(*g, y_min, _CMP_GE_OQ), _mm256_cmp_pd(*g, y_max, _CMP_LE_OQ)));
    }
    const unsigned in_bits = lanes & Bits(inside), out_bits = lanes & ~in_bits;
    const __m128i ray = _mm_add_epi32(_mm_setr_epi32(0, 1, 2, 3), _mm_set1_epi32(static_cast<int32_t>(i)));
    Store32(reinterpret_cast<int32_t*>(in.uncovered.data() + uncovered), PermuteEpi32(ray, Row8(kFourLanes.compress32[out_bits])));
    uncovered += static_cast<size_t>(__builtin_popcount(out_bits));
    if (in_bits == 0) continue;
    // FastRay's constructor: the first cell (FloorToInt), mirrored where the ray goes back.
    const __m256d back_x = _mm256_cmp_pd(dx, zero, _CMP_LT_OQ), back_y = _mm256_cmp_pd(dy, zero, _CMP_LT_OQ);
    const __m128i back_x32 = Narrow(back_x), back_y32 = Narrow(back_y);
    const auto floor = [](__m256d g) SLAM_AVX2_TARGET {
      const __m128i truncated = _mm256_cvttpd_epi32(g);
      return _mm_add_epi32(truncated, Narrow(_mm256_cmp_pd(g, _mm256_cvtepi32_pd(truncated), _CMP_LT_OQ)));
    };
    const __m128i cx = floor(gx), cy = floor(gy);
    const __m128i u0 = _mm_xor_si128(cx, back_x32), v0 = _mm_xor_si128(cy, back_y32);
    const __m256d ox = _mm256_sub_pd(_mm256_xor_pd(gx, _mm256_and_pd(back_x, sign)), _mm256_cvtepi32_pd(u0));
    const __m256d oy = _mm256_sub_pd(_mm256_xor_pd(gy, _mm256_and_pd(back_y, sign)), _mm256_cvtepi32_pd(v0));
    const __m256d ax = _mm256_andnot_pd(sign, dx), ay = _mm256_andnot_pd(sign, dy);
    // WindowField::CursorFor.
    const __m128i quadrant = _mm_add_epi32(_mm_and_si128(back_x32, one_i), _mm_and_si128(back_y32, _mm_set1_epi32(2)));
    const __m128i base = _mm_add_epi32(_mm_mullo_epi32(quadrant, cells_per_quadrant),
                                       _mm_add_epi32(_mm_mullo_epi32(_mm_sub_epi32(cy, y0), width), _mm_sub_epi32(cx, x0)));
    const __m128i step_u = _mm_or_si128(back_x32, one_i);                         // -1 or 1
    const __m128i step_v = _mm_sub_epi32(_mm_xor_si128(width, back_y32), back_y32);  // -width or width
    // Packed: the covered lanes' values one after another.
    const __m256i c64 = Row8(kFourLanes.compress64[in_bits]), c32 = Row8(kFourLanes.compress32[in_bits]);
    const auto pack = [&](std::vector<double>& out, __m256d value) SLAM_AVX2_TARGET {
      _mm256_storeu_pd(out.data() + covered, PermutePd(value, c64));
    };
    pack(in.ox, ox);
    pack(in.oy, oy);
    pack(in.ax, ax);
    pack(in.ay, ay);
    pack(in.ix, _mm256_div_pd(one, ax));
    pack(in.iy, _mm256_div_pd(one, ay));
    pack(in.length, _mm256_div_pd(range, res));
    pack(in.max_range, range);
    Store32(in.base.data() + covered, PermuteEpi32(base, c32));
    Store32(in.step_u.data() + covered, PermuteEpi32(step_u, c32));
    Store32(in.step_v.data() + covered, PermuteEpi32(step_v, c32));
    Store32(reinterpret_cast<int32_t*>(in.index.data() + covered), PermuteEpi32(ray, c32));
    covered += static_cast<size_t>(__builtin_popcount(in_bits));
  }
  return covered;
}

/// Four lanes, each advancing one ray as FastRay<WindowField> does (see WideLanes: the same
/// operations on each lane, so the same answers bit for bit).
struct Avx2Lanes {
  __m256d ox, oy, ax, ay, ix, iy, length, t;
  __m128i base, step_u, step_v, u, v, cells, jumps, ray;
  unsigned active = 0, free_lanes = 0xf;

  SLAM_AVX2_INLINE Avx2Lanes() {
    ox = oy = ax = ay = ix = iy = length = t = _mm256_setzero_pd();
    base = step_u = step_v = u = v = cells = jumps = ray = _mm_setzero_si128();
  }

  /// Lanes without a ray take the next ones (consecutive in `in`, expanded into the lanes).
  SLAM_AVX2_INLINE void Fill(const WideRays& in, int32_t& next, int32_t count) {
    if (free_lanes == 0 || next >= count) return;
    unsigned fill = free_lanes;
    while (__builtin_popcount(fill) > count - next) fill &= ~(1u << (31 - __builtin_clz(fill)));  // keep the lowest
    free_lanes &= ~fill;
    const __m256i e64 = Row8(kFourLanes.expand64[fill]), e32 = Row8(kFourLanes.expand32[fill]);
    const __m256d m64 = Mask64(fill);
    const __m128i m32 = Mask32(fill);
    const auto n = static_cast<size_t>(next);
    ox = _mm256_blendv_pd(ox, PermutePd(_mm256_loadu_pd(in.ox.data() + n), e64), m64);
    oy = _mm256_blendv_pd(oy, PermutePd(_mm256_loadu_pd(in.oy.data() + n), e64), m64);
    ax = _mm256_blendv_pd(ax, PermutePd(_mm256_loadu_pd(in.ax.data() + n), e64), m64);
    ay = _mm256_blendv_pd(ay, PermutePd(_mm256_loadu_pd(in.ay.data() + n), e64), m64);
    ix = _mm256_blendv_pd(ix, PermutePd(_mm256_loadu_pd(in.ix.data() + n), e64), m64);
    iy = _mm256_blendv_pd(iy, PermutePd(_mm256_loadu_pd(in.iy.data() + n), e64), m64);
    length = _mm256_blendv_pd(length, PermutePd(_mm256_loadu_pd(in.length.data() + n), e64), m64);
    t = _mm256_andnot_pd(m64, t);
    base = _mm_blendv_epi8(base, PermuteEpi32(Load32(in.base.data() + n), e32), m32);
    step_u = _mm_blendv_epi8(step_u, PermuteEpi32(Load32(in.step_u.data() + n), e32), m32);
    step_v = _mm_blendv_epi8(step_v, PermuteEpi32(Load32(in.step_v.data() + n), e32), m32);
    ray = _mm_blendv_epi8(ray, PermuteEpi32(_mm_add_epi32(_mm_setr_epi32(0, 1, 2, 3), _mm_set1_epi32(next)), e32), m32);
    u = _mm_andnot_si128(m32, u);
    v = _mm_andnot_si128(m32, v);
    cells = _mm_andnot_si128(m32, cells);
    jumps = _mm_andnot_si128(m32, jumps);
    active |= fill;
    next += __builtin_popcount(fill);
  }

  /// One jump or one cell of every active lane; the finished lanes' answers packed into
  /// `answers`' arrays from `finished` on.
  SLAM_AVX2_INLINE void Advance(const uint8_t* squares, __m256d res, WideRays& answers, int32_t& finished) {
    if (active == 0) return;
    const __m256d one = _mm256_set1_pd(1.0), active64 = Mask64(active);
    const __m128i zero_i = _mm_setzero_si128(), one_i = _mm_set1_epi32(1);
    // WindowField::At (a 4-byte load at each byte's address, inside thanks to the padding).
    const __m128i at = _mm_add_epi32(base, _mm_add_epi32(_mm_mullo_epi32(step_u, u), _mm_mullo_epi32(step_v, v)));
    const __m128i k =
        _mm_and_si128(_mm_mask_i32gather_epi32(zero_i, reinterpret_cast<const int*>(squares), at, Mask32(active), 1),
                      _mm_set1_epi32(0xff));
    const __m256d occupied = Widen(_mm_cmpeq_epi32(k, zero_i));
    // A hit, unless the ray only touches the cell.
    const __m256d leave_u = _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtepi32_pd(_mm_add_epi32(u, one_i)), ox), ix);
    const __m256d leave_v = _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtepi32_pd(_mm_add_epi32(v, one_i)), oy), iy);
    const __m256d t_leave = _mm256_min_pd(length, _mm256_min_pd(leave_v, leave_u));
    const __m256d hit = _mm256_and_pd(occupied, _mm256_cmp_pd(t_leave, t, _CMP_GT_OQ));
    // LeaveBox: out of the free square (of this cell when k <= 1).
    const __m128i reach = _mm_max_epi32(k, one_i);
    const __m128i end_u = _mm_add_epi32(u, reach), end_v = _mm_add_epi32(v, reach);
    const __m128i jump = _mm_cmpgt_epi32(k, one_i);
    const __m256d exit_u = _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtepi32_pd(end_u), ox), ix);
    const __m256d exit_v = _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtepi32_pd(end_v), oy), iy);
    const __m256d t_exit = _mm256_min_pd(exit_v, exit_u);
    const __m128i counted = Narrow(_mm256_andnot_pd(hit, active64));
    jumps = _mm_sub_epi32(jumps, _mm_and_si128(counted, jump));  // a mask lane is -1: subtracting counts
    const __m128i crossed = Narrow(_mm256_cmp_pd(_mm256_min_pd(length, t_exit), t, _CMP_GT_OQ));
    cells = _mm_sub_epi32(cells, _mm_and_si128(_mm_andnot_si128(jump, counted), crossed));
    const __m256d out = _mm256_cmp_pd(t_exit, length, _CMP_GE_OQ);
    const __m256d slack = _mm256_mul_pd(_mm256_set1_pd(GridWalk::kCornerEpsilon), _mm256_add_pd(one, t_exit));
    const __m256d gap = _mm256_andnot_pd(_mm256_set1_pd(-0.0), _mm256_sub_pd(exit_u, exit_v));  // |exit_u - exit_v|
    const __m256d corner = _mm256_cmp_pd(gap, slack, _CMP_LE_OQ);
    const __m256d ahead = _mm256_add_pd(t_exit, slack);
    const __m128i along_u = _mm_min_epi32(
        _mm_max_epi32(_mm256_cvttpd_epi32(_mm256_add_pd(ox, _mm256_mul_pd(ax, ahead))), u), _mm_sub_epi32(end_u, one_i));
    const __m128i along_v = _mm_min_epi32(
        _mm_max_epi32(_mm256_cvttpd_epi32(_mm256_add_pd(oy, _mm256_mul_pd(ay, ahead))), v), _mm_sub_epi32(end_v, one_i));
    const __m128i across_u = Narrow(_mm256_or_pd(corner, _mm256_cmp_pd(exit_u, exit_v, _CMP_LT_OQ)));
    const __m128i across_v = Narrow(_mm256_or_pd(corner, _mm256_cmp_pd(exit_v, exit_u, _CMP_LT_OQ)));
    const __m256d t_hit = t;
    u = _mm_blendv_epi8(along_u, end_u, across_u);
    v = _mm_blendv_epi8(along_v, end_v, across_v);
    t = _mm256_max_pd(t_exit, t);

    const unsigned done = active & Bits(_mm256_or_pd(hit, out));
    if (done == 0) return;
    // The finished lanes' answers, packed, then their lanes are free for the next rays.
    const __m256i c64 = Row8(kFourLanes.compress64[done]), c32 = Row8(kFourLanes.compress32[done]);
    const auto at_out = static_cast<size_t>(finished);
    Store32(answers.finished.data() + at_out, PermuteEpi32(ray, c32));
    Store32(answers.hit.data() + at_out, PermuteEpi32(_mm_and_si128(Narrow(hit), one_i), c32));
    Store32(answers.cells.data() + at_out, PermuteEpi32(cells, c32));
    Store32(answers.jumps.data() + at_out, PermuteEpi32(jumps, c32));
    _mm256_storeu_pd(answers.distance.data() + at_out, PermutePd(_mm256_mul_pd(t_hit, res), c64));
    _mm256_storeu_pd(answers.exit.data() + at_out, PermutePd(_mm256_mul_pd(t_leave, res), c64));
    finished += __builtin_popcount(done);
    active &= ~done;
    free_lanes |= done;
  }
};

/// CastToObstacles(window, rays, hits) four rays at a time.
SLAM_AVX2_TARGET void CastAvx2(const MatchWindow& window, const std::vector<RayQuery>& rays, std::vector<RayHit>& hits) {
  const size_t n = rays.size();
  hits.resize(n);
  thread_local WideRays in;
  in.Reserve(n);
  size_t uncovered = 0;
  const size_t covered = StartAvx2(window, rays, in, uncovered);
  const uint8_t* squares = window.free_squares();
  const __m256d res = _mm256_set1_pd(window.grid().geometry().resolution());
  Avx2Lanes lanes;
  const auto count = static_cast<int32_t>(covered);
  int32_t next = 0, finished = 0;
  while (true) {
    lanes.Fill(in, next, count);
    if (lanes.active == 0) break;
    lanes.Advance(squares, res, in, finished);
  }
  FinishWindowRays(window, rays, in, covered, uncovered, hits);
}

#undef SLAM_AVX2_INLINE
#undef SLAM_AVX2_TARGET

bool Supports(WindowKernel kernel) {
  __builtin_cpu_init();
  switch (kernel) {
    case WindowKernel::kAvx512:
      return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("bmi2") && __builtin_cpu_supports("avx512f") &&
             __builtin_cpu_supports("avx512vl");
    case WindowKernel::kAvx2:
      return __builtin_cpu_supports("avx2");
    default:
      return true;
  }
}

#endif  // SLAM_WIDE_WINDOW_KERNEL

/// What kBest runs here.
WindowKernel BestKernel();

}  // namespace

bool WindowKernelAvailable(WindowKernel kernel) {
  if (kernel == WindowKernel::kBest || kernel == WindowKernel::kPortable) return true;
#ifdef SLAM_WIDE_WINDOW_KERNEL
  static const bool avx512 = Supports(WindowKernel::kAvx512), avx2 = Supports(WindowKernel::kAvx2);
  return kernel == WindowKernel::kAvx512 ? avx512 : avx2;
#else
  return false;
#endif
}

namespace {

WindowKernel BestKernel() {
  static const WindowKernel best = [] {
    // SLAM_RAY_KERNEL=portable|avx2|avx512 caps the choice (to compare kernels, or to rule one
    // out); tools report the kernel that runs.
    const char* cap = std::getenv("SLAM_RAY_KERNEL");
    const std::string wanted = cap != nullptr ? cap : "avx512";
    if (wanted == "portable") return WindowKernel::kPortable;
    if (wanted != "avx2" && WindowKernelAvailable(WindowKernel::kAvx512)) return WindowKernel::kAvx512;
    if (WindowKernelAvailable(WindowKernel::kAvx2)) return WindowKernel::kAvx2;
    return WindowKernel::kPortable;
  }();
  return best;
}

}  // namespace

const char* BestWindowKernelName() {
  switch (BestKernel()) {
    case WindowKernel::kAvx512:
      return "avx512";
    case WindowKernel::kAvx2:
      return "avx2";
    default:
      return "portable";
  }
}

void CastToObstacles(const MatchWindow& window, const std::vector<RayQuery>& rays, std::vector<RayHit>& hits,
                     WindowKernel kernel) {
  const OccupancyGrid& grid = window.grid();
  const WindowField field(window);
  const auto through_grid = [&](const RayQuery& q) {
    return CastToObstacle(grid, q.origin, q.direction, q.max_range_m, window.occupied_above());
  };
  if (kernel == WindowKernel::kBest) kernel = BestKernel();
#ifdef SLAM_WIDE_WINDOW_KERNEL
  if (kernel == WindowKernel::kAvx512 && WindowKernelAvailable(kernel)) {
    CastWide(window, rays, hits);
    return;
  }
  if (kernel == WindowKernel::kAvx2 && WindowKernelAvailable(kernel)) {
    CastAvx2(window, rays, hits);
    return;
  }
#endif
  CastInPairs(
      field, grid.geometry(), rays, hits, [&](const RayQuery& q) { return window.Covers(q); },
      [&](const RayQuery& q) { return window.Covers(q) ? CastOne(field, grid.geometry(), q) : through_grid(q); });
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
