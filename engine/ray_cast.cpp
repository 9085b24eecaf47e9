#include "engine/ray_cast.hpp"

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "engine/ray_cast_wide.hpp"

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
  result.cells = TraverseCells(
      grid.geometry(), origin, direction, max_range_m,
      [&](CellIndex c, double enter_m, double exit_m) {
        const TileIndex t = GridGeometry::TileOf(c);
        if (!(t == cached_index)) {
          cached_index = t;
          cached = grid.FindTile(t);
        }
        if (cached != nullptr &&
            cached->cells[static_cast<size_t>(GridGeometry::OffsetInTile(c))] > occupied_above) {
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

RayHit CastToObstacle(const OccupancyGrid& grid, const Vec2& origin, const Vec2& direction,
                      double max_range_m, LogOdds occupied_above) {
  if (!UsesFastPath(max_range_m, occupied_above)) {
    return CastToObstaclePlain(grid, origin, direction, max_range_m, occupied_above);
  }
  if (!grid.HasTiles()) return RayHit{max_range_m, max_range_m, false, 0, 0};  // nothing to hit
  return CastOne(TileField(grid, occupied_above), grid.geometry(),
                 {origin, direction, max_range_m});
}

void CastToObstacles(const OccupancyGrid& grid, const std::vector<RayQuery>& rays,
                     LogOdds occupied_above, std::vector<RayHit>& hits) {
  CastInPairs(
      TileField(grid, occupied_above), grid.geometry(), rays, hits,
      [&](const RayQuery& q) {
        return grid.HasTiles() && UsesFastPath(q.max_range_m, occupied_above);
      },
      [&](const RayQuery& q) {
        return CastToObstacle(grid, q.origin, q.direction, q.max_range_m, occupied_above);
      });
}

MatchWindow::MatchWindow(const OccupancyGrid& grid, LogOdds occupied_above, CellIndex lo,
                         CellIndex hi)
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
      const int32_t x_begin = std::max(origin.x, lo.x),
                    x_end = std::min(origin.x + kTileSize - 1, hi.x);
      const int32_t y_begin = std::max(origin.y, lo.y),
                    y_end = std::min(origin.y + kTileSize - 1, hi.y);
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
          for (size_t x = 1; x < w; ++x)
            row[x] =
                std::min(std::min(next[x], next[x - 1]), static_cast<uint8_t>(kClearanceFar - 1));
        } else {
          for (size_t x = 0; x + 1 < w; ++x)
            row[x] =
                std::min(std::min(next[x], next[x + 1]), static_cast<uint8_t>(kClearanceFar - 1));
          row[w - 1] = std::min(next[w - 1], static_cast<uint8_t>(kClearanceFar - 1));
        }
        for (size_t x = 0; x < w; ++x)
          row[x] = occupancy[x] == 0 ? uint8_t{0} : static_cast<uint8_t>(row[x] + 1);
      }
      RelaxRow(row, w, back_x, !back_x, scratch);  // from the far side only
    }
  }
}

bool MatchWindow::Covers(const RayQuery& q) const {
  if (!(q.max_range_m > 0) || !std::isfinite(q.max_range_m)) return false;
  const GridGeometry& geometry = grid_->geometry();
  const Vec2 a = geometry.ToGrid(q.origin),
             b = geometry.ToGrid(q.origin + q.direction * q.max_range_m);
  const std::array<double, 4> box = CoverBox();
  const auto inside = [&](const Vec2& p) {
    return p.x() >= box[0] && p.y() >= box[1] && p.x() <= box[2] && p.y() <= box[3];
  };
  return inside(a) && inside(b);
}

bool WindowKernelAvailable(WindowKernel kernel) {
  switch (kernel) {
    case WindowKernel::kAvx512:
      return wide::Avx512Supported();
    case WindowKernel::kAvx2:
      return wide::Avx2Supported();
    default:
      return true;
  }
}

namespace {

/// What kBest runs here.
WindowKernel BestKernel() {
  static const WindowKernel best = [] {
    // SLAM_RAY_KERNEL=portable|avx2|avx512 caps the choice (to compare kernels, or to rule one
    // out); tools report the kernel that runs.
    const char* cap = std::getenv("SLAM_RAY_KERNEL");
    const std::string wanted = cap != nullptr ? cap : "avx512";
    if (wanted == "portable") return WindowKernel::kPortable;
    if (wanted != "avx2" && WindowKernelAvailable(WindowKernel::kAvx512))
      return WindowKernel::kAvx512;
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

void CastToObstacles(const MatchWindow& window, const std::vector<RayQuery>& rays,
                     std::vector<RayHit>& hits, WindowKernel kernel) {
  const OccupancyGrid& grid = window.grid();
  const WindowField field(window);
  const auto through_grid = [&](const RayQuery& q) {
    return CastToObstacle(grid, q.origin, q.direction, q.max_range_m, window.occupied_above());
  };
  if (kernel == WindowKernel::kBest) kernel = BestKernel();
  if (kernel == WindowKernel::kAvx512 && WindowKernelAvailable(kernel)) {
    wide::CastAvx512(window, rays, hits);
    return;
  }
  if (kernel == WindowKernel::kAvx2 && WindowKernelAvailable(kernel)) {
    wide::CastAvx2(window, rays, hits);
    return;
  }
  CastInPairs(
      field, grid.geometry(), rays, hits, [&](const RayQuery& q) { return window.Covers(q); },
      [&](const RayQuery& q) {
        return window.Covers(q) ? CastOne(field, grid.geometry(), q) : through_grid(q);
      });
}

int ApplyUpdateRay(OccupancyGrid& grid, const Vec2& origin, double angle,
                   const UpdateProfile& profile) {
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
                  const int delta =
                      profile.delta[std::min(static_cast<size_t>(exit_m * inv_step), size - 1)];
                  if (delta == 0) return true;
                  const TileIndex t = GridGeometry::TileOf(c);
                  if (cached == nullptr || !(t == cached_index)) {
                    if (!InMapBound(t)) return true;  // never written: the map is bounded
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
