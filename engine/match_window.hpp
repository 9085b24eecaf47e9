#pragma once
// The match window: one particle's neighbourhood with its free squares, through which its
// matching rays jump, and the kernels that cast them (portable, AVX2, AVX-512, picked at run
// time; the same answers, bit for bit).

#include <array>
#include <cstdint>
#include <vector>

#include "engine/grid_geometry.hpp"
#include "engine/matching_rays.hpp"
#include "engine/occupancy_grid.hpp"

namespace slam {

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

}  // namespace slam
