#include "engine/occupancy_grid.hpp"

#include <algorithm>
#include <atomic>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "engine/avx2_dispatch.hpp"

#if defined(__SANITIZE_THREAD__)  // GCC
#define SLAM_THREAD_SANITIZER 1
#elif defined(__has_feature)  // Clang
#if __has_feature(thread_sanitizer)
#define SLAM_THREAD_SANITIZER 1
#endif
#endif

namespace slam {
namespace {

// use_count() is a relaxed load: reading 1 says that the other owners are gone, not that what
// they did with the tile (another particle's thread copying it on write, a server thread reading
// a snapshot) happens before our writes. Each of them let go with a release (the acq_rel
// decrement of the count); this is the matching acquire.
void AcquireSoleOwnership([[maybe_unused]] const std::shared_ptr<Tile>& slot) {
#if defined(SLAM_THREAD_SANITIZER)
  // ThreadSanitizer does not model fences: the same acquire through a read-modify-write of the
  // count (an increment, then the acq_rel decrement).
  std::shared_ptr<Tile>(slot).reset();
#else
  std::atomic_thread_fence(std::memory_order_acquire);
#endif
}

}  // namespace

OccupancyGrid::OccupancyGrid(const GridGeometry& geometry, int limit,
                             std::shared_ptr<VersionClock> clock)
    : geometry_(geometry), limit_(std::clamp(limit, 1, kLogOddsLimit)), clock_(std::move(clock)) {}

// A copy shares tiles and the clock, but starts its own write epoch so that its changes get
// versions distinct from the original's.
OccupancyGrid::OccupancyGrid(const OccupancyGrid& other)
    : geometry_(other.geometry_),
      limit_(other.limit_),
      clock_(other.clock_),
      origin_(other.origin_),
      width_(other.width_),
      height_(other.height_),
      slots_(other.slots_) {}

OccupancyGrid& OccupancyGrid::operator=(const OccupancyGrid& other) {
  if (this != &other) {
    OccupancyGrid copy(other);
    *this = std::move(copy);
  }
  return *this;
}

void OccupancyGrid::BeginWrite() { write_version_ = clock_->fetch_add(1) + 1; }

Tile& OccupancyGrid::MutableTile(TileIndex t) {
  if (!InMapBound(t)) {
    throw std::out_of_range("tile (" + std::to_string(t.x) + ", " + std::to_string(t.y) +
                            ") is outside the map's bound of " + std::to_string(kMapTileBound) +
                            " tiles around the origin");
  }
  EnsureCovers(t);
  auto& slot = slots_[static_cast<size_t>((t.y - origin_.y) * width_ + (t.x - origin_.x))];
  if (write_version_ == 0) BeginWrite();
  if (!slot) {
    slot = std::make_shared<Tile>();
  } else if (slot.use_count() > 1) {
    slot = std::make_shared<Tile>(*slot);  // copy on write
  } else {
    AcquireSoleOwnership(slot);
  }
  slot->version = write_version_;
  slot->clearance_known_stale = false;
  slot->occupied_blocks.store(kUnknownSummary,
                              std::memory_order_relaxed);  // being written (held alone)
  return *slot;
}

void OccupancyGrid::EnsureCovers(TileIndex t) {
  if (width_ > 0 && t.x >= origin_.x && t.y >= origin_.y && t.x < origin_.x + width_ &&
      t.y < origin_.y + height_) {
    return;
  }
  // Grow to include t with slack on the side that grew, so a robot exploring in one direction
  // triggers O(log n) reallocations.
  constexpr int64_t kSlack = 4;
  int64_t x0 = width_ > 0 ? origin_.x : t.x, y0 = width_ > 0 ? origin_.y : t.y;
  int64_t x1 = width_ > 0 ? origin_.x + width_ : t.x + 1;
  int64_t y1 = width_ > 0 ? origin_.y + height_ : t.y + 1;
  if (t.x < x0) x0 = t.x - std::max(kSlack, width_ / 2);
  if (t.y < y0) y0 = t.y - std::max(kSlack, height_ / 2);
  if (t.x >= x1) x1 = t.x + 1 + std::max(kSlack, width_ / 2);
  if (t.y >= y1) y1 = t.y + 1 + std::max(kSlack, height_ / 2);
  const int64_t w = x1 - x0, h = y1 - y0;
  std::vector<std::shared_ptr<Tile>> slots(static_cast<size_t>(w * h));
  for (int64_t v = 0; v < height_; ++v) {
    for (int64_t u = 0; u < width_; ++u) {
      const int64_t nu = origin_.x + u - x0, nv = origin_.y + v - y0;
      slots[static_cast<size_t>(nv * w + nu)] =
          std::move(slots_[static_cast<size_t>(v * width_ + u)]);
    }
  }
  slots_ = std::move(slots);
  origin_ = {static_cast<int32_t>(x0), static_cast<int32_t>(y0)};
  width_ = w;
  height_ = h;
}

std::array<uint64_t, kTileSize> ComputeOccupiedRows(const Tile& tile) {
  std::array<uint64_t, kTileSize> rows{};
  for (int y = 0; y < kTileSize; ++y) {
    const LogOdds* row = tile.cells.data() + y * kTileSize;
    uint64_t bits = 0;
    for (int x = 0; x < kTileSize; ++x) bits |= uint64_t{row[x] > kSummaryThreshold} << x;
    rows[static_cast<size_t>(y)] = bits;
  }
  return rows;
}

uint64_t OccupiedBlocks(const std::array<uint64_t, kTileSize>& rows) {
  uint64_t mask = 0;
  for (int by = 0; by < kBlocksPerSide; ++by) {
    uint64_t any = 0;
    for (int i = 0; i < kBlockSize; ++i) any |= rows[static_cast<size_t>(by * kBlockSize + i)];
    for (int bx = 0; bx < kBlocksPerSide; ++bx) {
      if (((any >> (bx * kBlockSize)) & 0xFF) != 0)
        mask |= uint64_t{1} << (by * kBlocksPerSide + bx);
    }
  }
  return mask;
}

namespace {

SLAM_AVX2_BODY void RelaxRowBody(uint8_t* row, size_t width, bool from_below, bool from_above,
                                 std::vector<uint8_t>& scratch) {
  // Doubling the offset (1, 2, ..., 64) instead of one sequential scan each way: the same
  // minimum, in loops without a carried dependency. Each pass reads one copy of the row and
  // writes the other; the copies are padded with far cells on both sides, which never lower a
  // value (row values are <= kClearanceFar, so a padded value plus 64 still fits a byte), so
  // every pass is one uniform loop over the row (they vectorise).
  constexpr size_t kPad = 64;  // the farthest offset a pass reads
  const size_t stride = width + 2 * kPad;
  if (scratch.size() < 2 * stride) scratch.resize(2 * stride);
  uint8_t* src = scratch.data() + kPad;
  uint8_t* dst = src + stride;
  for (uint8_t* copy : {src, dst}) {
    std::fill(copy - kPad, copy, kClearanceFar);
    std::fill(copy + width, copy + width + kPad, kClearanceFar);
  }
  std::copy(row, row + width, src);
  for (size_t s = 1; s < width && s <= kPad; s <<= 1) {
    const auto step = static_cast<uint8_t>(s);
    // The row s before and s after (inside the padding): src[x - s] with an unsigned x - s
    // would wrap, which is undefined for a pointer.
    const uint8_t* below = src - s;
    const uint8_t* above = src + s;
    if (from_below && from_above) {
      for (size_t x = 0; x < width; ++x) {
        dst[x] = std::min(src[x], static_cast<uint8_t>(std::min(below[x], above[x]) + step));
      }
    } else if (from_below) {
      for (size_t x = 0; x < width; ++x)
        dst[x] = std::min(src[x], static_cast<uint8_t>(below[x] + step));
    } else if (from_above) {
      for (size_t x = 0; x < width; ++x)
        dst[x] = std::min(src[x], static_cast<uint8_t>(above[x] + step));
    } else {
      break;
    }
    std::swap(src, dst);
  }
  std::copy(src, src + width, row);
}

SLAM_AVX2_COPY void RelaxRowAvx2(uint8_t* row, size_t width, bool from_below, bool from_above,
                                 std::vector<uint8_t>& scratch) {
  RelaxRowBody(row, width, from_below, from_above, scratch);
}

}  // namespace

void RelaxRow(uint8_t* row, size_t width, bool from_below, bool from_above,
              std::vector<uint8_t>& scratch) {
  if (SLAM_AVX2_AVAILABLE()) return RelaxRowAvx2(row, width, from_below, from_above, scratch);
  RelaxRowBody(row, width, from_below, from_above, scratch);
}

namespace {

/// row[x] = min(row[x], near[x - 1] + 1, near[x] + 1, near[x + 1] + 1): the row next to it.
/// `scratch` holds `width` bytes.
void RelaxFromRow(uint8_t* row, const uint8_t* near, uint8_t* scratch, size_t width) {
  std::copy(near, near + width, scratch);
  for (size_t x = 1; x < width; ++x) scratch[x] = std::min(scratch[x], near[x - 1]);
  for (size_t x = 0; x + 1 < width; ++x) scratch[x] = std::min(scratch[x], near[x + 1]);
  for (size_t x = 0; x < width; ++x)
    row[x] = std::min(row[x], static_cast<uint8_t>(scratch[x] + 1));
}

/// In place on a width x height array (0 on occupied cells, kClearanceFar elsewhere): the
/// chessboard distance of every cell to the nearest occupied one (kClearanceFar when none).
void ChessboardDistance(uint8_t* d, int width, int height) {
  // Two-pass chamfer transform with the 3 x 3 mask of unit weights, exact for the chessboard
  // distance (values stay below 127 + 64, so uint8_t never wraps): downwards from the row
  // above and along the row, then upwards from the row below and along the row. Relaxing
  // along a row both ways in each pass reaches the same fixed point as the classic one-way
  // scans, since every path it adds is also a valid chessboard path.
  if (width <= 0 || height <= 0) return;
  const auto w = static_cast<size_t>(width), h = static_cast<size_t>(height);
  std::vector<uint8_t> near(w), scratch;
  for (size_t y = 0; y < h; ++y) {
    if (y > 0) RelaxFromRow(d + y * w, d + (y - 1) * w, near.data(), w);
    RelaxRow(d + y * w, w, true, true, scratch);
  }
  for (size_t y = h - 1; y-- > 0;) {
    RelaxFromRow(d + y * w, d + (y + 1) * w, near.data(), w);
    RelaxRow(d + y * w, w, true, true, scratch);
  }
}

}  // namespace

void ComputeClearance(const std::array<uint64_t, kTileSize>& rows,
                      std::array<uint8_t, kTileCells>& clearance) {
  for (size_t y = 0; y < kTileSize; ++y) {
    for (size_t x = 0; x < kTileSize; ++x) {
      clearance[y * kTileSize + x] = ((rows[y] >> x) & 1) != 0 ? 0 : kClearanceFar;
    }
  }
  ChessboardDistance(clearance.data(), kTileSize, kTileSize);
}

void OccupancyGrid::RefreshSummaries(bool clearance) {
  for (auto& slot : slots_) {
    if (!slot || slot->occupied_blocks.load(std::memory_order_acquire) != kUnknownSummary) continue;
    if (!clearance && slot->clearance_known_stale) continue;
    const std::array<uint64_t, kTileSize> rows = ComputeOccupiedRows(*slot);
    const uint64_t mask = OccupiedBlocks(rows);
    const bool stale_clearance =
        mask != 0 && !(slot->has_clearance && rows == slot->clearance_rows);
    // Only this grid may change a tile it holds alone (a count of 1 cannot grow meanwhile:
    // only this grid could copy the reference).
    const bool alone = slot.use_count() == 1;
    if (stale_clearance && !clearance) {
      if (alone) {
        AcquireSoleOwnership(slot);
        slot->clearance_known_stale = true;
      }
      continue;
    }
    if (alone) {
      AcquireSoleOwnership(slot);  // another grid's copy of it, made before it let go, is done
    } else {
      slot = std::make_shared<Tile>(*slot);
    }
    Tile& tile = *slot;
    if (stale_clearance) {
      ComputeClearance(rows, tile.clearance);
      tile.clearance_rows = rows;
      tile.has_clearance = true;
    }
    tile.occupied_blocks.store(mask, std::memory_order_release);
  }
}

std::vector<TileRef> OccupancyGrid::Tiles() const {
  std::vector<TileRef> tiles;
  for (int64_t v = 0; v < height_; ++v) {
    for (int64_t u = 0; u < width_; ++u) {
      const auto& slot = slots_[static_cast<size_t>(v * width_ + u)];
      if (slot) {
        tiles.push_back(
            {{static_cast<int32_t>(origin_.x + u), static_cast<int32_t>(origin_.y + v)}, slot});
      }
    }
  }
  return tiles;
}

int OccupancyGrid::TileCount() const {
  return static_cast<int>(
      std::count_if(slots_.begin(), slots_.end(), [](const auto& s) { return s != nullptr; }));
}

uint64_t OccupancyGrid::Version() const {
  uint64_t version = 0;
  for (const auto& slot : slots_) {
    if (slot) version = std::max(version, slot->version);
  }
  return version;
}

bool OccupancyGrid::SharesTileWith(const OccupancyGrid& other, TileIndex t) const {
  const Tile* mine = FindTile(t);
  return mine != nullptr && mine == other.FindTile(t);
}

}  // namespace slam
