#include "engine/match_window.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "engine/avx2_dispatch.hpp"
#include "engine/fast_ray.hpp"
#include "engine/ray_cast_wide.hpp"

namespace slam {

namespace {

/// MatchWindow's free squares of the four quadrants (see its constructor) from `free` (0 on
/// occupied cells), w x h cells, into `squares` (4 w h bytes).
SLAM_AVX2_BODY void BuildFreeSquaresBody(const uint8_t* free, uint8_t* squares, size_t w,
                                         size_t h) {
  std::vector<uint8_t> scratch;
  for (size_t quadrant = 0; quadrant < 4; ++quadrant) {
    const bool back_x = (quadrant & 1) != 0, back_y = (quadrant & 2) != 0;
    uint8_t* q = squares + quadrant * w * h;
    for (size_t i = 0; i < h; ++i) {
      const size_t y = back_y ? i : h - 1 - i;
      uint8_t* row = q + y * w;
      const uint8_t* occupancy = free + y * w;
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

SLAM_AVX2_COPY void BuildFreeSquaresAvx2(const uint8_t* free, uint8_t* squares, size_t w,
                                         size_t h) {
  BuildFreeSquaresBody(free, squares, w, h);
}

void BuildFreeSquares(const uint8_t* free, uint8_t* squares, size_t w, size_t h) {
  if (SLAM_AVX2_AVAILABLE()) return BuildFreeSquaresAvx2(free, squares, w, h);
  BuildFreeSquaresBody(free, squares, w, h);
}

}  // namespace

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
  BuildFreeSquares(free.data(), squares_.data(), w, h);
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

}  // namespace slam
