#pragma once
// Ray casting on the occupancy grid: the unit of cost that the ray budget counts.
//
// Traversal is exact (Amanatides & Woo): a ray visits, in order, every cell whose interior it
// crosses. Conventions, relied upon by the tests:
//  - a ray passing exactly through a cell corner steps diagonally (neither side cell is visited);
//  - a ray running exactly along a grid line belongs to the cells above / right of that line
//    (cells are half-open, [i*r, (i+1)*r));
//  - cells crossed over zero length (a ray starting on a boundary and leaving it) are not visited.

#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "engine/grid_geometry.hpp"
#include "engine/occupancy_grid.hpp"

namespace slam {

/// Amanatides & Woo traversal state, in cell units along the ray: the current cell and the
/// times of the next x and y boundary crossings. The matching rays' fast path (ray_cast.cpp)
/// starts in the same cell and uses the same crossing expressions and corner tolerance.
struct GridWalk {
  static constexpr double kInf = std::numeric_limits<double>::infinity();
  static constexpr double kCornerEpsilon = 1e-9;

  Vec2 p;  // origin in grid coordinates
  int step_x = 0, step_y = 0;
  double delta_x = kInf, delta_y = kInf;  // time to cross one cell along x / y
  int32_t cx = 0, cy = 0;
  double next_x = kInf, next_y = kInf;
  double t = 0.0;  // when the ray entered the current cell

  /// Starts in the cell holding `grid_origin`. Precondition: direction has unit length.
  GridWalk(const Vec2& grid_origin, const Vec2& direction) : p(grid_origin) {
    const double dx = direction.x(), dy = direction.y();
    step_x = dx > 0 ? 1 : (dx < 0 ? -1 : 0);
    step_y = dy > 0 ? 1 : (dy < 0 ? -1 : 0);
    delta_x = step_x != 0 ? 1.0 / std::abs(dx) : kInf;
    delta_y = step_y != 0 ? 1.0 / std::abs(dy) : kInf;
    Enter(static_cast<int32_t>(std::floor(p.x())), static_cast<int32_t>(std::floor(p.y())), 0.0);
  }

  /// Moves to cell (x, y), entered at time `time`; the next crossings in closed form.
  void Enter(int32_t x, int32_t y, double time) {
    cx = x;
    cy = y;
    t = time;
    next_x = step_x > 0 ? (cx + 1 - p.x()) * delta_x : step_x < 0 ? (p.x() - cx) * delta_x : kInf;
    next_y = step_y > 0 ? (cy + 1 - p.y()) * delta_y : step_y < 0 ? (p.y() - cy) * delta_y : kInf;
  }

  /// When the ray leaves the current cell.
  double NextCrossing() const { return std::min(next_x, next_y); }

