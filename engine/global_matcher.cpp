#include "engine/global_matcher.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>
#include <utility>

namespace slam {

namespace {

/// In place over rows [v_begin, v_end), each cell the larger of itself and the cell `half`
/// further along one axis: from a view of windows `half` wide along that axis, the view of
/// windows twice as wide. Rows in increasing order read only cells not yet changed.
void WindowMax(std::vector<uint8_t>& view, int64_t width, int64_t height, int64_t half,
               bool along_x, int64_t v_begin, int64_t v_end) {
  for (int64_t v = v_begin; v < v_end; ++v) {
    for (int64_t u = 0; u < width; ++u) {
      const int64_t u2 = along_x ? u + half : u, v2 = along_x ? v : v + half;
      if (u2 >= width || v2 >= height) continue;
      uint8_t& cell = view[static_cast<size_t>(v * width + u)];
      cell = std::max(cell, view[static_cast<size_t>(v2 * width + u2)]);
    }
  }
}

}  // namespace

MatchField MatchField::FromGrid(const OccupancyGrid& grid, const MatchFieldConfig& config) {
  MatchFieldBuild build(grid, config);
  build.Finish();
  return *build.field();
}

MatchFieldBuild::MatchFieldBuild(const OccupancyGrid& grid, const MatchFieldConfig& config)
    : config_(config),
      map_cells_(grid.geometry()),
      field_cells_(config.resolution_m),
      tiles_(grid.Tiles()) {
  assert(config.resolution_m > 0 && config.sigma_m > 0);
  assert(config.levels >= 0 && config.levels <= 12);
}

void MatchFieldBuild::Finish() {
  while (!done()) ops_ += Step();
}

bool MatchFieldBuild::Continue(int64_t max_lookups) {
  const int64_t until = ops_ + std::max<int64_t>(max_lookups, 1) * kCellOpsPerLookup;
  do {
    if (done()) break;
    ops_ += Step();
  } while (ops_ < until);
  return done();
}

int64_t MatchFieldBuild::Step() {
  switch (stage_) {
    case Stage::kMark:
      return next_tile_ < tiles_.size() ? MarkTile() : StartStamping();
    case Stage::kClear:
      return ClearRow();
    case Stage::kStamp:
      return StampCells();
    case Stage::kViews:
      return ViewRow();
    case Stage::kDone:
      break;
  }
  return 0;
}

int64_t MatchFieldBuild::MarkTile() {
  // The field cells holding an occupied map cell (its centre inside them), once per tile.
  const TileRef& ref = tiles_[next_tile_++];
  const CellIndex first = GridGeometry::TileOrigin(ref.index);
  tile_cells_.clear();
  for (int j = 0; j < kTileSize; ++j) {
    for (int i = 0; i < kTileSize; ++i) {
      if (ref.tile->cells[static_cast<size_t>(j * kTileSize + i)] <= config_.occupied_above) {
        continue;
      }
      tile_cells_.push_back(field_cells_.CellOf(map_cells_.CellCenter({first.x + i, first.y + j})));
    }
  }
  std::sort(tile_cells_.begin(), tile_cells_.end(), [](const CellIndex& a, const CellIndex& b) {
    return a.y != b.y ? a.y < b.y : a.x < b.x;
  });
  tile_cells_.erase(std::unique(tile_cells_.begin(), tile_cells_.end()), tile_cells_.end());
  for (const CellIndex& c : tile_cells_) {
    if (occupied_.empty()) lo_ = hi_ = c;
    lo_ = {std::min(lo_.x, c.x), std::min(lo_.y, c.y)};
    hi_ = {std::max(hi_.x, c.x), std::max(hi_.y, c.y)};
    occupied_.push_back(c);
  }
  // A read and a compare per cell; a sort's few comparisons per occupied one.
  return int64_t{kTileCells} + 8 * static_cast<int64_t>(tile_cells_.size());
}

int64_t MatchFieldBuild::StartStamping() {
  const double res = config_.resolution_m;
  if (occupied_.empty()) {  // an empty field: every score 0
    result_ = std::make_shared<const MatchField>(
        MatchField::FromScores(res, {0, 0}, 0, 0, {}, config_.levels));
    stage_ = Stage::kDone;
    return 1;
  }
  // Each occupied cell stamps a Gaussian of the distance between cell centres; a cell keeps
  // the largest stamp (the nearest occupied cell's).
  reach_ = static_cast<int>(std::ceil(3.0 * config_.sigma_m / res));
  const int side = 2 * reach_ + 1;
  kernel_.assign(static_cast<size_t>(side * side), 0);
  for (int dy = -reach_; dy <= reach_; ++dy) {
    for (int dx = -reach_; dx <= reach_; ++dx) {
      const double d2 = (dx * dx + dy * dy) * res * res;
      kernel_[static_cast<size_t>((dy + reach_) * side + dx + reach_)] = static_cast<uint8_t>(
          std::lround(255.0 * std::exp(-d2 / (2 * config_.sigma_m * config_.sigma_m))));
    }
  }
  // The scored cells span the occupied ones and the kernel's reach; the views reach
  // 2^levels - 1 cells below them (a window starting there still covers a scored cell).
  MatchField& f = field_;
  f.resolution_ = res;
  f.empty_ = false;  // the kernel's centre scores 255
  f.pad_ = (int32_t{1} << config_.levels) - 1;
  f.origin_ = {lo_.x - reach_ - f.pad_, lo_.y - reach_ - f.pad_};
  f.width_ = int64_t{hi_.x} + reach_ + 1 - (lo_.x - reach_) + f.pad_;
  f.height_ = int64_t{hi_.y} + reach_ + 1 - (lo_.y - reach_) + f.pad_;
  // The base view is cleared a row a step (ClearRow), so that no step costs a whole view.
  f.views_.assign(1, {});
  f.views_[0].reserve(static_cast<size_t>(f.width_ * f.height_));
  stage_ = Stage::kClear;
  return static_cast<int64_t>(kernel_.size());
}

int64_t MatchFieldBuild::ClearRow() {
  std::vector<uint8_t>& base = field_.views_[0];
  base.resize(base.size() + static_cast<size_t>(field_.width_), 0);
  if (base.size() == static_cast<size_t>(field_.width_ * field_.height_)) stage_ = Stage::kStamp;
  return field_.width_;
}

int64_t MatchFieldBuild::StampCells() {
  MatchField& f = field_;
  const int side = 2 * reach_ + 1;
  std::vector<uint8_t>& base = f.views_[0];
  constexpr size_t kCellsPerStep = 16;
  const size_t end = std::min(occupied_.size(), next_occupied_ + kCellsPerStep);
  for (; next_occupied_ < end; ++next_occupied_) {
    const CellIndex& c = occupied_[next_occupied_];
    for (int dy = -reach_; dy <= reach_; ++dy) {
      uint8_t* row = &base[static_cast<size_t>((int64_t{c.y} + dy - f.origin_.y) * f.width_ +
                                               (int64_t{c.x} - reach_ - f.origin_.x))];
      const uint8_t* k = &kernel_[static_cast<size_t>((dy + reach_) * side)];
      for (int i = 0; i < side; ++i) row[i] = std::max(row[i], k[i]);
    }
  }
  const int64_t ops = static_cast<int64_t>(kCellsPerStep) * side * side;
  if (next_occupied_ == occupied_.size()) {
    occupied_ = {};
    level_ = 1;
    along_y_ = false;
    row_ = 0;
    stage_ = config_.levels > 0 ? Stage::kViews : Stage::kDone;
    if (stage_ == Stage::kDone) result_ = std::make_shared<const MatchField>(std::move(field_));
  }
  return ops;
}

int64_t MatchFieldBuild::ViewRow() {
  MatchField& f = field_;
  int64_t ops = f.width_;
  if (!along_y_) {  // a new view, copied from the one below a row at a time
    if (row_ == 0) {
      f.views_.emplace_back();
      f.views_.back().reserve(static_cast<size_t>(f.width_ * f.height_));
    }
    const std::vector<uint8_t>& below = f.views_[f.views_.size() - 2];
    const auto from = below.begin() + static_cast<std::ptrdiff_t>(row_ * f.width_);
    f.views_.back().insert(f.views_.back().end(), from,
                           from + static_cast<std::ptrdiff_t>(f.width_));
    ops += f.width_;
  }
  const int64_t half = int64_t{1} << (level_ - 1);
  WindowMax(f.views_.back(), f.width_, f.height_, half, /*along_x=*/!along_y_, row_, row_ + 1);
  if (++row_ < f.height_) return ops;
  row_ = 0;
  if (!along_y_) {
    along_y_ = true;
  } else if (++level_ <= config_.levels) {
    along_y_ = false;
  } else {
    result_ = std::make_shared<const MatchField>(std::move(field_));
    stage_ = Stage::kDone;
  }
  return ops;
}

MatchField MatchField::FromScores(double resolution_m, CellIndex origin, int width, int height,
                                  std::vector<uint8_t> scores, int levels) {
  assert(levels >= 0 && levels <= 12);
  assert(scores.size() == static_cast<size_t>(width) * static_cast<size_t>(height));
  MatchField field;
  field.resolution_ = resolution_m;
  field.empty_ = std::none_of(scores.begin(), scores.end(), [](uint8_t s) { return s > 0; });
  // The views reach 2^levels - 1 cells below the scores: a window starting there still covers
  // a scored cell.
  field.pad_ = (int32_t{1} << levels) - 1;
  field.origin_ = {origin.x - field.pad_, origin.y - field.pad_};
  field.width_ = int64_t{width} + field.pad_;
  field.height_ = int64_t{height} + field.pad_;
  std::vector<uint8_t> base(static_cast<size_t>(field.width_ * field.height_), 0);
  for (int v = 0; v < height; ++v) {
    std::copy_n(&scores[static_cast<size_t>(v) * static_cast<size_t>(width)], width,
                &base[static_cast<size_t>((v + field.pad_) * field.width_ + field.pad_)]);
  }
  field.views_.push_back(std::move(base));
  field.BuildViews(levels);
  return field;
}

void MatchField::BuildViews(int levels) {
  for (int k = 1; k <= levels; ++k) {
    std::vector<uint8_t> view = views_.back();
    const int64_t half = int64_t{1} << (k - 1);
    WindowMax(view, width_, height_, half, /*along_x=*/true, 0, height_);
    WindowMax(view, width_, height_, half, /*along_x=*/false, 0, height_);
    views_.push_back(std::move(view));
  }
}

GlobalSearch::GlobalSearch(std::shared_ptr<const MatchField> field, std::vector<Vec2> points,
                           const GlobalRegion& region, const GlobalSearchConfig& config)
    : field_(std::move(field)), config_(config), point_count_(points.size()) {
  const double res = field_->resolution();
  // Field cells as the grid's (GridGeometry::CellOf: floor, saturated far beyond the map).
  const GridGeometry field_cells(res);
  if (config_.turn_about_centroid && region.whole_map && !points.empty()) {
    for (const Vec2& p : points) pivot_ += p;
    pivot_ /= static_cast<double>(points.size());
    for (Vec2& p : points) p -= pivot_;
  }
  double reach = res;
  for (const Vec2& p : points) reach = std::max(reach, p.norm());
  // Headings spaced so that the farthest point moves by about a cell (Olson's, Hess et al.'s).
  const double moved = res * std::max(config_.heading_step_cells, 1e-3);
  const double step = std::acos(std::clamp(1.0 - moved * moved / (2.0 * reach * reach), -1.0, 1.0));
  if (region.half_angle_rad >= kPi) {
    const auto n = static_cast<size_t>(std::ceil(2.0 * kPi / step));
    for (size_t i = 0; i < n; ++i) {
      headings_.push_back(NormalizeAngle(region.heading + 2.0 * kPi * static_cast<double>(i) /
                                                              static_cast<double>(n)));
    }
  } else {
    const auto n = static_cast<int>(std::ceil(region.half_angle_rad / step));
    for (int i = -n; i <= n; ++i) headings_.push_back(NormalizeAngle(region.heading + i * step));
  }
  for (const double theta : headings_) {
    const double c = std::cos(theta), s = std::sin(theta);
    std::vector<CellIndex>& cells = cells_.emplace_back();
    cells.reserve(points.size());
    for (const Vec2& p : points) {
      cells.push_back(field_cells.CellOf({c * p.x() - s * p.y(), s * p.x() + c * p.y()}));
    }
  }
  if (region.whole_map) {
    // Every translation that puts the query frame on a scored cell.
    min_offset_ = field_->min_cell();
    max_offset_ = {field_->max_cell().x - 1, field_->max_cell().y - 1};
  } else {
    const Vec2 half(region.half_width_m, region.half_width_m);
    min_offset_ = field_cells.CellOf(region.center - half);
    max_offset_ = field_cells.CellOf(region.center + half);
  }
  min_raw_ =
      std::max<int64_t>(1, static_cast<int64_t>(std::ceil(config_.min_score * 255.0 *
                                                          static_cast<double>(point_count_))));
  next_top_ = {0, min_offset_.x, min_offset_.y, 0, 0};
  if (point_count_ == 0 || field_->empty() || max_offset_.x < min_offset_.x ||
      max_offset_.y < min_offset_.y) {
    done_ = true;
  }
}

Pose2 GlobalSearch::CandidatePose(size_t h, CellIndex offset) const {
  const double res = field_->resolution();
  // The pivot sits at the offset: the query frame's origin is the pivot's turn back from it.
  const double theta = headings_[h], c = std::cos(theta), si = std::sin(theta);
  return {offset.x * res - (c * pivot_.x() - si * pivot_.y()),
          offset.y * res - (si * pivot_.x() + c * pivot_.y()), theta};
}

int64_t GlobalSearch::Bound(const Node& node) {
  int64_t sum = 0;
  for (const CellIndex& c : cells_[node.heading]) {
    sum += field_->At(node.level, {c.x + node.x, c.y + node.y});
  }
  lookups_ += static_cast<int64_t>(point_count_);
  return sum;
}

int64_t GlobalSearch::Threshold() const {
  // A node must beat unique_ratio of the best and, once as many candidates as wanted are
  // kept, the last of them, to change any; below min_score nothing counts.
  int64_t t = min_raw_ - 1;
  if (!top_.empty()) {
    t = std::max(t, static_cast<int64_t>(
                        std::floor(config_.unique_ratio * static_cast<double>(top_[0].raw))));
  }
  if (top_.size() >= static_cast<size_t>(std::max(config_.candidates, 1))) {
    t = std::max(t, top_.back().raw);
  }
  return t;
}

void GlobalSearch::Offer(const Node& leaf) {
  const auto denominator = 255.0 * static_cast<double>(point_count_);
  top_.push_back({CandidatePose(leaf.heading, {leaf.x, leaf.y}), leaf.bound,
                  static_cast<double>(leaf.bound) / denominator});
  // Best first (the earlier found first on ties), each kept only when distinct from every
  // better one, as many as wanted, none at or below unique_ratio of the best.
  std::stable_sort(top_.begin(), top_.end(),
                   [](const GlobalMatch& a, const GlobalMatch& b) { return a.raw > b.raw; });
  std::vector<GlobalMatch> kept;
  for (const GlobalMatch& m : top_) {
    if (kept.size() >= static_cast<size_t>(std::max(config_.candidates, 1))) break;
    if (!kept.empty() &&
        static_cast<double>(m.raw) <= config_.unique_ratio * static_cast<double>(kept[0].raw)) {
      break;
    }
    if (std::all_of(kept.begin(), kept.end(),
                    [&](const GlobalMatch& k) { return Distinct(k, m, config_); })) {
      kept.push_back(m);
    }
  }
  top_ = std::move(kept);
}

bool GlobalSearch::Continue(int64_t max_lookups) {
  if (done_) return true;
  const int64_t stop_at = lookups_ + std::max<int64_t>(max_lookups, 1);
  const int top = field_->levels();
  if (!started_) {
    // Every heading's top-level nodes are scored first (the search's entry price, paid over as
    // many calls as it takes), then stacked so that the best is expanded first.
    const int32_t span = int32_t{1} << top;
    while (next_top_.heading < headings_.size()) {
      if (lookups_ >= stop_at) return false;
      Node node{next_top_.heading, next_top_.x, next_top_.y, top, 0};
      node.bound = Bound(node);
      if (node.bound > Threshold()) stack_.push_back(node);
      next_top_.x += span;
      if (next_top_.x > max_offset_.x) {
        next_top_.x = min_offset_.x;
        next_top_.y += span;
        if (next_top_.y > max_offset_.y) {
          next_top_.y = min_offset_.y;
          ++next_top_.heading;
        }
      }
    }
    std::stable_sort(stack_.begin(), stack_.end(),
                     [](const Node& a, const Node& b) { return a.bound < b.bound; });
    started_ = true;
  }
  while (!stack_.empty() && lookups_ < stop_at) {
    const Node node = stack_.back();
    stack_.pop_back();
    if (node.bound <= Threshold()) continue;
    if (node.level == 0) {
      Offer(node);
      continue;
    }
    const int32_t half = int32_t{1} << (node.level - 1);
    Node children[4];
    int count = 0;
    for (int32_t dy = 0; dy <= half; dy += half) {
      for (int32_t dx = 0; dx <= half; dx += half) {
        Node child{node.heading, node.x + dx, node.y + dy, node.level - 1, 0};
        if (child.x > max_offset_.x || child.y > max_offset_.y) continue;
        child.bound = Bound(child);
        if (child.bound > Threshold()) children[count++] = child;
      }
    }
    std::stable_sort(children, children + count,
                     [](const Node& a, const Node& b) { return a.bound < b.bound; });
    stack_.insert(stack_.end(), children, children + count);
  }
  done_ = stack_.empty();
  return done_;
}

void GlobalSearch::Finish() {
  while (!Continue(std::numeric_limits<int64_t>::max() / 2)) {
  }
}

}  // namespace slam
