#pragma once
// The global scan matcher: where in a whole map (or a given region of it) a set of points
// fits best, with a score that says how sure the fit is. It answers "where am I?" when the
// tracker has no prior: at start on a saved map, after a kidnap, when the track is lost.
//
// Branch and bound over a precomputed multi-resolution view of the map, as the fast
// correlative matchers do (Olson, "Real-time correlative scan matching", ICRA 2009; Hess et
// al., "Real-time loop closure in 2D LIDAR SLAM", ICRA 2016):
//
// - MatchField: the map at the search's own resolution (coarser than the map's: the tracker
//   refines the answer), each cell scored 0..255 by its distance to the nearest occupied cell
//   (a Gaussian of `sigma_m`, the basin a point may land in), and `levels` further views where
//   cell (x, y) of level k holds the largest score of the 2^k x 2^k cells from (x, y) on.
// - A query is points in its own frame: a multiscan, the readings of the last seconds placed
//   by the tracker (a sparse scanner sees too little in one scan to be placed globally). A
//   candidate pose is a heading from a discrete set and a translation in whole cells; its
//   score is the sum of the level-0 scores of the cells its points fall into.
// - GlobalSearch: depth-first over the headings and a quadtree of translations; a node of
//   level k stands for 2^k x 2^k translations and is bounded by the sum of level-k scores
//   (never below any of its translations' scores), so a node whose bound cannot beat the best
//   found is dropped unseen. The answer equals an exhaustive search's (tests/global_matcher_
//   test.cpp checks it against one).
//
// The search is anytime and pays per point looked up: Continue(lookups) runs until it has
// spent that many (a scan's share of the ray budget) or has ended, keeping the best answer so
// far, and the next call goes on where it stopped.

#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "engine/grid_geometry.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"

namespace slam {

/// How a map is turned into a MatchField.
struct MatchFieldConfig {
  double resolution_m = 0.05;  // of the field's cells (any size: the tracker refines)
  double sigma_m = 0.05;       // the score's Gaussian in the distance to an occupied cell
  int levels = 6;              // views above the field itself: the quadtree's top covers 2^6 cells
  LogOdds occupied_above = 0;  // a map cell above this log odds is occupied
};

/// A map as the global matcher reads it (see the file comment). Immutable once built; share it
/// between searches.
class MatchField {
 public:
  /// The field of `grid`'s occupied cells. An empty grid gives an empty field (every score 0).
  /// Precondition: config.resolution_m > 0, config.sigma_m > 0, 0 <= config.levels <= 12.
  static MatchField FromGrid(const OccupancyGrid& grid, const MatchFieldConfig& config);
  /// A field from its level-0 scores, row-major (`width` x `height` cells of `resolution_m`,
  /// cell (0, 0) at field cell `origin`): for tests and for maps scored elsewhere.
  static MatchField FromScores(double resolution_m, CellIndex origin, int width, int height,
                               std::vector<uint8_t> scores, int levels);

  double resolution() const { return resolution_; }
  int levels() const { return static_cast<int>(views_.size()) - 1; }
  /// The score of field cell `c` at `level` (the largest level-0 score of the 2^level square of
  /// cells from `c` on); 0 outside the field.
  uint8_t At(int level, CellIndex c) const {
    const int64_t u = int64_t{c.x} - origin_.x, v = int64_t{c.y} - origin_.y;
    if (u < 0 || v < 0 || u >= width_ || v >= height_) return 0;
    return views_[static_cast<size_t>(level)][static_cast<size_t>(v * width_ + u)];
  }
  /// The field cells with a score, as [min, max) corners: where a point can score.
  CellIndex min_cell() const { return {origin_.x + pad_, origin_.y + pad_}; }
  CellIndex max_cell() const {
    return {origin_.x + static_cast<int32_t>(width_), origin_.y + static_cast<int32_t>(height_)};
  }
  /// Whether no cell scores at all.
  bool empty() const { return empty_; }

 private:
  friend class MatchFieldBuild;
  void BuildViews(int levels);

