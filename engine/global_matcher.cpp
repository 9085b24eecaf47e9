#include "engine/global_matcher.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>
#include <utility>

namespace slam {

namespace {

/// In place, each cell the larger of itself and the cell `half` further along one axis: from a
/// view of windows `half` wide along that axis, the view of windows twice as wide.
void WindowMax(std::vector<uint8_t>& view, int64_t width, int64_t height, int64_t half,
               bool along_x) {
  for (int64_t v = 0; v < height; ++v) {
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
  assert(config.resolution_m > 0 && config.sigma_m > 0);
  const double res = config.resolution_m;
  const GridGeometry field_cells(res);
  // The field cells holding an occupied map cell (its centre inside them).
  std::vector<CellIndex> occupied;
  for (const TileRef& ref : grid.Tiles()) {
    const CellIndex first = GridGeometry::TileOrigin(ref.index);
    for (int j = 0; j < kTileSize; ++j) {
      for (int i = 0; i < kTileSize; ++i) {
        if (ref.tile->cells[static_cast<size_t>(j * kTileSize + i)] <= config.occupied_above) {
          continue;
        }
        occupied.push_back(
            field_cells.CellOf(grid.geometry().CellCenter({first.x + i, first.y + j})));
      }
    }
  }
  std::sort(occupied.begin(), occupied.end(), [](const CellIndex& a, const CellIndex& b) {
    return a.y != b.y ? a.y < b.y : a.x < b.x;
  });
  occupied.erase(std::unique(occupied.begin(), occupied.end()), occupied.end());
  if (occupied.empty()) return FromScores(res, {0, 0}, 0, 0, {}, config.levels);

  // Each occupied cell stamps a Gaussian of the distance between cell centres; a cell keeps
  // the largest stamp (the nearest occupied cell's).
  const int reach = static_cast<int>(std::ceil(3.0 * config.sigma_m / res));
  std::vector<uint8_t> kernel(static_cast<size_t>((2 * reach + 1) * (2 * reach + 1)));
  for (int dy = -reach; dy <= reach; ++dy) {
    for (int dx = -reach; dx <= reach; ++dx) {
      const double d2 = (dx * dx + dy * dy) * res * res;
      kernel[static_cast<size_t>((dy + reach) * (2 * reach + 1) + dx + reach)] =
          static_cast<uint8_t>(
              std::lround(255.0 * std::exp(-d2 / (2 * config.sigma_m * config.sigma_m))));
    }
  }
  CellIndex lo = occupied.front(), hi = occupied.front();
  for (const CellIndex& c : occupied) {
    lo = {std::min(lo.x, c.x), std::min(lo.y, c.y)};
    hi = {std::max(hi.x, c.x), std::max(hi.y, c.y)};
  }
  lo = {lo.x - reach, lo.y - reach};
  const int width = hi.x + reach + 1 - lo.x, height = hi.y + reach + 1 - lo.y;
  std::vector<uint8_t> scores(static_cast<size_t>(width) * static_cast<size_t>(height), 0);
  for (const CellIndex& c : occupied) {
    for (int dy = -reach; dy <= reach; ++dy) {
      uint8_t* row = &scores[static_cast<size_t>(c.y + dy - lo.y) * static_cast<size_t>(width) +
                             static_cast<size_t>(c.x - reach - lo.x)];
      const uint8_t* k = &kernel[static_cast<size_t>((dy + reach) * (2 * reach + 1))];
      for (int i = 0; i <= 2 * reach; ++i) row[i] = std::max(row[i], k[i]);
    }
  }
  return FromScores(res, lo, width, height, std::move(scores), config.levels);
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
    WindowMax(view, width_, height_, half, /*along_x=*/true);
    WindowMax(view, width_, height_, half, /*along_x=*/false);
    views_.push_back(std::move(view));
  }
}

GlobalSearch::GlobalSearch(std::shared_ptr<const MatchField> field, std::vector<Vec2> points,
                           const GlobalRegion& region, const GlobalSearchConfig& config)
    : field_(std::move(field)), config_(config), point_count_(points.size()) {
  const double res = field_->resolution();
  // Field cells as the grid's (GridGeometry::CellOf: floor, saturated far beyond the map).
  const GridGeometry field_cells(res);
  double reach = res;
  for (const Vec2& p : points) reach = std::max(reach, p.norm());
  // Headings spaced so that the farthest point moves by about a cell (Olson's, Hess et al.'s).
  const double step = std::acos(std::clamp(1.0 - res * res / (2.0 * reach * reach), -1.0, 1.0));
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
  return {offset.x * res, offset.y * res, headings_[h]};
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
