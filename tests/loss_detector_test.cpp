// The loss detector on a drawn L room: readings placed right agree, placed where the map is
// known free or seen through a wall contradict, in unknown space say nothing; a window of
// contradicting scans is a loss, a single one or a room not yet mapped is not.

#include "engine/loss_detector.hpp"

#include <gtest/gtest.h>

#include "tests/drawn_rooms.hpp"

namespace slam {
namespace {

using testing::Draw;
using testing::LRoom;
using testing::SeenFrom;

/// The L room drawn at 1 cm with its inside seen free (what a robot that drove there maps).
OccupancyGrid MappedLRoom() {
  OccupancyGrid map = Draw(LRoom(), 0.01);
  map.BeginWrite();
  for (double x = -0.97; x < 1.38; x += 0.01) {
    for (double y = -0.97; y < 0.98; y += 0.01) {
      const bool in_cut = x > 0.57 && y > 0.27;
      const bool in_box = x > -0.53 && x < -0.27 && y > 0.27 && y < 0.53;
      const CellIndex c = map.geometry().CellOf({x, y});
      if (!in_cut && !in_box && map.At(c) == 0) map.Add(c, EncodeLogOdds(-4.0));
    }
  }
  return map;
}

TEST(LossDetector, ReadingsPlacedRightAgreeAndPlacedInFreeSpaceContradict) {
  const OccupancyGrid map = MappedLRoom();
  const Pose2 robot{0.1, -0.3, 0.4};
  const std::vector<Vec2> seen = SeenFrom(LRoom(), robot, 1.2, 10);
  ASSERT_GT(seen.size(), 80u);
  LossDetector right;
  const LossCheck ok = right.Check(map, robot, seen);
  EXPECT_EQ(ok.agree, static_cast<int>(seen.size()));
  EXPECT_EQ(ok.contradict, 0);
  EXPECT_LE(ok.lookups, right.MaxLookups());
  EXPECT_GT(ok.lookups, 0);
  // Placed a quarter turn and 30 cm off, most readings land inside the room, where it is free.
  LossDetector wrong;
  const LossCheck bad = wrong.Check(map, Compose(robot, Pose2{0.3, 0.0, kPi / 2}), seen);
  EXPECT_GT(bad.contradict, 2 * bad.agree) << bad.agree << " agree, " << bad.unknown << " unknown";
}

TEST(LossDetector, AWindowOfContradictingScansIsALossOneScanIsNot) {
  const OccupancyGrid map = MappedLRoom();
  const Pose2 robot{0.1, -0.3, 0.4};
  const Pose2 off = Compose(robot, Pose2{0.3, 0.0, kPi / 2});
  const std::vector<Vec2> seen = SeenFrom(LRoom(), robot, 1.2, 10);
  LossDetectorConfig config;
  LossDetector detector(config);
  for (int k = 0; k < 20; ++k) {
    // One bad scan among good ones (a person crossing the beams) is no loss.
    const LossCheck c = detector.Check(map, k == 10 ? off : robot, seen);
    EXPECT_FALSE(c.lost) << k;
    EXPECT_LT(c.window_share, config.lost_share) << k;
  }
  int scans = 0;
  LossCheck c;
  while (!c.lost && scans < 20) {
    c = detector.Check(map, off, seen);
    ++scans;
  }
  EXPECT_TRUE(c.lost);
  EXPECT_GE(c.window_share, config.lost_share);
  EXPECT_LE(scans, config.window_scans);  // as soon as the window turns
  detector.Reset();
  EXPECT_FALSE(detector.Check(map, off, seen).lost) << "a reset window holds no verdict";
}

TEST(LossDetector, UnknownSpaceSaysNothing) {
  // A room not yet mapped: readings placed there land in unknown space, their rays cross no
  // wall the map knows, and they are no contradiction.
  const OccupancyGrid map = MappedLRoom();
  const std::vector<Vec2> seen = SeenFrom(LRoom(), Pose2{0.1, -0.3, 0.4}, 1.2, 10);
  LossDetector detector;
  for (int k = 0; k < 10; ++k) {
    const LossCheck c = detector.Check(map, Pose2{6.0, 5.0, 2.0}, seen);
    EXPECT_EQ(c.contradict, 0);
    EXPECT_EQ(c.unknown, static_cast<int>(seen.size()));
    EXPECT_FALSE(c.lost);
  }
  // Nor do readings that are not finite.
  std::vector<Vec2> bad(50, Vec2(std::nan(""), 0.0));
  const LossCheck c = detector.Check(map, Pose2{}, bad);
  EXPECT_EQ(c.agree + c.contradict + c.unknown, 0);
}

/// Readings from (0, 0) straight down, `beyond` metres past the L room's bottom wall (y = -1).
std::vector<Vec2> Beyond(double beyond) {
  std::vector<Vec2> points;
  for (double x = -0.6; x <= 0.6; x += 0.05) points.push_back({x, -1.0 - beyond});
  return points;
}

TEST(LossDetector, AReadingSeenThroughAWallTheMapIsSureOfContradictsIt) {
  // A robot set down elsewhere sees, placed where it wrongly is, walls beyond the room's: the
  // readings land in unknown space, but their rays cross the room's wall.
  const OccupancyGrid map = MappedLRoom();
  const std::vector<Vec2> beyond = Beyond(0.2);
  LossDetector detector;
  const LossCheck c = detector.Check(map, Pose2{}, beyond);
  EXPECT_EQ(c.contradict, static_cast<int>(beyond.size()));
  EXPECT_EQ(c.through, c.contradict);
  EXPECT_EQ(c.unknown, 0);
  EXPECT_LE(c.lookups, detector.MaxLookups());
  // Ending on the wall (a ray that grazes it on the way in ends there too): they agree.
  const LossCheck on = detector.Check(map, Pose2{}, Beyond(0.0));
  EXPECT_EQ(on.agree, static_cast<int>(beyond.size()));
  EXPECT_EQ(on.through, 0);
  // A wall the map is not sure of (below through_above_logodds) proves nothing; nor one the
  // ray crosses only within through_margin_m of its end.
  LossDetectorConfig unsure;
  unsure.through_above_logodds = 4.0;  // the drawn walls are at 3
  EXPECT_EQ(LossDetector(unsure).Check(map, Pose2{}, beyond).unknown,
            static_cast<int>(beyond.size()));
  LossDetectorConfig wide_margin;
  wide_margin.through_margin_m = 0.25;
  EXPECT_EQ(LossDetector(wide_margin).Check(map, Pose2{}, beyond).through, 0);
  // Nor one farther back along the ray than through_reach_m.
  LossDetectorConfig short_reach;
  short_reach.through_reach_m = 0.05;
  EXPECT_EQ(LossDetector(short_reach).Check(map, Pose2{}, beyond).through, 0);
}

TEST(LossDetector, ConfigIsValidated) {
  EXPECT_TRUE(LossDetectorConfig{}.Validate().empty());
  LossDetectorConfig bad;
  bad.lost_share = 0.0;
  bad.window_scans = 0;
  bad.free_below_logodds = 1.0;
  bad.through_above_logodds = -1.0;
  bad.through_margin_m = -0.1;
  bad.through_reach_m = std::nan("");
  EXPECT_EQ(bad.Validate().size(), 6u);
}

}  // namespace
}  // namespace slam
