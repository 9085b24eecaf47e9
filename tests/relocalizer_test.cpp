// The relocaliser on maps drawn cell by cell: a robot driving in a room finds itself, an
// ambiguous place is not taken.
#include "engine/relocalizer.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "drawn_rooms.hpp"
#include "engine/cell_encoding.hpp"
#include "engine/slam.hpp"

namespace slam {
namespace {

constexpr int64_t kBudget = 16250;

using testing::Draw;
using testing::LRoom;
using testing::SeenFrom;

struct Drive {
  std::optional<Relocalization> found;
  Pose2 truth;
  int scans = 0;
  int64_t lookups = 0;
};

// A robot driving a slow arc in the drawn L room, its odometry from another origin (it was
// carried), each scan's view given to the relocaliser until it answers. With `bad_input`, every
// scan also brings readings that are not finite or absurdly far, and a scan of odometry that is
// not finite comes before each.
// With `rival_offset`, the relocaliser is given a rival each scan: the truth moved by it.
Drive DriveInLRoom(bool bad_input, std::optional<Pose2> rival_offset = std::nullopt) {
  const std::vector<Vec2> outline = LRoom();
  Relocalizer relocalizer;
  relocalizer.Start(Draw(outline, 0.01));
  EXPECT_TRUE(relocalizer.active());
  const Pose2 odom_origin{5.0, -3.0, 1.0};
  const Pose2 start{-0.6, -0.5, 0.3};
  const double nan = std::numeric_limits<double>::quiet_NaN();
  Drive drive;
  for (; drive.scans < 60 && !drive.found; ++drive.scans) {
    const double t = 0.6 * drive.scans;
    drive.truth = Compose(start, Pose2{0.08 * t, 0.0, 0.0});
    drive.truth.theta = start.theta + 0.05 * t;
    const Pose2 odom = Compose(odom_origin, Between(start, drive.truth));
    std::vector<Vec2> points = SeenFrom(outline, drive.truth, 1.2, 40);
    if (bad_input) {
      const RelocalizerStep skipped = relocalizer.Add(points, {nan, 0.0, 0.0}, t - 0.1, 200'000);
      EXPECT_EQ(skipped.lookups, 0);
      EXPECT_FALSE(skipped.found);
      points.insert(points.begin(), {Vec2{nan, 0.5}, Vec2{1e300, -1e300}});
    }
    if (rival_offset) relocalizer.SetRival(Compose(drive.truth, *rival_offset), odom);
    const RelocalizerStep step = relocalizer.Add(points, odom, t, 200'000);
    EXPECT_TRUE(step.searching || step.found);
    EXPECT_LE(step.lookups, 200'000 + 4 * RelocalizerConfig{}.max_points);
    drive.found = step.found;
  }
  drive.lookups = relocalizer.lookups();
  EXPECT_FALSE(relocalizer.active());  // done: the engine takes over
  return drive;
}

TEST(Relocalizer, FindsARobotDrivingInADrawnRoomAndCarriesItsPoseToTheNewestScan) {
  const Drive drive = DriveInLRoom(false);
  const std::optional<Relocalization>& found = drive.found;
  const Pose2& truth = drive.truth;
  ASSERT_TRUE(found) << "not found in " << drive.scans << " scans";
  EXPECT_LT((found->pose.translation() - truth.translation()).norm(), 0.03)
      << found->pose.x << " " << found->pose.y << " vs " << truth.x << " " << truth.y;
  EXPECT_LT(std::abs(NormalizeAngle(found->pose.theta - truth.theta)), DegToRad(2.0));
  EXPECT_GE(found->score, RelocalizerConfig{}.accept_score);
  EXPECT_EQ(found->lookups, drive.lookups);
  // The whole map, at least one check, two confirmations.
  EXPECT_GE(found->searches, 4);
  // Slower than one scan: the search was spread over several.
  EXPECT_GT(drive.scans, 3);
}

TEST(Relocalizer, ARivalIsScoredBesideTheAnswerWhereverItIs) {
  const Drive plain = DriveInLRoom(false);
  ASSERT_TRUE(plain.found);
  EXPECT_EQ(plain.found->rival_score, 0.0);
  // The rival at the truth: the answer is there, and the rival scores as well as it.
  const Drive at_truth = DriveInLRoom(false, Pose2{0.0, 0.0, 0.0});
  ASSERT_TRUE(at_truth.found);
  EXPECT_LT((at_truth.found->pose.translation() - at_truth.truth.translation()).norm(), 0.03);
  EXPECT_GE(at_truth.found->rival_score, RelocalizerConfig{}.accept_score);
  // The rival turned and moved away (where a lost tracker would be): the answer is still the
  // truth, and the rival's score says the readings do not fit there.
  const Drive away = DriveInLRoom(false, Pose2{3.0, -3.0, 1.5});
  ASSERT_TRUE(away.found);
  EXPECT_LT((away.found->pose.translation() - away.truth.translation()).norm(), 0.03);
  EXPECT_LT(away.found->rival_score, 0.5);
  EXPECT_GT(away.found->score, away.found->rival_score + 0.3);
}

TEST(Relocalizer, ReadingsAndOdometryThatAreNotFiniteAreSkipped) {
  const Drive clean = DriveInLRoom(false);
  const Drive bad = DriveInLRoom(true);
  ASSERT_TRUE(clean.found && bad.found);
  EXPECT_EQ(bad.scans, clean.scans);
  EXPECT_EQ(bad.found->pose.x, clean.found->pose.x);
  EXPECT_EQ(bad.found->pose.y, clean.found->pose.y);
  EXPECT_EQ(bad.found->pose.theta, clean.found->pose.theta);
  EXPECT_EQ(bad.lookups, clean.lookups);
}

// Two identical rooms side by side (2 x 1.5 m, at x = 0 and x = 3, a short wall inside each),
// and what a robot at (1, 0.7, 0) in the first, or at (4, 0.7, 0) in the second, sees.
struct TwinRooms {
  OccupancyGrid map{GridGeometry(0.01), EncodeLogOdds(5.0)};
  std::vector<Vec2> seen;
};

/// With `second_wall_m`, the second room's short wall is that long instead of 0.2 m (a
/// near-twin).
TwinRooms DrawTwinRooms(double second_wall_m = 0.2) {
  TwinRooms twins;
  OccupancyGrid& map = twins.map;
  map.BeginWrite();
  for (const double x0 : {0.0, 3.0}) {
    for (int i = 0; i <= 200; ++i) {
      for (const Vec2& p : {Vec2{x0 + i * 0.01, 0.0}, Vec2{x0 + i * 0.01, 1.5},
                            Vec2{x0, i * 0.0075}, Vec2{x0 + 2.0, i * 0.0075}}) {
        map.Add(map.geometry().CellOf(p), EncodeLogOdds(3.0));
      }
    }
    const int wall_cells = static_cast<int>(std::lround((x0 == 0.0 ? 0.2 : second_wall_m) / 0.01));
    for (int i = 0; i < wall_cells; ++i)
      map.Add(map.geometry().CellOf({x0 + 0.5 + i * 0.01, 0.4}), EncodeLogOdds(3.0));
  }
  map.RefreshSummaries();
  for (int i = 0; i <= 200; i += 2) {
    twins.seen.push_back(Vec2{-1.0 + i * 0.01, -0.7});
    twins.seen.push_back(Vec2{-1.0, -0.7 + i * 0.0075});
  }
  for (int i = 0; i < 20; i += 2) twins.seen.push_back(Vec2{-0.5 + i * 0.01, -0.3});
  return twins;
}

TEST(Relocalizer, AnAmbiguousSearchIsNotTakenAndAnInactiveOneDoesNothing) {
  const TwinRooms twins = DrawTwinRooms();
  const OccupancyGrid& map = twins.map;
  const std::vector<Vec2>& seen = twins.seen;
  Relocalizer relocalizer;
  EXPECT_FALSE(relocalizer.Add(seen, Pose2{}, 0.0, 1'000'000'000).searching);
  relocalizer.Start(map);
  const RelocalizerStep step = relocalizer.Add(seen, Pose2{}, 0.0, 1'000'000'000);
  EXPECT_FALSE(step.found);
  ASSERT_TRUE(step.rejected_best);
  EXPECT_GT(step.rejected_best->score, 0.8);
  EXPECT_GT(step.rejected_runner_up, 0.95 * step.rejected_best->score);
  EXPECT_TRUE(relocalizer.active());
}

// The places an unsure search reports in the twin rooms (robot at (1, 0.7, 0)): both rooms,
// best first, each place once.
void ExpectEveryPlaceOnceBestFirstInBothRooms(const RelocalizerStep& step,
                                              const RelocalizerConfig& config) {
  const std::vector<GlobalMatch>& places = step.rejected_candidates;
  ASSERT_GE(places.size(), 2u);
  ASSERT_TRUE(step.rejected_best);
  EXPECT_EQ(places[0].pose.x, step.rejected_best->pose.x);
  EXPECT_EQ(places[1].score, step.rejected_runner_up);
  for (size_t i = 1; i < places.size(); ++i) {
    EXPECT_LE(places[i].score, places[i - 1].score);
    for (size_t j = 0; j < i; ++j) EXPECT_TRUE(Distinct(places[i], places[j], config.search));
  }
  for (const double x : {1.0, 4.0}) {
    EXPECT_TRUE(std::any_of(places.begin(), places.end(),
                            [&](const GlobalMatch& p) {
                              return (p.pose.translation() - Vec2{x, 0.7}).norm() < 0.05 &&
                                     std::abs(NormalizeAngle(p.pose.theta)) < DegToRad(3.0);
                            }))
        << "no place in the room at x = " << x;
  }
}

TEST(Relocalizer, APlaceThatLeadsItsTwinSearchAfterSearchIsTakenAnExactTwinNever) {
  // The robot stands in the first room, whose short wall is 20 cm long; the second room's is
  // 12 cm: 4 of the 10 readings of the wall miss there. Each search finds both rooms, the first
  // a little ahead (less than unique_margin): it is taken once it led lead_searches searches
  // by lead_sum in all, never without the rule, nor between rooms exactly alike.
  const auto search = [](const TwinRooms& twins, const RelocalizerConfig& config) {
    Relocalizer relocalizer(config);
    relocalizer.Start(twins.map);
    Drive drive;
    for (; drive.scans < 40 && !drive.found; ++drive.scans) {
      const RelocalizerStep step =
          relocalizer.Add(twins.seen, Pose2{}, 1.0 * drive.scans, 1'000'000'000);
      if (drive.scans == 0) {  // the first search alone cannot tell the rooms apart
        EXPECT_FALSE(step.found);
        EXPECT_TRUE(step.rejected_best);
        EXPECT_GT(step.rejected_runner_up, step.rejected_best->score - config.unique_margin);
        EXPECT_LE(step.rejected_runner_up, step.rejected_best->score);
        ExpectEveryPlaceOnceBestFirstInBothRooms(step, config);
      }
      drive.found = step.found;
    }
    return drive;
  };
  const TwinRooms near_twins = DrawTwinRooms(0.12);
  const RelocalizerConfig config;
  const Drive led = search(near_twins, config);
  ASSERT_TRUE(led.found) << "not taken in " << led.scans << " scans";
  EXPECT_LT((led.found->pose.translation() - Vec2{1.0, 0.7}).norm(), 0.03)
      << led.found->pose.x << " " << led.found->pose.y;
  EXPECT_LT(std::abs(led.found->pose.theta), DegToRad(2.0));
  EXPECT_GT(led.found->runner_up_score, led.found->score - config.unique_margin);

  RelocalizerConfig without = config;
  without.lead_searches = 1000;
  EXPECT_FALSE(search(near_twins, without).found);
  EXPECT_FALSE(search(DrawTwinRooms(), config).found);
}

TEST(Relocalizer, TheMapsFieldsAreBuiltFromTheScansSharesBeforeTheFirstSearch) {
  // The twin rooms' fields as the relocaliser builds them (never finer than the map's cells).
  const TwinRooms twins = DrawTwinRooms();
  const RelocalizerConfig config;
  int64_t build_cost = 0;
  for (const MatchFieldConfig& field : {config.field, config.fine_field}) {
    MatchFieldBuild build(twins.map, field);
    build.Finish();
    build_cost += build.lookups();
  }
  Relocalizer relocalizer(config);
  relocalizer.Start(twins.map);
  EXPECT_EQ(relocalizer.lookups(), 0);  // Start itself builds nothing
  const int64_t share = 5000;
  int scans = 0;
  while (relocalizer.searches() == 0) {
    ASSERT_LT(scans, 1000);
    const int64_t before = relocalizer.lookups();
    const RelocalizerStep step = relocalizer.Add(twins.seen, Pose2{}, 0.5 * scans++, share);
    EXPECT_TRUE(step.searching);
    EXPECT_EQ(step.lookups, relocalizer.lookups() - before);
    // A share, overrun by at most one step of a build (a view of these small fields) or of
    // the search (one node: four points' lookups and a few).
    EXPECT_LE(step.lookups, share + 20'000);
    if (relocalizer.searches() == 0) {
      EXPECT_LE(relocalizer.lookups(), build_cost);
    }
  }
  // The builds took several scans' shares (each scan spends its whole share: no more scans
  // than shares in their cost), then the search began on the scan they ended.
  EXPECT_GT(scans, 2);
  EXPECT_LE(scans, build_cost / share + 1);
  EXPECT_GE(relocalizer.lookups(), build_cost);
}

TEST(Relocalizer, AHintGivenEarlierIsCarriedByTheOdometryAndSettlesAnAmbiguity) {
  // The robot stands in the second room at (4, 0.7, 0). Someone said "about (3.5, 0.7)" when the
  // robot was half a metre behind where it is now: carried by the odometry, the hint's region
  // (20 cm) holds the robot, and only the second room's place.
  const TwinRooms twins = DrawTwinRooms();
  const Pose2 odom_now{10.0, 10.0, 0.0};
  const Pose2 odom_then = Compose(odom_now, Pose2{-0.5, 0.0, 0.0});
  GlobalRegion hint;
  hint.whole_map = false;
  hint.center = Vec2{3.5, 0.7};
  hint.half_width_m = 0.2;
  hint.heading = 0.0;
  hint.half_angle_rad = DegToRad(10.0);
  const auto search = [&](const std::optional<Pose2>& given_at) {
    Relocalizer relocalizer;
    relocalizer.Start(twins.map, hint, given_at);
    std::optional<Relocalization> found;
    for (int k = 0; k < 30 && !found; ++k) {
      found = relocalizer.Add(twins.seen, odom_now, 0.6 * k, 1'000'000).found;
    }
    return found;
  };
  const std::optional<Relocalization> carried = search(odom_then);
  ASSERT_TRUE(carried);
  EXPECT_LT((carried->pose.translation() - Vec2{4.0, 0.7}).norm(), 0.03)
      << carried->pose.x << " " << carried->pose.y;
  EXPECT_LT(std::abs(carried->pose.theta), DegToRad(2.0));
  // Taken where the robot is now instead, the region misses it: nothing is found there.
  EXPECT_FALSE(search(odom_now));
}

}  // namespace
}  // namespace slam
