#include "engine/loss_detector.hpp"

#include <algorithm>
#include <cmath>

#include "engine/cell_encoding.hpp"
#include "engine/even_spacing.hpp"
#include "engine/grid_traversal.hpp"

namespace slam {

ConfigErrors LossDetectorConfig::Validate() const {
  ConfigErrors errors;
  if (max_points < 1) errors.push_back({"/max_points", "must be at least 1"});
  if (!(agree_radius_m >= 0.0 && agree_radius_m <= 0.5)) {
    errors.push_back({"/agree_radius_m", "must be in [0, 0.5] m"});
  }
  if (!(free_below_logodds < occupied_above_logodds)) {
    errors.push_back({"/free_below_logodds", "must be below occupied_above_logodds"});
  }
  if (window_scans < 1) errors.push_back({"/window_scans", "must be at least 1"});
  if (min_known < 1) errors.push_back({"/min_known", "must be at least 1"});
  if (!(lost_share > 0.0 && lost_share <= 1.0)) {
    errors.push_back({"/lost_share", "must be in (0, 1]"});
  }
  if (!(through_above_logodds > occupied_above_logodds)) {
    errors.push_back({"/through_above_logodds", "must be above occupied_above_logodds"});
  }
  if (!(through_margin_m >= 0.0 && through_margin_m <= 1.0)) {
    errors.push_back({"/through_margin_m", "must be in [0, 1] m"});
  }
  if (!(through_reach_m >= 0.0 && through_reach_m <= 10.0)) {
    errors.push_back({"/through_reach_m", "must be in [0, 10] m"});
  }
  if (history_scans < window_scans) {
    errors.push_back({"/history_scans", "must be at least window_scans"});
  }
  return errors;
}

LossDetector::LossDetector(const LossDetectorConfig& config) : config_(config) {}

namespace {

int RadiusCells(double radius_m, double resolution_m) {
  return std::max(0, static_cast<int>(std::ceil(radius_m / resolution_m - 1e-9)));
}

}  // namespace

int64_t LossDetector::MaxLookups() const {
  // A resolution of 1 cm is the finest the engine maps at; coarser maps read fewer cells.
  const int r = RadiusCells(config_.agree_radius_m, 0.01);
  // A traversal over a length of n cells visits at most sqrt(2) n + 2 of them.
  const auto through =
      static_cast<int64_t>(std::ceil(std::sqrt(2.0) * config_.through_reach_m / 0.01)) + 2;
  return int64_t{config_.max_points} * ((2 * r + 1) * (2 * r + 1) + through);
}

LossCheck LossDetector::Check(const OccupancyGrid& map, const Pose2& pose,
                              const std::vector<Vec2>& points) {
  LossCheck check;
  const GridGeometry& geometry = map.geometry();
  const int r = RadiusCells(config_.agree_radius_m, geometry.resolution());
  const LogOdds free_below = EncodeLogOdds(config_.free_below_logodds);
  const LogOdds occupied_above = EncodeLogOdds(config_.occupied_above_logodds);
  const LogOdds through_above = EncodeLogOdds(config_.through_above_logodds);
  // Whether the ray to reading `p` passes through a sure wall before its end (see the file
  // comment); counts its lookups.
  const auto seen_through = [&](const Vec2& p) {
    const Vec2 origin = pose.translation(), end = pose.Transform(p);
    const double length = (end - origin).norm() - config_.through_margin_m;
    if (!(length > 0.0)) return false;
    const Vec2 direction = (end - origin) / (end - origin).norm();
    const double skip = std::max(0.0, length - config_.through_reach_m);
    bool wall = false;
    TraverseCells(geometry, origin + direction * skip, direction, length - skip,
                  [&](CellIndex cell, double, double) {
                    ++check.lookups;
                    wall = map.At(cell) > through_above;
                    return !wall;
                  });
    return wall;
  };
  const size_t total = points.size();
  const size_t keep = std::min(total, static_cast<size_t>(config_.max_points));
  for (size_t k = 0; k < total && keep > 0; ++k) {
    if (!KeptEvenly(k, keep, total)) continue;
    const Vec2& p = points[k];
    if (!p.allFinite()) continue;
    const CellIndex c = geometry.CellOf(pose.Transform(p));
    bool occupied = false, all_free = true;
    for (int dy = -r; dy <= r && !occupied; ++dy) {
      for (int dx = -r; dx <= r && !occupied; ++dx) {
        const LogOdds v = map.At({c.x + dx, c.y + dy});
        ++check.lookups;
        occupied = v > occupied_above;
        all_free = all_free && v < free_below;
      }
    }
    if (occupied) {
      ++check.agree;
    } else if (all_free) {
      ++check.contradict;
    } else if (seen_through(p)) {
      ++check.contradict;
      ++check.through;
    } else {
      ++check.unknown;
    }
  }
  window_.push_back({check.agree, check.contradict});
  while (static_cast<int>(window_.size()) > config_.window_scans) window_.pop_front();
  int agree = 0, contradict = 0;
  for (const Counts& w : window_) {
    agree += w.agree;
    contradict += w.contradict;
  }
  if (agree + contradict >= config_.min_known) {
    check.window_share = static_cast<double>(contradict) / (agree + contradict);
    check.lost = static_cast<int>(window_.size()) >= config_.window_scans &&
                 check.window_share >= config_.lost_share;
  }
  return check;
}

}  // namespace slam
