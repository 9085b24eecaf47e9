#pragma once
// Relocalisation: where the robot is in a map it already has, without a prior. A sparse
// scanner sees too little in one scan to be placed in a whole map, so the query is a
// multiscan: the readings of the last seconds, each scan's placed by the odometry from its end
// to the newest scan's end (over seconds the odometry errs by far less than a field cell).
// Three searches of the global scan matcher (global_matcher.hpp), anytime, a share of each
// scan's budget at a time:
//
// 1. the whole map on a coarse field: the best pose and the distinct candidates that score
//    nearly as well (search.candidates of them, above search.unique_ratio of the best);
// 2. each candidate checked on a fine field around it with the same multiscan: the answer is the
//    fine best when it scores at least accept_score and no distinct candidate comes within
//    unique_margin of it (a corridor, a symmetric room: the robot gathers readings and
//    searches again, over a wider window);
// 3. confirmed at the newest scan: the search took scans, the robot moved, and a heading off
//    by a fraction of a degree grows into centimetres over the metres driven; the answer is
//    carried there by the odometry and searched again around it (confirm_half_width_m,
//    confirm_half_angle_deg) with the newest multiscan, and taken when that scores at least
//    accept_score, `confirmations` times, seconds apart.

#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <vector>

#include "engine/global_matcher.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"

namespace slam {

/// What a scan's quota pays the search: point lookups per quota ray. A lookup is one byte read
/// and an add, a quota ray a cast through tens of cells; a ray costs some 35-50 lookups
/// (bench: BM_GlobalSearch against BM_Scan, docs/performance.md), and the rate errs low so
/// that a search never costs more than the rays it replaces.
inline constexpr int64_t kLookupsPerRay = 32;

struct RelocalizerConfig {
  /// The multiscan: the readings of this many seconds of scans, half as many more after each
  /// search that ended unsure, up to max_window_s.
  double window_s = 10.0;
  double max_window_s = 30.0;
  int min_points = 120;  // a search starts once the multiscan holds this many readings
  /// Readings of a multiscan kept at most (evenly spaced): the search's cost per candidate.
  int max_points = 400;
  /// ... of which the whole-map search scores at most this many (evenly spaced): its cost is
  /// headings x translations x points, and it only nominates candidates, which the checks
  /// score with every reading.
  int coarse_points = 200;
  /// The whole-map search's field is coarse (fewer translations and headings to try), the
  /// checks' and the confirmation's fine (small regions).
  MatchFieldConfig field{0.10, 0.10, 6, 0};
  MatchFieldConfig fine_field{0.03, 0.03, 4, 0};
  /// The coarse search's: its candidates (and unique_ratio) are the ones checked. It takes
  /// headings two cells apart and turns the multiscan about its centroid (GlobalSearchConfig):
  /// a candidate's heading is then within a degree or two of the best, which its check, over
  /// check_half_angle_deg, finds at every heading.
  GlobalSearchConfig search{0.3, 0.7, 0.3, DegToRad(20.0), 4, 2.0, true};
  double check_half_width_m = 0.15;
  double check_half_angle_deg = 5.0;
  double accept_score = 0.8;    // a fine score at least this
  double unique_margin = 0.05;  // ... and no distinct candidate's fine score within this of it
  /// ... or, where twins of a place score nearly alike (rooms alike, a corridor), the same
  /// place (carried by the odometry from search to search) the best of at least
  /// `lead_searches` checks in a row, each scoring at least accept_score, its leads over the
  /// best distinct candidate adding up to `lead_sum`: evidence gathered as the robot drives
  /// (the multiscans overlap, so the sum asks for more than one search's margin).
  int lead_searches = 3;
  double lead_sum = 0.1;
  /// The answer carried by the odometry over a few seconds is off by centimetres: the
  /// confirmation looks no wider than the check did.
  double confirm_half_width_m = 0.15;
  double confirm_half_angle_deg = 4.0;
  /// Confirmations wanted, each `confirm_spacing_s` after the last with the multiscan of
  /// then: a place that only looked right from where the robot was is seldom right from
  /// where it drove on to.
  int confirmations = 2;
  double confirm_spacing_s = 4.0;
};

/// One answer of the relocaliser.
struct Relocalization {
  Pose2 pose;  // the robot's pose at the end of the scan that completed the search
  double score = 0.0;
  double runner_up_score = 0.0;  // 0 when no distinct candidate scored above the floor
  /// The rival's fine score (SetRival), 0 without one.
  double rival_score = 0.0;
  int points = 0;       // in the multiscan
  int64_t lookups = 0;  // the cost since Start: the fields' builds and the searches
  int searches = 0;     // searches it took (an ambiguous one searches again)
};

/// What the last Add did.
struct RelocalizerStep {
  int64_t lookups = 0;  // spent in this step (fields' builds and searches)
  bool searching = false;
  std::optional<Relocalization> found;
  /// A search ended without an answer taken: the best candidate's fine check (the coarse
  /// best when none was checked) and the next distinct one's fine score (0: none), for logs;
  /// the pose carried by the odometry to the end of the step's scan.
  std::optional<GlobalMatch> rejected_best;
  double rejected_runner_up = 0.0;
  /// ... and every distinct place the checks scored, best first (rejected_best among them),
  /// carried likewise: where the robot may be (none when nothing was checked).
  std::vector<GlobalMatch> rejected_candidates;
  /// The search that ended unsure was an answer's confirmation (rejected_best is its score
  /// there): the answer found, then not confirmed from where the robot drove on.
  bool rejected_confirmation = false;
};

class Relocalizer {
 public:
  explicit Relocalizer(const RelocalizerConfig& config = {});