  /// Into the next cell: diagonally when both crossings coincide (a corner), else across the
  /// nearer boundary.
  void Step() {
    const double t_next = NextCrossing();
    if (std::abs(next_x - next_y) <= kCornerEpsilon * (1.0 + t_next)) {
      cx += step_x;
      cy += step_y;
      t = t_next;
      next_x += delta_x;
      next_y += delta_y;
    } else if (next_x < next_y) {
      cx += step_x;
      t = next_x;
      next_x += delta_x;
    } else {
      cy += step_y;
      t = next_y;
      next_y += delta_y;
    }
  }
};

/// Visits the cells crossed by the segment from `origin` (metres) along the unit vector
/// `direction` over `length_m`, calling visit(CellIndex, double enter_m, double exit_m) -> bool
/// in order; visiting stops when it returns false. Returns the number of cells visited.
/// Preconditions: direction has unit length; length_m >= 0 and finite.
template <typename Visitor>
int TraverseCells(const GridGeometry& geometry, const Vec2& origin, const Vec2& direction,
                  double length_m, Visitor&& visit) {
  const double res = geometry.resolution();
  const double length = length_m / res;
  GridWalk walk(geometry.ToGrid(origin), direction);
  int visited = 0;
  while (true) {
    const double t_next = walk.NextCrossing();
    const double t_exit = std::min(t_next, length);
    if (t_exit > walk.t || (length == 0.0 && visited == 0)) {
      ++visited;
      if (!visit(CellIndex{walk.cx, walk.cy}, walk.t * res, t_exit * res)) break;
    }
    if (t_next >= length) break;
    walk.Step();
  }
  return visited;
}

/// The cells a segment crosses, in order (for tests and tools; the hot paths use TraverseCells).
std::vector<CellIndex> CellsOnRay(const GridGeometry& geometry, const Vec2& from, const Vec2& to);

/// What a matching ray found.
struct RayHit {
  double distance_m = 0.0;  // to the entry of the first occupied cell, or the maximum range
  double exit_m = 0.0;      // where the ray leaves that cell (equals distance_m when no hit)
  bool hit = false;         // false: nothing occupied within the maximum range
  int cells = 0;            // cells visited (work done)
  int jumps = 0;            // jumps over empty space (work done by the fast path)
};

/// Matching ray: from `origin` along the unit vector `direction` to the first cell whose log
/// odds exceed `occupied_above`, up to `max_range_m`. Reads only; safe to call concurrently on
/// one grid. Jumps over missing tiles and tiles free of cells above kSummaryThreshold, and
/// inside other tiles moves by their clearance (chessboard distance to the nearest such cell)
/// whenever it exceeds one cell; so for occupied_above >= kSummaryThreshold (below it, and in
/// tiles written since the grid's last RefreshSummaries, this is the cell-by-cell traversal).
/// It finds the same first occupied cell as CastToObstaclePlain; distances agree to rounding
/// (after each jump the traversal restarts from closed-form crossing times).
RayHit CastToObstacle(const OccupancyGrid& grid, const Vec2& origin, const Vec2& direction,
                      double max_range_m, LogOdds occupied_above);

/// One matching ray of a batch.
struct RayQuery {
  Vec2 origin;
  Vec2 direction;  // unit length
  double max_range_m = 0.0;
};

/// CastToObstacle for every ray of `rays` (the same answers, into hits[i]), several rays in
/// flight at once: the processor overlaps their independent chains of loads. `hits` is resized.
void CastToObstacles(const OccupancyGrid& grid, const std::vector<RayQuery>& rays,
                     LogOdds occupied_above, std::vector<RayHit>& hits);

/// The cells around one pose that a particle's matching rays run through, with, for each cell
/// and each quadrant a ray can move towards, the side of the largest square of free cells
/// (none above a threshold) with that cell as its corner: a ray in the cell crosses free cells
/// only until it leaves that square, which spans tile edges (a tile's own clearance ends at
/// its edge) and ignores what lies behind the ray. Rays cast through it read one byte per
/// jump. Building it reads every cell of the window once, so it pays where many rays share it
/// (the engine builds one per particle and scan when they are enough). Reads the grid when
/// built and for rays it does not cover: the grid must outlive it, unchanged.
class MatchWindow {
 public:
  /// The window of cells [lo, hi] (inclusive) of `grid`, for rays stopping at cells above
  /// `occupied_above` (any threshold: unknown cells, 0, count as occupied below 0).
  MatchWindow(const OccupancyGrid& grid, LogOdds occupied_above, CellIndex lo, CellIndex hi);

  /// Whether a ray runs inside the window from start to end (else it is cast through the grid):
  /// a positive, finite range, and both ends at least kCoverMargin cells inside its edges.
  bool Covers(const RayQuery& ray) const;
  /// The cells a ray crosses lie between the cells of its ends, and the traversal may step one
  /// cell beyond (a crossing within its corner tolerance of the end): hence two cells.
  static constexpr double kCoverMargin = 2.0;
  /// Where both ends of a ray the window covers lie, in grid coordinates (cells): kCoverMargin
  /// inside its edges, as {x_min, y_min, x_max, y_max} (inclusive).
  std::array<double, 4> CoverBox() const {
    return {static_cast<double>(x0_) + kCoverMargin, static_cast<double>(y0_) + kCoverMargin,
            static_cast<double>(x0_ + width_) - kCoverMargin,
            static_cast<double>(y0_ + height_) - kCoverMargin};
  }
  /// The side of the largest square of free cells [x, x + k) x [y, y + k), with x growing
  /// towards -x when back_x (cells x - k + 1 .. x) and y likewise, capped at kClearanceFar;
  /// cells beyond the window count as free. 0 on a cell above the threshold. Precondition:
  /// c is inside the window.
  int FreeSquareAt(CellIndex c, bool back_x, bool back_y) const {
    return squares_[static_cast<size_t>((back_x ? 1 : 0) + (back_y ? 2 : 0)) *
                        static_cast<size_t>(cells()) +
                    static_cast<size_t>(IndexOf(c))];
  }
  /// The four quadrants' squares (forward, back in x, back in y, back in both), each
  /// row-major from the window's lower-left cell; cell c at IndexOf(c) of each. Followed by
  /// kFreeSquaresPadding readable bytes (a wide kernel loads 4 bytes where it needs one).
  const uint8_t* free_squares() const { return squares_.data(); }
  static constexpr size_t kFreeSquaresPadding = 3;
  int64_t IndexOf(CellIndex c) const {
    return (int64_t{c.y} - y0_) * width_ + (int64_t{c.x} - x0_);
  }
  int64_t width() const { return width_; }
  int64_t height() const { return height_; }
  /// The window's lower-left cell.
  CellIndex lo() const { return {x0_, y0_}; }

