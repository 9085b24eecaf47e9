// The global scan matcher on maps drawn cell by cell and on random fields, against an
// exhaustive search of the same candidates.
#include "engine/global_matcher.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include "drawn_rooms.hpp"
#include "engine/cell_encoding.hpp"
#include "engine/random.hpp"

namespace slam {
namespace {

constexpr double kMapCell = 0.02;

// The exhaustive answer: the largest sum of level-0 scores over every candidate the search has.
int64_t BruteForceBest(const MatchField& field, const GlobalSearch& search) {
  int64_t best = 0;
  for (size_t h = 0; h < search.headings(); ++h) {
    for (int32_t y = search.min_offset().y; y <= search.max_offset().y; ++y) {
      for (int32_t x = search.min_offset().x; x <= search.max_offset().x; ++x) {
        int64_t sum = 0;
        for (const CellIndex& c : search.PointCells(h)) sum += field.At(0, {c.x + x, c.y + y});
        best = std::max(best, sum);
      }
    }
  }
  return best;
}

// The raw score of a candidate found by the search, recomputed from its pose.
int64_t ScoreAt(const MatchField& field, const GlobalSearch& search, const GlobalMatch& m) {
  for (size_t h = 0; h < search.headings(); ++h) {
    const Pose2 first = search.CandidatePose(h, {0, 0});
    if (std::abs(NormalizeAngle(first.theta - m.pose.theta)) > 1e-12) continue;
    // The candidate's offset is where the pivot lands.
    const Vec2 pivot = m.pose.Transform(search.pivot());
    const CellIndex offset{static_cast<int32_t>(std::lround(pivot.x() / field.resolution())),
                           static_cast<int32_t>(std::lround(pivot.y() / field.resolution()))};
    int64_t sum = 0;
    for (const CellIndex& c : search.PointCells(h)) {
      sum += field.At(0, {c.x + offset.x, c.y + offset.y});
    }
    return sum;
  }
  return -1;
}

using testing::LRoom;
using testing::SeenFrom;

OccupancyGrid DrawnGrid(const std::vector<Vec2>& outline) {
  return testing::Draw(outline, kMapCell);
}

TEST(MatchFieldTest, ScoresFallWithDistanceAndViewsHoldTheirWindowsLargest) {
  OccupancyGrid grid(GridGeometry(kMapCell), EncodeLogOdds(5.0));
  grid.BeginWrite();
  grid.Add({10, 10}, EncodeLogOdds(2.0));   // centre (0.21, 0.21): field cell (5, 5) at 4 cm
  grid.Add({40, 12}, EncodeLogOdds(-2.0));  // free: no score
  grid.RefreshSummaries();
  MatchFieldConfig config;
  config.resolution_m = 0.04;
  config.sigma_m = 0.04;
  config.levels = 3;
  const MatchField field = MatchField::FromGrid(grid, config);
  ASSERT_FALSE(field.empty());
  EXPECT_EQ(field.At(0, {5, 5}), 255);
  EXPECT_EQ(field.At(0, {6, 5}), std::lround(255 * std::exp(-0.5)));
  EXPECT_EQ(field.At(0, {6, 6}), std::lround(255 * std::exp(-1.0)));
  EXPECT_EQ(field.At(0, {9, 5}), 0);   // beyond three sigmas
  EXPECT_EQ(field.At(0, {10, 3}), 0);  // the free cell
  EXPECT_EQ(field.At(0, {-100, 5}), 0);
  for (int level = 1; level <= 3; ++level) {
    for (int y = -2; y <= 12; ++y) {
      for (int x = -10; x <= 12; ++x) {
        int largest = 0;
        for (int dy = 0; dy < (1 << level); ++dy) {
          for (int dx = 0; dx < (1 << level); ++dx) {
            largest = std::max<int>(largest, field.At(0, {x + dx, y + dy}));
          }
        }
        ASSERT_EQ(field.At(level, {x, y}), largest) << level << " " << x << " " << y;
      }
    }
  }
}

TEST(MatchFieldTest, ABuildInSlicesEqualsOneBuildKeepsItsSharesAndHoldsTheGridAsItWas) {
  OccupancyGrid grid = DrawnGrid(LRoom());
  MatchFieldConfig config;
  config.resolution_m = 0.04;
  config.sigma_m = 0.04;
  config.levels = 4;
  const MatchField whole = MatchField::FromGrid(grid, config);
  MatchFieldBuild build(grid, config);
  // Written after the build began: not in its field.
  grid.BeginWrite();
  grid.Add({500, 500}, EncodeLogOdds(5.0));
  grid.RefreshSummaries();
  ASSERT_EQ(MatchField::FromGrid(grid, config).At(0, {250, 250}), 255);

  // A call stops at its share, overrunning by at most its last step: a tile read (a read per
  // cell, a sort's few per occupied one), 16 stamps, or a row of a view (cleared, or copied and
  // passed over).
  const int32_t pad = (1 << config.levels) - 1;
  const int64_t width = whole.max_cell().x - whole.min_cell().x + pad;
  const int64_t side = 2 * 3 + 1;  // the kernel's: three sigmas of one cell each way
  const int64_t step = std::max({int64_t{9} * kTileCells, 16 * side * side, 2 * width});
  const int64_t share = 1000;
  int calls = 0;
  while (!build.done()) {
    ASSERT_EQ(build.field(), nullptr);
    const int64_t before = build.lookups();
    build.Continue(share);
    EXPECT_GT(build.lookups(), before);
    EXPECT_LE(build.lookups() - before, share + step / MatchFieldBuild::kCellOpsPerLookup + 1);
    ++calls;
  }
  EXPECT_GT(calls, 20);
  const std::shared_ptr<const MatchField> sliced = build.field();
  ASSERT_NE(sliced, nullptr);
  EXPECT_EQ(sliced->min_cell(), whole.min_cell());
  EXPECT_EQ(sliced->max_cell(), whole.max_cell());
  ASSERT_EQ(sliced->levels(), whole.levels());
  for (int level = 0; level <= whole.levels(); ++level) {
    for (int32_t y = whole.min_cell().y - pad - 1; y <= whole.max_cell().y; ++y) {
      for (int32_t x = whole.min_cell().x - pad - 1; x <= whole.max_cell().x; ++x) {
        ASSERT_EQ(sliced->At(level, {x, y}), whole.At(level, {x, y}))
            << level << " " << x << " " << y;
      }
    }
  }
  EXPECT_EQ(sliced->At(0, {250, 250}), 0);
  // Built to the end at once, the same work.
  MatchFieldBuild at_once(DrawnGrid(LRoom()), config);
  at_once.Finish();
  EXPECT_EQ(at_once.lookups(), build.lookups());
  // An empty grid: an empty field after one step.
  MatchFieldBuild empty(OccupancyGrid(GridGeometry(kMapCell), EncodeLogOdds(5.0)), config);
  EXPECT_TRUE(empty.Continue(1));
  ASSERT_NE(empty.field(), nullptr);
  EXPECT_TRUE(empty.field()->empty());
}

TEST(MatchFieldTest, OnALargeMapNoSliceOfTheBuildCostsAWholeView) {
  // A 30 x 24 m building's outline: its views hold some 450000 cells at 4 cm, far more than a
  // tile read or a row costs, and a scan's share of a few thousand lookups is never overrun by
  // more than a row's work.
  const OccupancyGrid grid = DrawnGrid(testing::Outline(
      {{-15.0, -12.0}, {15.0, -12.0}, {15.0, 12.0}, {-15.0, 12.0}, {-15.0, -12.0}}, 0.02));
  MatchFieldConfig config;
  config.resolution_m = 0.04;
  config.sigma_m = 0.04;
  config.levels = 4;
  MatchFieldBuild build(grid, config);
  const int64_t share = 2000;
  int64_t largest = 0;
  while (!build.done()) {
    const int64_t before = build.lookups();
    build.Continue(share);
    largest = std::max(largest, build.lookups() - before);
  }
  const MatchField& field = *build.field();
  const int32_t pad = (1 << config.levels) - 1;
  const int64_t width = field.max_cell().x - field.min_cell().x + pad;
  const int64_t height = field.max_cell().y - field.min_cell().y + pad;
  ASSERT_GT(width * height, 400000);
  EXPECT_LE(largest, share + std::max<int64_t>(9 * kTileCells, 2 * width));
  EXPECT_LT(largest, width * height / 4);
  const MatchField whole = MatchField::FromGrid(grid, config);
  for (int level = 0; level <= whole.levels(); ++level) {
    for (int32_t y = whole.min_cell().y - pad - 1; y <= whole.max_cell().y; y += 7) {
      for (int32_t x = whole.min_cell().x - pad - 1; x <= whole.max_cell().x; ++x) {
        ASSERT_EQ(field.At(level, {x, y}), whole.At(level, {x, y}))
            << level << " " << x << " " << y;
      }
    }
  }
}

TEST(GlobalSearchTest, EqualsAnExhaustiveSearchOnRandomFields) {
  for (uint64_t seed = 1; seed <= 12; ++seed) {
    Rng rng(seed);
    const int width = 20 + static_cast<int>(rng.Uniform() * 30);
    const int height = 20 + static_cast<int>(rng.Uniform() * 30);
    std::vector<uint8_t> scores(static_cast<size_t>(width * height), 0);
    for (uint8_t& s : scores) {
      if (rng.Uniform() < 0.15) s = static_cast<uint8_t>(1 + rng.Uniform() * 254);
    }
    const int levels = 1 + static_cast<int>(seed % 4);
    auto field = std::make_shared<const MatchField>(
        MatchField::FromScores(0.05, {-7, 3}, width, height, scores, levels));
    std::vector<Vec2> points;
    const int count = 5 + static_cast<int>(rng.Uniform() * 20);
    for (int i = 0; i < count; ++i) {
      points.push_back({(rng.Uniform() - 0.5) * 1.6, (rng.Uniform() - 0.5) * 1.6});
    }
    GlobalRegion region;
    if (seed % 2 == 0) {
      region.whole_map = false;
      region.center = {0.3, 1.2};
      region.half_width_m = 0.6;
      region.heading = 1.0;
      region.half_angle_rad = 0.5;
    }
    GlobalSearchConfig config;
    config.min_score = 0.0;
    config.unique_ratio = 0.6;
    config.distinct_m = 0.2;
    config.candidates = 1 + static_cast<int>(seed % 5);
    // Every third seed turns the query about its centroid, every fourth takes headings twice
    // as far apart: still exact over the candidates it has.
    config.turn_about_centroid = seed % 3 == 0;
    config.heading_step_cells = seed % 4 == 3 ? 2.0 : 1.0;
    GlobalSearch search(field, points, region, config);
    search.Finish();
    const int64_t expected = BruteForceBest(*field, search);
    ASSERT_GT(expected, 0) << seed;
    ASSERT_TRUE(search.best()) << seed;
    EXPECT_EQ(search.best()->raw, expected) << seed;
    EXPECT_EQ(ScoreAt(*field, search, *search.best()), expected) << seed;
    EXPECT_DOUBLE_EQ(search.best()->score, static_cast<double>(expected) / (255.0 * count));
    // The candidates kept: best first, distinct from one another, above unique_ratio of the
    // best, no more than asked for.
    const std::vector<GlobalMatch>& kept = search.candidates();
    ASSERT_LE(kept.size(), static_cast<size_t>(config.candidates));
    for (size_t i = 1; i < kept.size(); ++i) {
      EXPECT_LE(kept[i].raw, kept[i - 1].raw);
      EXPECT_GT(static_cast<double>(kept[i].raw),
                config.unique_ratio * static_cast<double>(expected));
      for (size_t j = 0; j < i; ++j) EXPECT_TRUE(Distinct(kept[i], kept[j], config));
    }
    // Branch and bound looked at fewer candidates than there are.
    const int64_t candidates = static_cast<int64_t>(search.headings()) *
                               (search.max_offset().x - search.min_offset().x + 1) *
                               (search.max_offset().y - search.min_offset().y + 1);
    EXPECT_LT(search.lookups(), candidates * count) << seed;
  }
}

TEST(GlobalSearchTest, PlacesAViewOfAnLShapedRoomAnywhereInIt) {
  const std::vector<Vec2> outline = LRoom();
  const OccupancyGrid grid = DrawnGrid(outline);
  auto field = std::make_shared<const MatchField>(MatchField::FromGrid(grid, {}));
  for (const Pose2& truth :
       {Pose2{0.2, -0.3, 2.5}, Pose2{-0.5, 0.5, -1.2}, Pose2{1.0, -0.6, 0.1}}) {
    const std::vector<Vec2> seen = SeenFrom(outline, truth, 1.5, 3);
    ASSERT_GT(seen.size(), 50u);
    GlobalSearch search(field, seen, GlobalRegion{});
    search.Finish();
    ASSERT_TRUE(search.best());
    const GlobalMatch m = *search.best();
    EXPECT_LT((m.pose.translation() - truth.translation()).norm(), 0.06)
        << m.pose.x << " " << m.pose.y;
    EXPECT_LT(std::abs(NormalizeAngle(m.pose.theta - truth.theta)), DegToRad(3.0));
    EXPECT_GT(m.score, 0.8);
    // Nothing else in an L-shaped room looks nearly like it.
    EXPECT_FALSE(search.runner_up()) << search.runner_up()->score << " vs " << m.score;
  }
}

TEST(GlobalSearchTest, TurningAboutTheCentroidTriesFewerHeadingsAndPlacesTheSameFrame) {
  const std::vector<Vec2> outline = LRoom();
  const OccupancyGrid grid = DrawnGrid(outline);
  auto field = std::make_shared<const MatchField>(MatchField::FromGrid(grid, {}));
  const Pose2 truth{0.2, -0.3, 2.5};
  // A multiscan's frame lies at one end of what it holds: here 0.8 m from the robot (still in
  // the room: a search about the origin tries only origins on the field).
  const Pose2 behind{-0.6, -0.5, 0.3};
  const Pose2 frame = Compose(truth, behind);
  std::vector<Vec2> query;
  for (const Vec2& p : SeenFrom(outline, truth, 1.5, 3))
    query.push_back(Inverse(behind).Transform(p));
  GlobalSearchConfig about_origin, about_centroid;
  about_centroid.turn_about_centroid = true;
  GlobalSearch a(field, query, GlobalRegion{}, about_origin);
  GlobalSearch b(field, query, GlobalRegion{}, about_centroid);
  a.Finish();
  b.Finish();
  EXPECT_EQ(a.pivot(), Vec2::Zero());
  EXPECT_GT(b.pivot().norm(), 0.3);
  EXPECT_LT(b.headings() * 4, a.headings() * 3);
  EXPECT_LT(b.lookups(), a.lookups());
  for (const GlobalSearch* search : {&a, &b}) {
    ASSERT_TRUE(search->best());
    const Pose2 found = search->best()->pose;
    EXPECT_LT((found.translation() - frame.translation()).norm(), 0.08)
        << found.x << " " << found.y;
    EXPECT_LT(std::abs(NormalizeAngle(found.theta - frame.theta)), DegToRad(3.0));
  }
  // A search in a region never turns about anything but the query's origin.
  GlobalRegion region;
  region.whole_map = false;
  region.center = frame.translation();
  region.half_width_m = 0.2;
  region.heading = frame.theta;
  region.half_angle_rad = DegToRad(5.0);
  EXPECT_EQ(GlobalSearch(field, query, region, about_centroid).pivot(), Vec2::Zero());
}

TEST(GlobalSearchTest, ASymmetricRoomGivesARunnerUpAsGoodAsTheBest) {
  // A 2 x 1 m rectangle looks the same turned by half a turn.
  const std::vector<Vec2> corners{{-1.0, -0.5}, {1.0, -0.5}, {1.0, 0.5}, {-1.0, 0.5}, {-1.0, -0.5}};
  const std::vector<Vec2> outline = testing::Outline(corners, 0.01);
  auto field = std::make_shared<const MatchField>(MatchField::FromGrid(DrawnGrid(outline), {}));
  const Pose2 truth{0.3, 0.1, 0.4};
  GlobalSearch search(field, SeenFrom(outline, truth, 3.0, 4), GlobalRegion{});
  search.Finish();
  ASSERT_TRUE(search.best());
  ASSERT_TRUE(search.runner_up());
  EXPECT_GT(search.runner_up()->score, 0.9 * search.best()->score);
  // The two are the pose and its mirror through the room's centre.
  const bool best_is_truth = (search.best()->pose.translation() - truth.translation()).norm() < 0.1;
  const GlobalMatch mirror = best_is_truth ? *search.runner_up() : *search.best();
  EXPECT_LT((mirror.pose.translation() + truth.translation()).norm(), 0.1);
}

TEST(GlobalSearchTest, AnytimeSlicesKeepTheirShareAndEndWhereOneCallEnds) {
  const std::vector<Vec2> outline = LRoom();
  auto field = std::make_shared<const MatchField>(MatchField::FromGrid(DrawnGrid(outline), {}));
  const std::vector<Vec2> seen = SeenFrom(outline, {0.1, 0.2, -2.0}, 1.5, 3);
  GlobalSearch whole(field, seen, GlobalRegion{});
  whole.Finish();
  GlobalSearch sliced(field, seen, GlobalRegion{});
  const int64_t share = 5000;
  const auto per_node = static_cast<int64_t>(4 * seen.size());
  int calls = 0;
  while (!sliced.done()) {
    const int64_t before = sliced.lookups();
    sliced.Continue(share);
    // A call stops at its share, overrunning by at most the expansion in progress.
    EXPECT_LE(sliced.lookups() - before, share + per_node);
    EXPECT_GT(sliced.lookups(), before);
    ++calls;
    if (calls == 3) {
      ASSERT_FALSE(sliced.done());
    }
  }
  EXPECT_GT(calls, 10);
  ASSERT_TRUE(sliced.best() && whole.best());
  EXPECT_EQ(sliced.best()->raw, whole.best()->raw);
  EXPECT_EQ(sliced.lookups(), whole.lookups());
}

TEST(GlobalSearchTest, NothingToMatchEndsAtOnceWithoutAnAnswer) {
  const OccupancyGrid empty(GridGeometry(kMapCell), EncodeLogOdds(5.0));
  auto none = std::make_shared<const MatchField>(MatchField::FromGrid(empty, {}));
  EXPECT_TRUE(none->empty());
  GlobalSearch on_empty(none, {{1.0, 0.0}}, GlobalRegion{});
  EXPECT_TRUE(on_empty.Continue(100));
  EXPECT_FALSE(on_empty.best());
  EXPECT_EQ(on_empty.lookups(), 0);

  auto field = std::make_shared<const MatchField>(MatchField::FromGrid(DrawnGrid(LRoom()), {}));
  GlobalSearch no_points(field, {}, GlobalRegion{});
  EXPECT_TRUE(no_points.Continue(100));
  EXPECT_FALSE(no_points.best());
  // Points that fit nowhere as well as the floor asks find no answer.
  GlobalSearchConfig strict;
  strict.min_score = 0.99;
  std::vector<Vec2> spread;
  for (int i = 0; i < 40; ++i) spread.push_back({0.05 * i, 0.03 * (i % 7)});
  GlobalSearch unfit(field, spread, GlobalRegion{}, strict);
  unfit.Finish();
  EXPECT_FALSE(unfit.best());
}

}  // namespace
}  // namespace slam
