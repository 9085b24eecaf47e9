// The relocaliser on maps drawn cell by cell: a robot driving in a room finds itself, an
// ambiguous place is not taken.
#include "engine/relocalizer.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
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

TEST(Relocalizer, FindsARobotDrivingInADrawnRoomAndCarriesItsPoseToTheNewestScan) {
  const std::vector<Vec2> outline = LRoom();
  const OccupancyGrid map = Draw(outline, 0.01);
  Relocalizer relocalizer;
  relocalizer.Start(map);
  EXPECT_TRUE(relocalizer.active());
  // The robot drives a slow arc; its odometry starts at another origin (it was carried).
  const Pose2 odom_origin{5.0, -3.0, 1.0};
  const Pose2 start{-0.6, -0.5, 0.3};
  std::optional<Relocalization> found;
  Pose2 truth;
  int scans = 0;
  for (; scans < 60 && !found; ++scans) {
    const double t = 0.6 * scans;
    truth = Compose(start, Pose2{0.08 * t, 0.0, 0.0});
    truth.theta = start.theta + 0.05 * t;
    const Pose2 odom = Compose(odom_origin, Between(start, truth));
    const RelocalizerStep step =
        relocalizer.Add(SeenFrom(outline, truth, 1.2, 40), odom, t, 200'000);
    EXPECT_TRUE(step.searching || step.found);
    EXPECT_LE(step.lookups, 200'000 + 4 * RelocalizerConfig{}.max_points);
    found = step.found;
  }
  ASSERT_TRUE(found) << "not found in " << scans << " scans";
  EXPECT_LT((found->pose.translation() - truth.translation()).norm(), 0.03)
      << found->pose.x << " " << found->pose.y << " vs " << truth.x << " " << truth.y;
  EXPECT_LT(std::abs(NormalizeAngle(found->pose.theta - truth.theta)), DegToRad(2.0));
  EXPECT_GE(found->score, RelocalizerConfig{}.accept_score);
  EXPECT_EQ(found->lookups, relocalizer.lookups());
  // The whole map, at least one check, two confirmations.
  EXPECT_GE(found->searches, 4);
  EXPECT_FALSE(relocalizer.active());  // done: the engine takes over
  // Slower than one scan: the search was spread over several.
  EXPECT_GT(scans, 3);
}

TEST(Relocalizer, AnAmbiguousSearchIsNotTakenAndAnInactiveOneDoesNothing) {
  // Two identical rooms side by side: a view inside one fits both.
  OccupancyGrid map(GridGeometry(0.01), EncodeLogOdds(5.0));
  map.BeginWrite();
  for (const double x0 : {0.0, 3.0}) {
    for (int i = 0; i <= 200; ++i) {
      for (const Vec2& p : {Vec2{x0 + i * 0.01, 0.0}, Vec2{x0 + i * 0.01, 1.5},
                            Vec2{x0, i * 0.0075}, Vec2{x0 + 2.0, i * 0.0075}}) {
        map.Add(map.geometry().CellOf(p), EncodeLogOdds(3.0));
      }
    }
    for (int i = 0; i < 20; ++i)
      map.Add(map.geometry().CellOf({x0 + 0.5 + i * 0.01, 0.4}), EncodeLogOdds(3.0));
  }
  map.RefreshSummaries();
  std::vector<Vec2> seen;
  for (int i = 0; i <= 200; i += 2) {
    seen.push_back(Vec2{-1.0 + i * 0.01, -0.7});
    seen.push_back(Vec2{-1.0, -0.7 + i * 0.0075});
  }
  for (int i = 0; i < 20; i += 2) seen.push_back(Vec2{-0.5 + i * 0.01, -0.3});
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

}  // namespace
}  // namespace slam
