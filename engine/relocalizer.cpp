#include "engine/relocalizer.hpp"

#include <algorithm>
#include <utility>

namespace slam {

Relocalizer::Relocalizer(const RelocalizerConfig& config) : config_(config) {}

void Relocalizer::Start(const OccupancyGrid& map, const GlobalRegion& region) {
  // A field is never finer than the map it comes from.
  const auto build = [&](MatchFieldConfig field) {
    field.resolution_m = std::max(field.resolution_m, map.geometry().resolution());
    field.sigma_m = std::max(field.sigma_m, map.geometry().resolution());
    return std::make_shared<const MatchField>(MatchField::FromGrid(map, field));
  };
  field_ = build(config_.field);
  confirm_field_ = build(config_.confirm_field);
  region_ = region;
  entries_.clear();
  search_.reset();
  search_lookups_ = 0;
  searches_ = 0;
  rejected_ = 0;
}

void Relocalizer::Cancel() {
  field_.reset();
  confirm_field_.reset();
  entries_.clear();
  search_.reset();
}

std::vector<Vec2> Relocalizer::Query() const {
  size_t total = 0;
  for (const Entry& e : entries_) total += e.points.size();
  const Pose2& newest = entries_.back().odom;
  const size_t keep = std::min(total, static_cast<size_t>(config_.max_points));
  std::vector<Vec2> query;
  query.reserve(keep);
  // Evenly spaced over the readings in time order: reading k of `total` is kept when it
  // starts a new share of total / keep.
  size_t k = 0;
  for (const Entry& e : entries_) {
    const Pose2 to_newest = Between(newest, e.odom);
    for (const Vec2& p : e.points) {
      if ((k * keep) / total != ((k + 1) * keep) / total) query.push_back(to_newest.Transform(p));
      ++k;
    }
  }
  return query;
}

void Relocalizer::StartSearch(const GlobalRegion& region, const Pose2& odom_end, bool confirming) {
  std::vector<Vec2> query = Query();
  query_points_ = static_cast<int>(query.size());
  query_odom_ = odom_end;
  confirming_ = confirming;
  search_ = std::make_unique<GlobalSearch>(confirming ? confirm_field_ : field_, std::move(query),
                                           region, config_.search);
  ++searches_;
}

void Relocalizer::EndSearch(const Pose2& odom_end, RelocalizerStep& step) {
  const std::optional<GlobalMatch>& best = search_->best();
  const bool sure =
      best && best->score >= config_.accept_score && (confirming_ || !search_->runner_up());
  if (sure && !confirming_) {
    // Carried to now and confirmed there (see the file comment).
    const Pose2 carried = Compose(best->pose, Between(query_odom_, odom_end));
    GlobalRegion around;
    around.whole_map = false;
    around.center = carried.translation();
    around.half_width_m = config_.confirm_half_width_m;
    around.heading = carried.theta;
    around.half_angle_rad = DegToRad(config_.confirm_half_angle_deg);
    StartSearch(around, odom_end, /*confirming=*/true);
    return;
  }
  if (sure) {
    Relocalization found;
    found.pose = Compose(best->pose, Between(query_odom_, odom_end));
    found.score = best->score;
    found.points = query_points_;
    found.lookups = search_lookups_;
    found.searches = searches_;
    step.found = found;
    step.searching = false;
    Cancel();
    return;
  }
  // Not sure: gather the next scans' readings and search the whole region again with them.
  ++rejected_;
  step.rejected_best = best;
  step.rejected_runner_up = search_->runner_up() ? search_->runner_up()->score : 0.0;
  search_.reset();
}

RelocalizerStep Relocalizer::Add(const std::vector<Vec2>& points, const Pose2& odom_end,
                                 double t_end, int64_t max_lookups) {
  RelocalizerStep step;
  if (!active()) return step;
  step.searching = true;
  entries_.push_back({t_end, odom_end, points});
  // Each search that ended unsure widens the window: more of the room to tell places apart.
  const double window_s =
      std::min(config_.window_s * (1.0 + 0.5 * rejected_), config_.max_window_s);
  while (entries_.size() > 1 && entries_.front().t < t_end - window_s) entries_.pop_front();
  if (!search_) {
    size_t total = 0;
    for (const Entry& e : entries_) total += e.points.size();
    if (total < static_cast<size_t>(config_.min_points)) return step;
    StartSearch(region_, odom_end, /*confirming=*/false);
  }
  // The confirming search starts where the global one ends, on the same share.
  while (search_ && step.lookups < max_lookups) {
    const int64_t before = search_->lookups();
    search_->Continue(max_lookups - step.lookups);
    const int64_t spent = search_->lookups() - before;
    step.lookups += spent;
    search_lookups_ += spent;
    total_lookups_ += spent;
    if (!search_->done()) break;
    EndSearch(odom_end, step);
    if (step.found || !search_) break;
  }
  return step;
}

}  // namespace slam