  const OccupancyGrid& grid() const { return *grid_; }
  LogOdds occupied_above() const { return occupied_above_; }
  int64_t cells() const { return width_ * height_; }

 private:
  const OccupancyGrid* grid_;
  LogOdds occupied_above_;
  int32_t x0_, y0_;
  int64_t width_, height_;
  std::vector<uint8_t> squares_;
};

/// How CastToObstacles casts the rays a MatchWindow covers; the answers are the same, bit for bit.
enum class WindowKernel {
  kBest,      // the fastest this processor runs: kAvx512, else kAvx2, else kPortable (the
              // environment variable SLAM_RAY_KERNEL=portable|avx2 caps it)
  kPortable,  // two rays in flight (any processor)
  kAvx2,      // four rays per instruction (x86-64 with AVX2)
  kAvx512,    // eight rays per instruction (x86-64 with AVX-512F/VL and BMI2)
};

/// Whether this build and this processor run `kernel` (kBest and kPortable always).
bool WindowKernelAvailable(WindowKernel kernel);
/// What WindowKernel::kBest runs here, as tools report it: "avx512", "avx2" or "portable".
const char* BestWindowKernelName();

/// CastToObstacles(window.grid(), rays, window.occupied_above(), hits), the same answers, with
/// the rays the window covers cast through its free squares by `kernel` (kPortable where this
/// processor lacks it).
void CastToObstacles(const MatchWindow& window, const std::vector<RayQuery>& rays,
                     std::vector<RayHit>& hits, WindowKernel kernel = WindowKernel::kBest);

/// The same along `angle` (radians).
inline RayHit CastToObstacle(const OccupancyGrid& grid, const Vec2& origin, double angle,
                             double max_range_m, LogOdds occupied_above) {
  return CastToObstacle(grid, origin, Vec2(std::cos(angle), std::sin(angle)), max_range_m,
                        occupied_above);
}

/// The same, cell by cell through every cell the ray crosses (the oracle of the tests).
RayHit CastToObstaclePlain(const OccupancyGrid& grid, const Vec2& origin, const Vec2& direction,
                           double max_range_m, LogOdds occupied_above);

inline RayHit CastToObstaclePlain(const OccupancyGrid& grid, const Vec2& origin, double angle,
                                  double max_range_m, LogOdds occupied_above) {
  return CastToObstaclePlain(grid, origin, Vec2(std::cos(angle), std::sin(angle)), max_range_m,
                             occupied_above);
}

/// The log-odds change along an update ray, by distance from the sensor, in bins of step_m.
/// `delta` must be non-decreasing (free, then occupied). A crossed cell takes the value at the far
/// end of its crossing, which is the largest over the crossing: the cell holding the measured
/// point is always occupied, whatever the angle. The ray stops at the end of the table.
struct UpdateProfile {
  double step_m = 0.0;
  std::vector<int16_t> delta;
  double length_m() const { return step_m * static_cast<double>(delta.size()); }
};

/// Update ray: applies `profile` along the ray from `origin` in direction `angle`.
/// Returns the number of cells changed.
int ApplyUpdateRay(OccupancyGrid& grid, const Vec2& origin, double angle,
                   const UpdateProfile& profile);

}  // namespace slam