  /// Starts relocalising on `map`, over `region` (the whole map by default); forgets any
  /// earlier multiscan and search. The map's fields (MatchFieldBuild) are built by the next
  /// Adds, paid from their shares like the searches, before the first search starts; the map is
  /// held as it is now. A region given where the odometry read
  /// `region_odom` (a hint: "the robot is about here") moves with the robot: each search looks
  /// around the region carried by the odometry from there to its newest scan.
  void Start(const OccupancyGrid& map, const GlobalRegion& region = {},
             const std::optional<Pose2>& region_odom = std::nullopt);
  /// A pose the answer must beat (a background check's: the tracked pose, where the odometry
  /// read `odom`), given before each Add: carried to the multiscan's time, it is checked on the
  /// fine field with the coarse search's candidates, so an answer elsewhere is taken only when
  /// it beats the rival by unique_margin, and an answer at the rival says the rival was right.
  /// Start forgets it.
  void SetRival(const Pose2& pose, const Pose2& odom) { rival_ = {pose, odom}; }
  /// Stops relocalising.
  void Cancel();
  bool active() const { return build_ != nullptr || field_ != nullptr; }  // coarse first

  /// Readings farther than this from the robot are dropped (no range sensor it takes reaches
  /// that far; a reading there is bad input).
  static constexpr double kMaxReadingRangeM = 1000.0;

  /// One scan: its readings in the robot's frame at its end (Slam::ReadingPoints), the
  /// odometry's pose at its end and its end time; spends at most about `max_lookups` on the
  /// fields' builds and the search (MatchFieldBuild::Continue, GlobalSearch::Continue). Once an
  /// answer is taken (`found`), the relocaliser is no longer active. Nothing is done while not
  /// active, nor with a scan whose time or odometry is not finite; readings that are not finite or
  /// beyond kMaxReadingRangeM are dropped.
  RelocalizerStep Add(const std::vector<Vec2>& points, const Pose2& odom_end, double t_end,
                      int64_t max_lookups);

  /// What every Add spent, the fields' builds included.
  int64_t lookups() const { return total_lookups_; }
  int searches() const { return searches_; }

 private:
  struct Entry {
    double t;
    Pose2 odom;
    std::vector<Vec2> points;
  };
  /// The multiscan in the newest scan's frame, at most max_points readings, of the scans at
  /// most `window_s` older than the newest.
  std::vector<Vec2> Query(double window_s) const;
  enum class Stage { kCoarse, kCheck, kConfirm };
  /// Starts a search of `query` (taken at odometry `odom`) over `region`.
  void StartSearch(Stage stage, std::vector<Vec2> query, const Pose2& odom,
                   const GlobalRegion& region);
  /// A search ended: the step's answer, or the next search (none: start over).
  void EndSearch(const Pose2& odom_end, double t_end, RelocalizerStep& step);
  /// The check that scored best (raw), checked_.end() with none.
  std::vector<GlobalMatch>::const_iterator BestChecked() const;
  /// The checks ended: the unique fine answer, if any.
  std::optional<GlobalMatch> Decide() const;
  /// The checks ended without a unique answer: the place that led them goes on leading (or a
  /// new lead starts); the place, once it led as RelocalizerConfig::lead_searches asks.
  std::optional<GlobalMatch> Lead();
  /// The rival (SetRival) carried by the odometry to the time of the query; call with one set.
  GlobalMatch RivalAtQuery() const;

  /// Spends on the fields' builds; returns whether both are done.
  bool Build(int64_t max_lookups, RelocalizerStep& step);
  void Spend(int64_t lookups, RelocalizerStep& step);

  RelocalizerConfig config_;
  std::unique_ptr<MatchFieldBuild> build_, fine_build_;  // until their fields are done
  std::shared_ptr<const MatchField> field_, fine_field_;
  GlobalRegion region_;
  std::optional<Pose2> region_odom_;  // where the odometry read when region_ was given
  struct Rival {
    Pose2 pose, odom;
  };
  std::optional<Rival> rival_;
  struct Leader {
    Pose2 pose, odom;   // the leading place, where the odometry read `odom`
    int searches = 0;   // checks in a row it led
    double lead = 0.0;  // its leads over the best distinct candidate, summed
  };
  std::optional<Leader> leader_;
  std::deque<Entry> entries_;
  std::unique_ptr<GlobalSearch> search_;
  Stage stage_ = Stage::kCoarse;         // search_'s
  std::vector<Vec2> query_;              // search_'s query
  Pose2 query_odom_;                     // the odometry at the newest scan's end when it was taken
  std::vector<GlobalMatch> candidates_;  // the coarse search's, to check
  std::vector<GlobalMatch> checked_;     // their fine answers so far
  int confirmed_ = 0;                    // confirmations of the answer so far
  double runner_up_ = 0.0;               // the answer's distinct runner-up's fine score
  double rival_score_ = 0.0;             // the rival's fine score when the answer was decided
  std::optional<Pose2> pending_;         // the answer between confirmations, at pending_odom_
  Pose2 pending_odom_;
  double pending_due_t_ = 0.0;
  int query_points_ = 0;
  int64_t search_lookups_ = 0;  // of the builds and searches since Start
  int64_t total_lookups_ = 0;
  int searches_ = 0;
  int rejected_ = 0;  // searches since Start that ended unsure
};

}  // namespace slam
