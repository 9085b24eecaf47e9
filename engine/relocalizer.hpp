#pragma once
// Relocalisation: where the robot is in a map it already has, without a prior. A sparse
// scanner sees too little in one scan to be placed in a whole map, so the query is a
// multiscan: the readings of the last seconds, each scan's placed by the odometry from its end
// to the newest scan's end (over seconds the odometry errs by far less than a field cell). The
// global scan matcher (global_matcher.hpp) searches it over the map, anytime, a share of each
// scan's budget at a time; the answer is taken when it scores well and no distinct pose scores
// nearly as well (a corridor, a symmetric room: the robot keeps gathering readings and searches
// again). The search takes scans; meanwhile the robot moves, and a heading off by half a
// heading step at the query grows into centimetres over metres driven. So the pose found is
// carried to the newest scan's end by the odometry and confirmed there: a second, small search
// of the newest multiscan around it (confirm_half_width_m, confirm_half_angle_deg), whose
// answer is taken when it scores at least accept_score.

#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <vector>

#include "engine/global_matcher.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"

namespace slam {

struct RelocalizerConfig {
  /// The multiscan: the readings of this many seconds of scans, half as many more after each
  /// search that ended unsure, up to max_window_s.
  double window_s = 10.0;
  double max_window_s = 30.0;
  int min_points = 120;  // a search starts once the multiscan holds this many readings
  /// Readings of a multiscan kept at most (evenly spaced): the search's cost per candidate.
  int max_points = 400;
  /// The whole-map search's field is coarse (fewer translations and headings to try), the
  /// confirming search's fine (a small region, an answer the tracker takes from there).
  MatchFieldConfig field{0.10, 0.10, 6, 0};
  MatchFieldConfig confirm_field{0.03, 0.03, 4, 0};
  GlobalSearchConfig search;
  double accept_score = 0.55;  // the best's score (GlobalMatch::score) at least; unique:
                               // no runner-up (GlobalSearchConfig::unique_ratio)
  double confirm_half_width_m = 0.3;
  double confirm_half_angle_deg = 8.0;
};

/// One answer of the relocaliser.
struct Relocalization {
  Pose2 pose;  // the robot's pose at the end of the scan that completed the search
  double score = 0.0;
  double runner_up_score = 0.0;  // 0 when no distinct candidate scored above the floor
  int points = 0;                // in the multiscan
  int64_t lookups = 0;           // the search's cost
  int searches = 0;              // searches it took (an ambiguous one searches again)
};

/// What the last Add did.
struct RelocalizerStep {
  int64_t lookups = 0;  // spent in this step
  bool searching = false;
  std::optional<Relocalization> found;
  /// A search ended without an answer taken: its best's score and the runner-up's (for logs).
  std::optional<GlobalMatch> rejected_best;
  double rejected_runner_up = 0.0;
};

class Relocalizer {
 public:
  explicit Relocalizer(const RelocalizerConfig& config = {});

  /// Starts relocalising on `map` (its field built now), over `region` (the whole map by
  /// default); forgets any earlier multiscan and search.
  void Start(const OccupancyGrid& map, const GlobalRegion& region = {});
  /// Stops relocalising.
  void Cancel();
  bool active() const { return field_ != nullptr; }

  /// One scan: its readings in the robot's frame at its end (Slam::ReadingPoints), the
  /// odometry's pose at its end and its end time; spends at most about `max_lookups` on the
  /// search (GlobalSearch::Continue). Once an answer is taken (`found`), the relocaliser is no
  /// longer active. Nothing is done while not active.
  RelocalizerStep Add(const std::vector<Vec2>& points, const Pose2& odom_end, double t_end,
                      int64_t max_lookups);

  int64_t lookups() const { return total_lookups_; }
  int searches() const { return searches_; }

 private:
  struct Entry {
    double t;
    Pose2 odom;
    std::vector<Vec2> points;
  };
  /// The multiscan in the newest scan's frame, at most max_points readings.
  std::vector<Vec2> Query() const;
  /// Starts a search of the multiscan as it is now, over `region`.
  void StartSearch(const GlobalRegion& region, const Pose2& odom_end, bool confirming);
  /// A search ended: the step's answer, or the next search.
  void EndSearch(const Pose2& odom_end, RelocalizerStep& step);

  RelocalizerConfig config_;
  std::shared_ptr<const MatchField> field_, confirm_field_;
  GlobalRegion region_;
  std::deque<Entry> entries_;
  std::unique_ptr<GlobalSearch> search_;
  bool confirming_ = false;  // search_ is the confirming one
  Pose2 query_odom_;         // the odometry at the newest scan's end when search_ started
  int query_points_ = 0;
  int64_t search_lookups_ = 0;  // of the searches since Start
  int64_t total_lookups_ = 0;
  int searches_ = 0;
  int rejected_ = 0;  // searches since Start that ended unsure
};

}  // namespace slam
