#include "engine/relocalizer.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "engine/even_spacing.hpp"

namespace slam {

Relocalizer::Relocalizer(const RelocalizerConfig& config) : config_(config) {}

void Relocalizer::Start(const OccupancyGrid& map, const GlobalRegion& region,
                        const std::optional<Pose2>& region_odom) {
  // A field is never finer than the map it comes from.
  const auto build = [&](MatchFieldConfig field) {
    field.resolution_m = std::max(field.resolution_m, map.geometry().resolution());
    field.sigma_m = std::max(field.sigma_m, map.geometry().resolution());
    return std::make_unique<MatchFieldBuild>(map, field);
  };
  build_ = build(config_.field);
  fine_build_ = build(config_.fine_field);
  field_.reset();
  fine_field_.reset();
  region_ = region;
  region_odom_ = region.whole_map ? std::nullopt : region_odom;
  rival_.reset();
  leader_.reset();
  entries_.clear();
  search_.reset();
  pending_.reset();
  search_lookups_ = 0;
  searches_ = 0;
  rejected_ = 0;
}

void Relocalizer::Cancel() {
  pending_.reset();
  leader_.reset();
  build_.reset();
  fine_build_.reset();
  field_.reset();
  fine_field_.reset();
  entries_.clear();
  search_.reset();
}

namespace {

/// `keep` of `points` (all of them when there are no more), evenly spaced in their order.
std::vector<Vec2> EvenlySpaced(const std::vector<Vec2>& points, size_t keep) {
  const size_t total = points.size();
  if (total <= keep) return points;
  std::vector<Vec2> kept;
  kept.reserve(keep);
  for (size_t k = 0; k < total; ++k) {
    if (KeptEvenly(k, keep, total)) kept.push_back(points[k]);
  }
  return kept;
}

}  // namespace

std::vector<Vec2> Relocalizer::Query(double window_s) const {
  const double since = entries_.back().t - window_s;
  size_t total = 0;
  for (const Entry& e : entries_) total += e.t >= since ? e.points.size() : 0;
  const Pose2& newest = entries_.back().odom;
  const size_t keep = std::min(total, static_cast<size_t>(config_.max_points));
  std::vector<Vec2> query;
  query.reserve(keep);
  // Evenly spaced over the readings in time order.
  size_t k = 0;
  for (const Entry& e : entries_) {
    if (e.t < since) continue;
    const Pose2 to_newest = Between(newest, e.odom);
    for (const Vec2& p : e.points) {
      if (KeptEvenly(k++, keep, total)) query.push_back(to_newest.Transform(p));
    }
  }
  return query;
}

void Relocalizer::StartSearch(Stage stage, std::vector<Vec2> query, const Pose2& odom,
                              const GlobalRegion& region) {
  stage_ = stage;
  if (stage == Stage::kCoarse) confirmed_ = 0;
  query_ = std::move(query);
  query_odom_ = odom;
  query_points_ = static_cast<int>(query_.size());
  GlobalSearchConfig config = config_.search;
  if (stage == Stage::kCoarse) {
    search_ = std::make_unique<GlobalSearch>(
        field_, EvenlySpaced(query_, static_cast<size_t>(std::max(config_.coarse_points, 1))),
        region, config);
  } else {
    config.min_score = 0.0;           // a fine score is always wanted
    config.heading_step_cells = 1.0;  // ... at every heading: it decides
    search_ = std::make_unique<GlobalSearch>(fine_field_, query_, region, config);
  }
  ++searches_;
}

std::vector<GlobalMatch>::const_iterator Relocalizer::BestChecked() const {
  return std::max_element(checked_.begin(), checked_.end(),
                          [](const GlobalMatch& a, const GlobalMatch& b) { return a.raw < b.raw; });
}

std::optional<GlobalMatch> Relocalizer::Decide() const {
  const auto best = BestChecked();
  if (best == checked_.end() || best->score < config_.accept_score) return std::nullopt;
  for (const GlobalMatch& other : checked_) {
    if (&other != &*best && Distinct(other, *best, config_.search) &&
        other.score > best->score - config_.unique_margin) {
      return std::nullopt;
    }
  }
  return *best;
}

std::optional<GlobalMatch> Relocalizer::Lead() {
  const auto best = BestChecked();
  if (best == checked_.end() || best->score < config_.accept_score) {
    leader_.reset();
    return std::nullopt;
  }
  double other = 0.0;
  for (const GlobalMatch& c : checked_) {
    if (Distinct(c, *best, config_.search)) other = std::max(other, c.score);
  }
  GlobalMatch carried;
  if (leader_) carried.pose = Compose(leader_->pose, Between(leader_->odom, query_odom_));
  if (!leader_ || Distinct(carried, *best, config_.search)) leader_ = Leader{};
  leader_->pose = best->pose;
  leader_->odom = query_odom_;
  ++leader_->searches;
  leader_->lead += best->score - other;
  if (leader_->searches >= config_.lead_searches && leader_->lead >= config_.lead_sum) {
    return *best;
  }
  return std::nullopt;
}

namespace {

GlobalRegion Around(const Pose2& pose, double half_width_m, double half_angle_deg) {
  GlobalRegion region;
  region.whole_map = false;
  region.center = pose.translation();
  region.half_width_m = half_width_m;
  region.heading = pose.theta;
  region.half_angle_rad = DegToRad(half_angle_deg);
  return region;
}

}  // namespace

GlobalMatch Relocalizer::RivalAtQuery() const {
  GlobalMatch rival;
  rival.pose = Compose(rival_->pose, Between(rival_->odom, query_odom_));
  return rival;
}

void Relocalizer::EndSearch(const Pose2& odom_end, double t_end, RelocalizerStep& step) {
  const std::optional<GlobalMatch> best = search_->best();
  switch (stage_) {
    case Stage::kCoarse:
      candidates_ = search_->candidates();
      if (rival_) {  // checked too, unless a candidate stands for it
        const GlobalMatch rival = RivalAtQuery();
        if (std::all_of(candidates_.begin(), candidates_.end(),
                        [&](const GlobalMatch& c) { return Distinct(c, rival, config_.search); })) {
          candidates_.push_back(rival);
        }
      }
      checked_.clear();
      break;
    case Stage::kCheck:
      // A check that scores nowhere (its region off the field: a rival beyond the map) scores
      // 0 there: every candidate is checked once.
      checked_.push_back(best ? *best : GlobalMatch{candidates_[checked_.size()].pose, 0, 0.0});
      break;
    case Stage::kConfirm:
      if (best && best->score >= config_.accept_score &&
          ++confirmed_ < std::max(config_.confirmations, 1)) {
        pending_ = best->pose;
        pending_odom_ = query_odom_;
        pending_due_t_ = t_end + config_.confirm_spacing_s;
        search_.reset();
        return;
      }
      if (best && best->score >= config_.accept_score) {
        Relocalization found;
        found.pose = Compose(best->pose, Between(query_odom_, odom_end));
        found.score = best->score;
        found.runner_up_score = runner_up_;
        found.rival_score = rival_score_;
        found.points = query_points_;
        found.lookups = search_lookups_;
        found.searches = searches_;
        step.found = found;
        step.searching = false;
        Cancel();
        return;
      }
      candidates_.clear();  // not confirmed: start over
      checked_.clear();
      pending_.reset();
      leader_.reset();
      break;
  }
  if (stage_ != Stage::kConfirm && checked_.size() < candidates_.size()) {
    // The next candidate's check, on the same multiscan.
    StartSearch(Stage::kCheck, std::move(query_), query_odom_,
                Around(candidates_[checked_.size()].pose, config_.check_half_width_m,
                       config_.check_half_angle_deg));
    return;
  }
  if (stage_ == Stage::kCheck) {
    std::optional<GlobalMatch> answer = Decide();
    if (answer) {
      leader_.reset();
    } else {
      answer = Lead();
    }
    if (answer) {
      // The next distinct candidate's fine score: how far the answer stood out.
      runner_up_ = 0.0;
      rival_score_ = 0.0;
      const GlobalMatch rival = rival_ ? RivalAtQuery() : GlobalMatch{};
      for (const GlobalMatch& other : checked_) {
        if (Distinct(other, *answer, config_.search))
          runner_up_ = std::max(runner_up_, other.score);
        if (rival_ && !Distinct(other, rival, config_.search))
          rival_score_ = std::max(rival_score_, other.score);
      }
      // Carried to the newest scan and confirmed there with the newest multiscan.
      StartSearch(Stage::kConfirm, Query(config_.window_s), odom_end,
                  Around(Compose(answer->pose, Between(query_odom_, odom_end)),
                         config_.confirm_half_width_m, config_.confirm_half_angle_deg));
      return;
    }
  }
  // Not sure: gather the next scans' readings and search the whole region again with them.
  ++rejected_;
  step.rejected_confirmation = stage_ == Stage::kConfirm;
  std::sort(checked_.begin(), checked_.end(),
            [](const GlobalMatch& a, const GlobalMatch& b) { return a.raw > b.raw; });
  // Each place once (the better of two checks that found the same place), carried to now.
  const Pose2 to_now = Between(query_odom_, odom_end);
  step.rejected_candidates.clear();
  for (const GlobalMatch& c : checked_) {
    if (std::all_of(step.rejected_candidates.begin(), step.rejected_candidates.end(),
                    [&](const GlobalMatch& kept) { return Distinct(kept, c, config_.search); })) {
      step.rejected_candidates.push_back(c);
    }
  }
  for (GlobalMatch& c : step.rejected_candidates) c.pose = Compose(c.pose, to_now);
  if (step.rejected_candidates.empty()) {
    step.rejected_best = best;
    if (step.rejected_best) step.rejected_best->pose = Compose(step.rejected_best->pose, to_now);
  } else {
    step.rejected_best = step.rejected_candidates.front();
  }
  step.rejected_runner_up =
      step.rejected_candidates.size() > 1 ? step.rejected_candidates[1].score : 0.0;
  search_.reset();
}

void Relocalizer::Spend(int64_t lookups, RelocalizerStep& step) {
  step.lookups += lookups;
  search_lookups_ += lookups;
  total_lookups_ += lookups;
}

bool Relocalizer::Build(int64_t max_lookups, RelocalizerStep& step) {
  // The coarse field first (the first search's), then the fine one.
  for (auto* build : {&build_, &fine_build_}) {
    if (!*build) continue;
    if (step.lookups >= max_lookups) return false;
    const int64_t before = (*build)->lookups();
    const bool done = (*build)->Continue(max_lookups - step.lookups);
    Spend((*build)->lookups() - before, step);
    if (!done) return false;
    (build == &build_ ? field_ : fine_field_) = (*build)->field();
    build->reset();
  }
  return true;
}

RelocalizerStep Relocalizer::Add(const std::vector<Vec2>& points, const Pose2& odom_end,
                                 double t_end, int64_t max_lookups) {
  RelocalizerStep step;
  if (!active()) return step;
  step.searching = true;
  // A scan whose time or odometry is not finite says nothing of where its readings lie (the
  // engine refuses it too); readings that are not finite, or beyond any sensor's reach, are
  // dropped.
  if (!std::isfinite(t_end) || !std::isfinite(odom_end.x) || !std::isfinite(odom_end.y) ||
      !std::isfinite(odom_end.theta)) {
    return step;
  }
  std::vector<Vec2> usable;
  usable.reserve(points.size());
  for (const Vec2& p : points) {
    if (p.allFinite() && p.norm() <= kMaxReadingRangeM) usable.push_back(p);
  }
  entries_.push_back({t_end, odom_end, std::move(usable)});
  // Each search that ended unsure widens the window: more of the room to tell places apart.
  const double window_s =
      std::min(config_.window_s * (1.0 + 0.5 * rejected_), config_.max_window_s);
  while (entries_.size() > 1 && entries_.front().t < t_end - window_s) entries_.pop_front();
  if (!Build(max_lookups, step)) return step;  // readings gathered meanwhile
  if (!search_ && pending_) {
    if (t_end < pending_due_t_) return step;
    const Pose2 carried = Compose(*pending_, Between(pending_odom_, odom_end));
    pending_.reset();
    StartSearch(Stage::kConfirm, Query(config_.window_s), odom_end,
                Around(carried, config_.confirm_half_width_m, config_.confirm_half_angle_deg));
  }
  if (!search_) {
    size_t total = 0;
    for (const Entry& e : entries_) total += e.points.size();
    if (total < static_cast<size_t>(config_.min_points)) return step;
    GlobalRegion region = region_;
    if (region_odom_) {  // a hint given a while ago: where it is now, by the odometry
      const Pose2 carried = Compose(Pose2{region.center.x(), region.center.y(), region.heading},
                                    Between(*region_odom_, odom_end));
      region.center = carried.translation();
      region.heading = carried.theta;
    }
    StartSearch(Stage::kCoarse, Query(std::numeric_limits<double>::infinity()), odom_end, region);
  }
  // The confirming search starts where the global one ends, on the same share.
  while (search_ && step.lookups < max_lookups) {
    const int64_t before = search_->lookups();
    search_->Continue(max_lookups - step.lookups);
    Spend(search_->lookups() - before, step);
    if (!search_->done()) break;
    EndSearch(odom_end, t_end, step);
    if (step.found || !search_) break;
  }
  return step;
}

}  // namespace slam