  double resolution_ = 0.04;
  CellIndex origin_{0, 0};  // field cell of index 0 in every view
  int64_t width_ = 0, height_ = 0;
  int32_t pad_ = 0;  // the views start this many cells below the scored cells
  bool empty_ = true;
  std::vector<std::vector<uint8_t>> views_;  // level 0 .. levels
};

/// Builds a grid's MatchField a share at a time, as a search runs (the relocaliser pays both
/// from the scans' quotas): Continue(lookups) works until it has spent about that many lookups'
/// worth or the field is done, and the next call goes on where it stopped. The field equals
/// MatchField::FromGrid's (which is this run to the end). The grid's tiles are held as they
/// were at construction (shared, immutable): later writes to the grid do not reach the build.
///
/// The work is counted in cell operations (a map cell read, a field cell stamped, copied or
/// compared), kCellOpsPerLookup of them to a lookup: a build's charged lookup costs about half
/// a search's (bench: BM_MatchFieldBuild against BM_GlobalSearch, docs/performance.md), so the
/// rate errs high and a build never costs more than the lookups it is charged.
class MatchFieldBuild {
 public:
  static constexpr int64_t kCellOpsPerLookup = 1;

  /// Precondition: as FromGrid's.
  MatchFieldBuild(const OccupancyGrid& grid, const MatchFieldConfig& config);

  /// Builds until `max_lookups` were spent (at least one step is always taken, so every call
  /// progresses) or the field is done; a call overruns its share by at most its last step,
  /// which is never more than a tile read, 16 cells stamped, or one row of a view cleared,
  /// copied or passed over (a large map's view costs as many steps as it has rows). Returns
  /// whether it is done.
  bool Continue(int64_t max_lookups);
  /// Runs to the end.
  void Finish();
  bool done() const { return stage_ == Stage::kDone; }
  /// The work so far, in lookups (cell operations / kCellOpsPerLookup, rounded up).
  int64_t lookups() const { return (ops_ + kCellOpsPerLookup - 1) / kCellOpsPerLookup; }
  /// The field once done() (null before).
  std::shared_ptr<const MatchField> field() const { return result_; }

 private:
  enum class Stage { kMark, kClear, kStamp, kViews, kDone };
  /// One step of the stage; returns the cell operations it took.
  int64_t Step();
  int64_t MarkTile();
  int64_t StartStamping();
  int64_t ClearRow();
  int64_t StampCells();
  int64_t ViewRow();

  MatchFieldConfig config_;
  GridGeometry map_cells_, field_cells_;
  std::vector<TileRef> tiles_;
  Stage stage_ = Stage::kMark;
  size_t next_tile_ = 0;
  std::vector<CellIndex> occupied_;    // field cells holding an occupied map cell (a cell on the
                                       // edge of two tiles may be there twice: stamped twice)
  std::vector<CellIndex> tile_cells_;  // scratch of MarkTile
  CellIndex lo_{0, 0}, hi_{-1, -1};    // of occupied_
  int reach_ = 0;
  std::vector<uint8_t> kernel_;
  size_t next_occupied_ = 0;
  MatchField field_;
  int level_ = 0;         // the view being built (kViews)
  bool along_y_ = false;  // its pass: the window along x (on a copy of the view below), then y
  int64_t row_ = 0;
  int64_t ops_ = 0;
  std::shared_ptr<const MatchField> result_;
};

/// Where a search looks: translations within `half_width_m` of `center` on both axes (the whole
/// field when `whole_map`), headings within `half_angle_rad` of `heading` (every heading when it
/// is pi or more).
struct GlobalRegion {
  bool whole_map = true;
  Vec2 center = Vec2::Zero();
  double half_width_m = 0.0;
  double heading = 0.0;
  double half_angle_rad = kPi;
};

/// One candidate pose with its score.
struct GlobalMatch {
  Pose2 pose;          // the query frame's pose in the map
  int64_t raw = 0;     // the sum of the points' scores
  double score = 0.0;  // raw / (255 * points): 1 when every point sits on a wall
};

/// A global search's options.
struct GlobalSearchConfig {
  /// Candidates scoring below this (a fraction of the perfect score) are never answers; a
  /// higher floor prunes more.
  double min_score = 0.3;
  /// The runner-up is sought among the candidates distinct from the best (at least
  /// `distinct_m` away on an axis, or `distinct_rad` turned) that score above this share of the
  /// best: whether one does says whether the answer is unique. The search prunes everything
  /// below that share of the best found so far, so a lower share costs more.
  double unique_ratio = 0.85;
  double distinct_m = 0.3;
  double distinct_rad = DegToRad(20.0);
  /// Distinct candidates kept, the best included (at least 1): a caller that checks them
  /// otherwise (finer, later) wants more than the runner-up.
  int candidates = 2;
  /// The headings' spacing: how many field cells it moves the farthest point by. One is the
  /// exhaustive spacing (every answer within a cell's turn); a caller that checks the candidates
  /// over a range of headings (the relocaliser) may take more, for a search that many times
  /// cheaper.
  double heading_step_cells = 1.0;
  /// A whole-map search turns the query about its points' centroid instead of its own origin:
  /// the points lie closer to what it turns about, so fewer headings move them by a cell (a
  /// multiscan's origin is its newest scan's end, at one end of the path it spans). The answers
  /// are the query frame's poses as ever; the candidates tried are the same headings and
  /// translations of the centroid.
  bool turn_about_centroid = false;
};

/// Whether two candidates are distinct places: at least distinct_m apart on an axis, or
/// distinct_rad turned.
inline bool Distinct(const GlobalMatch& a, const GlobalMatch& b, const GlobalSearchConfig& c) {
  return (a.pose.translation() - b.pose.translation()).cwiseAbs().maxCoeff() >= c.distinct_m ||
         std::abs(NormalizeAngle(a.pose.theta - b.pose.theta)) >= c.distinct_rad;
}

/// An anytime branch-and-bound search of one query over a field (see the file comment).
class GlobalSearch {
 public:
  /// Precondition: `field` outlives nothing of ours (shared), `points` finite.
  GlobalSearch(std::shared_ptr<const MatchField> field, std::vector<Vec2> points,
               const GlobalRegion& region, const GlobalSearchConfig& config = {});

  /// Searches until `max_lookups` point scores were looked up (at least one node is always
  /// expanded, so every call progresses) or the search has ended. Returns whether it has ended.
  bool Continue(int64_t max_lookups);
  /// Runs to the end.
  void Finish();

  bool done() const { return done_; }
  /// The best candidate scoring at least min_score found so far (the best of all once done()).
  std::optional<GlobalMatch> best() const {
    return top_.empty() ? std::nullopt : std::optional<GlobalMatch>(top_[0]);
  }
  /// The best candidate found so far that is distinct from best() and scores above
  /// unique_ratio of it (GlobalSearchConfig); none when no such candidate was met. Candidates
  /// that could not beat the threshold of their time are never scored, so the second place
  /// may be lower than an exhaustive search's, but when done() a distinct candidate above the
  /// share is reported if one exists (up to which best it was distinct from when met).
  std::optional<GlobalMatch> runner_up() const {
    return top_.size() < 2 ? std::nullopt : std::optional<GlobalMatch>(top_[1]);
  }
  /// The distinct candidates kept (GlobalSearchConfig::candidates), best first: best(),
  /// runner_up() and the next ones, each above unique_ratio of the best, on the same terms.
  const std::vector<GlobalMatch>& candidates() const { return top_; }
  /// Point scores looked up so far: the search's cost.
  int64_t lookups() const { return lookups_; }
  /// The headings the search tries (their spacing moves the farthest point by about a cell).
  size_t headings() const { return headings_.size(); }
  /// The translations (whole field cells) it tries on each axis, as [min, max].
  CellIndex min_offset() const { return min_offset_; }
  CellIndex max_offset() const { return max_offset_; }

  /// The pose of a candidate: heading index `h`, translation `offset` in field cells (of the
  /// point it turns about: the query frame's origin, or the centroid).
  Pose2 CandidatePose(size_t h, CellIndex offset) const;
  /// What the search turns the query about, in the query's frame (zero but for a whole-map
  /// search with GlobalSearchConfig::turn_about_centroid).
  const Vec2& pivot() const { return pivot_; }
  /// The cells the points fall into under heading `h` with a zero translation: a candidate's
  /// cells are these plus its offset.
  const std::vector<CellIndex>& PointCells(size_t h) const { return cells_[h]; }

 private:
  struct Node {
    uint32_t heading;
    int32_t x, y;
    int32_t level;
    int64_t bound;
  };
  int64_t Bound(const Node& node);
  void Offer(const Node& leaf);
  int64_t Threshold() const;

  std::shared_ptr<const MatchField> field_;
  GlobalSearchConfig config_;
  size_t point_count_ = 0;
  std::vector<double> headings_;
  Vec2 pivot_ = Vec2::Zero();
  std::vector<std::vector<CellIndex>> cells_;  // per heading, of the points less the pivot
  CellIndex min_offset_{0, 0}, max_offset_{-1, -1};
  int64_t min_raw_ = 0;
  std::vector<Node> stack_;
  Node next_top_{0, 0, 0, 0, 0};  // the next top-level node to score, until started_
  bool started_ = false;
  bool done_ = false;
  int64_t lookups_ = 0;
  std::vector<GlobalMatch> top_;  // distinct, best first
};

}  // namespace slam
