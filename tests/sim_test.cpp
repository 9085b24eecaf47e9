// Tests of the simulated worlds and of the simulated marXbot (sim/world.hpp, sim/scenario.hpp).

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "engine/io/robot_json.hpp"
#include "engine/pose.hpp"
#include "engine/robot.hpp"
#include "engine/sensor_model.hpp"
#include "sim/dataset.hpp"
#include "sim/scenario.hpp"
#include "sim/world.hpp"
#include "test_support.hpp"

namespace slam::sim {
namespace {

constexpr double kTol = 1e-12;

/// The marXbot description the project ships.
RobotDescription TestRobot() { return testing::ShippedRobot(); }

World OneWall() {
  World world;
  world.name = "wall";
  world.bounds = {-5.0, -5.0, 5.0, 5.0};
  world.segments.push_back({{1.0, -1.0}, {1.0, 1.0}});
  return world;
}

// ---------------------------------------------------------------------------------------------
// Ray casting and clearance against hand-computed values.

TEST(RayDistanceTest, HitsASegmentHeadOnAndObliquely) {
  const World world = OneWall();
  EXPECT_NEAR(*RayDistance(world, {0.0, 0.0}, 0.0, 5.0), 1.0, kTol);
  EXPECT_NEAR(*RayDistance(world, {0.0, 0.0}, DegToRad(30.0), 5.0), 1.0 / std::cos(DegToRad(30.0)),
              kTol);
  // Exactly through the end point (1, 1).
  EXPECT_NEAR(*RayDistance(world, {0.0, 0.0}, DegToRad(45.0), 5.0), std::sqrt(2.0), 1e-9);
  // From the other side, and from a point below the wall.
  EXPECT_NEAR(*RayDistance(world, {3.0, 0.5}, kPi, 5.0), 2.0, kTol);
  EXPECT_NEAR(*RayDistance(world, {0.0, -1.0}, DegToRad(45.0), 5.0), std::sqrt(2.0), 1e-9);
}

TEST(RayDistanceTest, MissesBesideBehindAndBeyondRange) {
  const World world = OneWall();
  EXPECT_FALSE(RayDistance(world, {0.0, 0.0}, DegToRad(60.0), 5.0));  // passes above (1, 1.73)
  EXPECT_FALSE(RayDistance(world, {0.0, 0.0}, kPi, 5.0));             // wall behind
  EXPECT_FALSE(RayDistance(world, {0.0, 0.0}, kPi / 2.0, 5.0));       // parallel, not collinear
  EXPECT_FALSE(RayDistance(world, {0.0, 0.0}, 0.0, 0.99));            // beyond the range
  EXPECT_TRUE(RayDistance(world, {0.0, 0.0}, 0.0, 1.0));              // range is inclusive
}

TEST(RayDistanceTest, CollinearSegmentIsHitAtItsNearerEnd) {
  World world;
  world.segments.push_back({{4.0, 0.0}, {2.0, 0.0}});
  EXPECT_NEAR(*RayDistance(world, {0.0, 0.0}, 0.0, 10.0), 2.0, kTol);
  EXPECT_NEAR(*RayDistance(world, {3.0, 0.0}, 0.0, 10.0), 0.0, kTol);  // starting on it
  EXPECT_FALSE(RayDistance(world, {5.0, 0.0}, 0.0, 10.0));             // past it
  EXPECT_NEAR(*RayDistance(world, {5.0, 0.0}, kPi, 10.0), 1.0, 1e-9);  // back along it
}

TEST(RayDistanceTest, CirclesFrontTangentInsideAndBehind) {
  World world;
  world.circles.push_back({{3.0, 0.0}, 0.5});
  EXPECT_NEAR(*RayDistance(world, {0.0, 0.0}, 0.0, 10.0), 2.5, kTol);
  EXPECT_NEAR(*RayDistance(world, {3.0, 2.0}, -kPi / 2.0, 10.0), 1.5, kTol);
  // Grazing ray: at asin(0.5 / 3) from the x axis it touches at distance sqrt(9 - 0.25).
  EXPECT_NEAR(*RayDistance(world, {0.0, 0.0}, std::asin(0.5 / 3.0) - 1e-9, 10.0), std::sqrt(8.75),
              1e-4);
  EXPECT_FALSE(RayDistance(world, {0.0, 0.0}, std::asin(0.5 / 3.0) + 1e-6, 10.0));
  EXPECT_NEAR(*RayDistance(world, {3.1, 0.0}, 1.0, 10.0), 0.0, kTol);  // inside
  EXPECT_FALSE(RayDistance(world, {0.0, 0.0}, kPi, 10.0));
}

TEST(RayDistanceTest, NearestOfSeveralObstaclesWins) {
  World world = OneWall();
  world.circles.push_back({{0.5, 0.0}, 0.1});
  EXPECT_NEAR(*RayDistance(world, {0.0, 0.0}, 0.0, 5.0), 0.4, kTol);
  EXPECT_NEAR(*RayDistance(world, {0.0, 0.5}, 0.0, 5.0), 1.0, kTol);
}

TEST(ClearanceTest, DistanceToNearestSegmentOrCircle) {
  World world = OneWall();
  EXPECT_NEAR(ClearanceAt(world, {0.0, 0.0}), 1.0, kTol);
  EXPECT_NEAR(ClearanceAt(world, {2.0, 2.0}), std::sqrt(2.0), kTol);  // nearest is the end (1, 1)
  world.circles.push_back({{-1.0, 0.0}, 0.25});
  EXPECT_NEAR(ClearanceAt(world, {0.0, 0.0}), 0.75, kTol);
  EXPECT_NEAR(ClearanceAt(world, {-1.1, 0.0}), 0.0, kTol);  // inside the disc
  EXPECT_TRUE(std::isinf(ClearanceAt(World{}, {0.0, 0.0})));
}

// ---------------------------------------------------------------------------------------------
// Built-in arenas.

/// Distance between two segments that do not cross.
double SegmentDistance(const Segment& s, const Segment& t) {
  World a, b;
  a.segments = {s};
  b.segments = {t};
  return std::min(
      {ClearanceAt(b, s.a), ClearanceAt(b, s.b), ClearanceAt(a, t.a), ClearanceAt(a, t.b)});
}

TEST(ArenaTest, BuiltinsAreValidNamedAndAboutTwoMetres) {
  const std::vector<std::string> names = BuiltinArenaNames();
  EXPECT_EQ(names, (std::vector<std::string>{"box", "rooms", "cluttered"}));
  for (const std::string& name : names) {
    SCOPED_TRACE(name);
    const std::optional<World> world = BuiltinWorld(name);
    ASSERT_TRUE(world);
    EXPECT_EQ(world->name, name);
    EXPECT_TRUE(Validate(*world).empty());
    const double width = world->bounds[2] - world->bounds[0];
    const double height = world->bounds[3] - world->bounds[1];
    EXPECT_GE(width, 1.5);
    EXPECT_LE(width, 3.0);
    EXPECT_GE(height, 1.5);
    EXPECT_LE(height, 3.0);
  }
  EXPECT_FALSE(BuiltinWorld("moon"));
  EXPECT_EQ(BuiltinWorld("cluttered")->circles.size(), 5u);
  EXPECT_GE(BuiltinWorld("cluttered")->segments.size(), 12u);  // walls and square obstacles
}

TEST(ArenaTest, RealSizeWorldsAreBuiltInValidAndOfRealSize) {
  EXPECT_EQ(BuiltinWorldNames(),
            (std::vector<std::string>{"box", "rooms", "cluttered", "flat", "corridor", "office",
                                      "studio", "lab", "building"}));
  // Free floor area of at least this many square metres, and the longest side.
  const std::map<std::string, std::pair<double, double>> expected = {
      {"flat", {20.0, 6.0}},   {"corridor", {12.0, 10.0}}, {"office", {30.0, 7.0}},
      {"studio", {15.0, 5.0}}, {"lab", {20.0, 6.0}},       {"building", {150.0, 20.0}}};
  for (const auto& [name, size] : expected) {
    SCOPED_TRACE(name);
    const std::optional<World> world = BuiltinWorld(name);
    ASSERT_TRUE(world) << "sim/worlds/" << name << ".json does not parse";
    EXPECT_EQ(world->name, name);
    EXPECT_TRUE(Validate(*world).empty());
    EXPECT_FALSE(world->floors.empty());
    // Mostly floor, not furniture: points of a 5 cm lattice with 10 cm of clearance cover at
    // least half the stated area.
    int free_points = 0;
    for (double x = world->bounds[0] + 0.025; x < world->bounds[2]; x += 0.05) {
      for (double y = world->bounds[1] + 0.025; y < world->bounds[3]; y += 0.05) {
        free_points += ClearanceAt(*world, {x, y}) > 0.1;
      }
    }
    EXPECT_GE(free_points * 0.05 * 0.05, size.first * 0.5);
    const double longest =
        std::max(world->bounds[2] - world->bounds[0], world->bounds[3] - world->bounds[1]);
    EXPECT_NEAR(longest, size.second, 1e-9);
    const double area =
        (world->bounds[2] - world->bounds[0]) * (world->bounds[3] - world->bounds[1]);
    EXPECT_GE(area, size.first);
  }
}

/// Component label of every segment: segments that touch (directly or through others) form one
/// obstacle (a room's walls, a box).
std::vector<size_t> SegmentComponents(const World& world) {
  std::vector<size_t> label(world.segments.size());
  for (size_t i = 0; i < label.size(); ++i) label[i] = i;
  bool changed = true;
  while (changed) {
    changed = false;
    for (size_t i = 0; i < label.size(); ++i) {
      for (size_t j = 0; j < label.size(); ++j) {
        if (label[j] < label[i] && SegmentDistance(world.segments[i], world.segments[j]) < 1e-6) {
          label[i] = label[j];
          changed = true;
        }
      }
    }
  }
  return label;
}

/// Whether a gap between two obstacles is fine: the robot (17 cm across) passes it with room
/// to spare, or cannot enter it at all; in the arenas every gap is passable.
bool GapIsFine(const std::string& world, double gap) {
  const bool arena = world == "box" || world == "rooms" || world == "cluttered";
  return gap >= 0.25 || (!arena && gap < 0.16);
}

TEST(ArenaTest, ObstaclesLeaveRoomForTheRobot) {
  // Any two distinct obstacles are at least 25 cm apart (the robot is 17 cm across); in the
  // real-size worlds, closer obstacles leave no gap the robot could squeeze into.
  for (const std::string& name : BuiltinWorldNames()) {
    SCOPED_TRACE(name);
    const World world = *BuiltinWorld(name);
    const std::vector<size_t> component = SegmentComponents(world);
    for (size_t i = 0; i < world.segments.size(); ++i) {
      for (size_t j = i + 1; j < world.segments.size(); ++j) {
        if (component[i] != component[j]) {
          const double gap = SegmentDistance(world.segments[i], world.segments[j]);
          EXPECT_TRUE(GapIsFine(name, gap)) << "segments " << i << " and " << j << ": " << gap;
        }
      }
      for (size_t k = 0; k < world.circles.size(); ++k) {
        const Circle& c = world.circles[k];
        World one;
        one.segments = {world.segments[i]};
        const double gap = ClearanceAt(one, c.center) - c.radius_m;
        EXPECT_TRUE(GapIsFine(name, gap)) << "segment " << i << ", circle " << k << ": " << gap;
      }
    }
    for (size_t i = 0; i < world.circles.size(); ++i) {
      for (size_t j = i + 1; j < world.circles.size(); ++j) {
        const Circle& a = world.circles[i];
        const Circle& b = world.circles[j];
        const double gap = (a.center - b.center).norm() - a.radius_m - b.radius_m;
        EXPECT_TRUE(GapIsFine(name, gap)) << "circles " << i << " and " << j << ": " << gap;
      }
    }
  }
}

TEST(ArenaTest, CornersAreWhereWallsMeet) {
  // A room with a box: 4 + 4 corners. Rooms: 4 room corners, 4 junctions of inner walls;
  // door jambs are free ends, not corners.
  EXPECT_EQ(Corners(*BuiltinWorld("box")).size(), 8u);
  const std::vector<Vec2> corners = Corners(*BuiltinWorld("rooms"));
  EXPECT_EQ(corners.size(), 8u);
  for (const Vec2& jamb : {Vec2(1.1, 0.3), Vec2(1.1, 0.8), Vec2(1.6, 1.1), Vec2(2.1, 1.1)}) {
    for (const Vec2& c : corners) EXPECT_GT((c - jamb).norm(), 0.01);
  }
  EXPECT_TRUE(Corners(OneWall()).empty());
}

// ---------------------------------------------------------------------------------------------
// world.json.

void ExpectSameWorld(const World& a, const World& b) {
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.bounds, b.bounds);
  ASSERT_EQ(a.segments.size(), b.segments.size());
  for (size_t i = 0; i < a.segments.size(); ++i) {
    EXPECT_EQ(a.segments[i].a, b.segments[i].a);
    EXPECT_EQ(a.segments[i].b, b.segments[i].b);
  }
  ASSERT_EQ(a.circles.size(), b.circles.size());
  for (size_t i = 0; i < a.circles.size(); ++i) {
    EXPECT_EQ(a.circles[i].center, b.circles[i].center);
    EXPECT_EQ(a.circles[i].radius_m, b.circles[i].radius_m);
  }
  ASSERT_EQ(a.floors.size(), b.floors.size());
  for (size_t i = 0; i < a.floors.size(); ++i) {
    EXPECT_EQ(a.floors[i].area, b.floors[i].area);
    EXPECT_EQ(a.floors[i].material, b.floors[i].material);
  }
}

TEST(WorldJsonTest, RoundTripsEveryBuiltinWorldExactly) {
  for (const std::string& name : BuiltinWorldNames()) {
    SCOPED_TRACE(name);
    const World world = *BuiltinWorld(name);
    const Result<World> parsed = ParseWorld(WorldToJson(world), "mem");
    ASSERT_TRUE(parsed.ok()) << parsed.errors().front().detail;
    ExpectSameWorld(world, parsed.value());
  }
}

TEST(WorldJsonTest, FloorsAreReadWithTheirMaterialsAndTheLastPatchWins) {
  const Result<World> world = ParseWorld(R"({"name": "w", "bounds": [0, 0, 4, 3],
      "floors": [{"area": [0, 0, 4, 3], "material": "carpet"},
                 {"area": [1, 1, 2, 2], "material": "rug"},
                 {"area": [3, 0, 4, 1], "material": "hard"}]})",
                                         "mem");
  ASSERT_TRUE(world.ok()) << world.Message();
  ASSERT_EQ(world.value().floors.size(), 3u);
  EXPECT_EQ(FloorAt(world.value(), {0.5, 0.5}), FloorMaterial::kCarpet);
  EXPECT_EQ(FloorAt(world.value(), {1.5, 1.5}), FloorMaterial::kRug);
  EXPECT_EQ(FloorAt(world.value(), {3.5, 0.5}), FloorMaterial::kHard);
  EXPECT_EQ(FloorAt(world.value(), {5.0, 5.0}), FloorMaterial::kHard);  // outside every patch
  EXPECT_EQ(FloorAt(World{}, {0.0, 0.0}), FloorMaterial::kHard);
  // Carpets and rugs make the encoders read long and the treels slip and skid more.
  EXPECT_EQ(TractionOf(FloorMaterial::kHard).scale_bias, 0.0);
  EXPECT_GT(TractionOf(FloorMaterial::kCarpet).scale_bias, 0.0);
  EXPECT_GT(TractionOf(FloorMaterial::kRug).slip_factor,
            TractionOf(FloorMaterial::kCarpet).slip_factor);
}

TEST(WorldJsonTest, BadFloorsAreErrorsNamingThePointer) {
  const Result<World> world = ParseWorld(R"({"name": "w", "bounds": [0, 0, 4, 3],
      "floors": [{"area": [0, 0, 4, 3], "material": "grass"},
                 {"area": [2, 0, 1, 1], "material": "rug"},
                 {"material": "rug"},
                 {"area": [0, 0, 1, 1], "material": "rug", "colour": "red"},
                 "carpet"]})",
                                         "mem");
  ASSERT_FALSE(world.ok());
  const std::string message = world.Message();
  EXPECT_NE(message.find("/floors/0/material: unknown material \"grass\""), std::string::npos)
      << message;
  EXPECT_NE(message.find("/floors/2/area: missing"), std::string::npos) << message;
  EXPECT_NE(message.find("/floors/3/colour: unknown key"), std::string::npos) << message;
  EXPECT_NE(message.find("/floors/4: expected an object"), std::string::npos) << message;
  const Result<World> reversed = ParseWorld(
      R"({"name": "w", "bounds": [0, 0, 4, 3], "floors": [{"area": [2, 0, 1, 1], "material": "rug"}]})",
      "mem");
  ASSERT_FALSE(reversed.ok());
  EXPECT_NE(reversed.Message().find("/floors/0/area: expected x0 < x1 and y0 < y1"),
            std::string::npos)
      << reversed.Message();
  const Result<World> not_a_list =
      ParseWorld(R"({"name": "w", "bounds": [0, 0, 4, 3], "floors": {}})", "mem");
  ASSERT_FALSE(not_a_list.ok());
  EXPECT_NE(not_a_list.Message().find("/floors: expected an array"), std::string::npos)
      << not_a_list.Message();
}

TEST(WorldJsonTest, SavesAndLoadsAFile) {
  World world = *BuiltinWorld("cluttered");
  world.name = "my \"arena\"";
  world.circles.push_back({{0.1 + 0.2, 1.0 / 3.0}, 0.0123456789012345});
  const std::string path = ::testing::TempDir() + "sim_test_world.json";
  ASSERT_TRUE(SaveWorld(path, world).ok());
  const Result<World> loaded = LoadWorld(path);
  ASSERT_TRUE(loaded.ok()) << loaded.errors().front().detail;
  ExpectSameWorld(world, loaded.value());
  const Result<World> resolved = ResolveWorld(path);
  ASSERT_TRUE(resolved.ok());
  EXPECT_EQ(resolved.value().name, world.name);
  ASSERT_TRUE(ResolveWorld("rooms").ok());
  EXPECT_EQ(ResolveWorld("rooms").value().name, "rooms");
  std::remove(path.c_str());
}

TEST(WorldJsonTest, ReadsTheDesignFormatWithOptionalLists) {
  const Result<World> r = ParseWorld(
      R"({"name": "tiny", "bounds": [0, 0, 1, 2], "segments": [[0, 0, 1, 0]]})", "tiny.json");
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r.value().name, "tiny");
  EXPECT_EQ(r.value().bounds, (std::array<double, 4>{0.0, 0.0, 1.0, 2.0}));
  ASSERT_EQ(r.value().segments.size(), 1u);
  EXPECT_EQ(r.value().segments[0].b, Vec2(1.0, 0.0));
  EXPECT_TRUE(r.value().circles.empty());
}

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

/// The errors of parsing `json`, joined by newlines.
std::string ErrorsOf(const std::string& json) {
  const Result<World> r = ParseWorld(json, "w.json");
  EXPECT_FALSE(r.ok()) << json;
  std::string text;
  for (const ConfigError& e : r.errors()) text += e.detail + "\n";
  return text;
}

TEST(WorldJsonTest, ErrorsNameTheSourceAndThePointer) {
  EXPECT_PRED2(Contains, ErrorsOf(R"({"name": "x", "bounds": [0, 0, 1, 1], )"),
               "w.json: invalid JSON");
  EXPECT_PRED2(Contains, ErrorsOf("[1, 2]"), "w.json: expected a JSON object");
  EXPECT_PRED2(Contains, ErrorsOf(R"({"name": "x", "bounds": [0, 0, 1, 1], "colour/x": 1})"),
               "w.json:1: /colour~1x: unknown key");
  EXPECT_PRED2(Contains, ErrorsOf(R"({"bounds": [0, 0, 1, 1]})"), "w.json:1: /name: missing");
  EXPECT_PRED2(Contains, ErrorsOf(R"({"name": 3, "bounds": [0, 0, 1, 1]})"),
               "w.json:1: /name: expected a string");
  EXPECT_PRED2(Contains, ErrorsOf(R"({"name": "x"})"), "w.json:1: /bounds: missing");
  EXPECT_PRED2(Contains, ErrorsOf(R"({"name": "x", "bounds": [0, 0, 1]})"),
               "w.json:1: /bounds: expected an array of 4 numbers");
  EXPECT_PRED2(Contains, ErrorsOf(R"({"name": "x", "bounds": [1, 0, 0, 1]})"),
               "w.json:1: /bounds: expected x0 < x1 and y0 < y1");
  EXPECT_PRED2(
      Contains,
      ErrorsOf(
          R"({"name": "x", "bounds": [0, 0, 1, 1], "segments": [[0, 0, 1, 1], [0, 0, "a", 1]]})"),
      "w.json:1: /segments/1/2: expected a number");
  EXPECT_PRED2(Contains,
               ErrorsOf(R"({"name": "x", "bounds": [0, 0, 1, 1], "segments": [[0, 0, 0, 0]]})"),
               "w.json:1: /segments/0: the two ends must differ");
  EXPECT_PRED2(Contains, ErrorsOf(R"({"name": "x", "bounds": [0, 0, 1, 1], "circles": {"a": 1}})"),
               "w.json:1: /circles: expected an array");
  EXPECT_PRED2(Contains,
               ErrorsOf(R"({"name": "x", "bounds": [0, 0, 1, 1], "circles": [[0.5, 0.5]]})"),
               "w.json:1: /circles/0: expected an array of 3 numbers");
  EXPECT_PRED2(Contains,
               ErrorsOf(R"({"name": "x", "bounds": [0, 0, 1, 1], "circles": [[0.5, 0.5, -1]]})"),
               "w.json:1: /circles/0/2: the radius must be positive");
}

TEST(WorldJsonTest, ImplausiblyLargeWorldsAreRefusedNamingTheKey) {
  // A world of 1e6 m used to be accepted; map quality then sampled its walls every centimetre.
  EXPECT_PRED2(Contains, ErrorsOf(R"({"name": "x", "bounds": [0, 0, 1e6, 1]})"),
               "w.json:1: /bounds/2: 1e+06 m is beyond the plausible +-1000 m of a world");
  EXPECT_PRED2(Contains,
               ErrorsOf(R"({"name": "x", "bounds": [0, 0, 1, 1], "segments": [[0, 0, 1, -2000]]})"),
               "w.json:1: /segments/0/3: -2000 m is beyond the plausible +-1000 m of a world");
  EXPECT_PRED2(Contains,
               ErrorsOf(R"({"name": "x", "bounds": [0, 0, 1, 1], "circles": [[0, 0, 5000]]})"),
               "w.json:1: /circles/0/2: 5000 m is beyond the plausible +-1000 m of a world");
  // Within the coordinates, but 12 walls of 1 km are more than any building.
  std::string walls;
  for (int i = 0; i < 12; ++i) {
    walls += std::string(i ? ", " : "") + "[-500, " + std::to_string(i) + ", 500, " +
             std::to_string(i) + "]";
  }
  EXPECT_PRED2(
      Contains,
      ErrorsOf(R"({"name": "x", "bounds": [-500, 0, 500, 12], "segments": [)" + walls + "]}"),
      "/segments: the walls and circles measure 12000 m in all, beyond the plausible "
      "10000 m");
  EXPECT_TRUE(ParseWorld(R"({"name": "x", "bounds": [-1000, -1000, 1000, 1000],)"
                         R"( "segments": [[-1000, 0, 1000, 0]]})",
                         "w")
                  .ok());
}

TEST(WorldJsonTest, ReportsEveryErrorAtOnce) {
  const Result<World> r =
      ParseWorld(R"({"extra": 1, "bounds": [0, 0, 1, 1], "segments": [[0, 0, 1], [1]]})", "w");
  EXPECT_FALSE(r.ok());
  EXPECT_EQ(r.errors().size(), 4u);  // /extra, /name, /segments/0, /segments/1
}

TEST(WorldJsonTest, FileErrorsNameTheLine) {
  // A saved arena has one obstacle per line: edit known lines and read the file back.
  const std::string path = ::testing::TempDir() + "sim_test_lines.world.json";
  const std::string text = WorldToJson(*BuiltinWorld("box"));
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  ASSERT_EQ(lines[1].rfind("  \"name\": ", 0), 0u) << text;
  ASSERT_EQ(lines[4].rfind("    [0.0, 0.0, 2.0, 0.0],", 0), 0u) << text;  // /segments/0
  lines.insert(lines.begin() + 2, "  \"colour\": \"red\",");              // line 3
  lines[5] = "    [0, 0, \"2\", 0],";  // /segments/0, now on line 6
  const auto load = [&] {
    std::ofstream out(path, std::ios::binary);
    for (const std::string& line : lines) out << line << "\n";
    out.close();
    return LoadWorld(path);
  };
  Result<World> r = load();
  ASSERT_EQ(r.errors().size(), 2u);
  EXPECT_EQ(r.errors()[0].detail, path + ":3: /colour: unknown key");
  EXPECT_EQ(r.errors()[1].detail, path + ":6: /segments/0/2: expected a number");
  EXPECT_PRED2(Contains, r.errors()[0].detail, "world.json:3: /colour");

  // Validation errors too; a missing key names the line of the object that lacks it.
  lines.erase(lines.begin() + 2);
  lines[4] = "    [0, 0, 0, 0],";
  lines[1] = "  \"nom\": \"box\",";
  r = load();
  ASSERT_EQ(r.errors().size(), 2u);
  EXPECT_EQ(r.errors()[0].detail, path + ":2: /nom: unknown key");
  EXPECT_EQ(r.errors()[1].detail, path + ":1: /name: missing");
  lines[1] = "  \"name\": \"box\",";
  r = load();
  ASSERT_EQ(r.errors().size(), 1u);
  EXPECT_EQ(r.errors()[0].detail, path + ":5: /segments/0: the two ends must differ");
  std::remove(path.c_str());
}

TEST(WorldJsonTest, MissingFileAndUnwritableDirectory) {
  const Result<World> r = LoadWorld("/nonexistent/dir/world.json");
  ASSERT_FALSE(r.ok());
  EXPECT_PRED2(Contains, r.errors().front().detail, "/nonexistent/dir/world.json: cannot open");
  EXPECT_FALSE(ResolveWorld("no-such-arena").ok());
  const Result<void> saved = SaveWorld("/nonexistent/dir/world.json", World{});
  ASSERT_FALSE(saved.ok());
  EXPECT_PRED2(Contains, saved.Message(), "/nonexistent/dir/world.json");
}

// ---------------------------------------------------------------------------------------------
// The simulated robot.

ScenarioConfig ShortRun(double duration_s, uint64_t seed) {
  ScenarioConfig config;
  config.duration_s = duration_s;
  config.seed = seed;
  return config;
}

TEST(ScenarioTest, ConfigValidation) {
  EXPECT_TRUE(ScenarioConfig{}.Validate().empty());
  ScenarioConfig bad;
  bad.duration_s = 0.0;
  bad.corner_hole_probability = 1.5;
  bad.odometry.gyro_noise_dps = -1.0;
  const std::vector<std::string> errors = bad.Validate();
  ASSERT_EQ(errors.size(), 3u);
  EXPECT_EQ(errors[0], "/duration_s: must be > 0");
}

TEST(ScenarioTest, EventRatesAndTimes) {
  const ScenarioOutput out = RunScenario(*BuiltinWorld("box"), TestRobot(), ShortRun(10.0, 3));
  ASSERT_EQ(out.odometry.size(), 501u);  // 50 Hz, t = 0 .. 10 s inclusive
  ASSERT_EQ(out.scanner.size(), 601u);   // 60 Hz
  ASSERT_EQ(out.ground_truth.size(), 301u);
  ASSERT_EQ(out.true_path.size(), out.scanner.size());
  EXPECT_DOUBLE_EQ(out.odometry[0].t, 0.0);
  EXPECT_DOUBLE_EQ(out.odometry[10].t, 0.2);
  EXPECT_DOUBLE_EQ(out.scanner[60].t, 1.0);
  EXPECT_DOUBLE_EQ(out.ground_truth.back().t, 10.0);
  for (size_t i = 0; i < out.scanner.size(); ++i) {
    EXPECT_EQ(out.scanner[i].seq, static_cast<uint16_t>(i));
  }
  // Platform at 1.5 half turns per second: 4.5 degrees = 819.2 raw units per sample.
  EXPECT_EQ(out.scanner[0].angle_raw, 0);
  EXPECT_EQ(out.scanner[1].angle_raw, 819);
  EXPECT_EQ(out.scanner[40].angle_raw, 32768);
  EXPECT_EQ(out.scanner[80].angle_raw, 0);
}

TEST(ScenarioTest, SameSeedSameOutputOtherSeedOtherOutput) {
  const World world = *BuiltinWorld("cluttered");
  const ScenarioOutput a = RunScenario(world, TestRobot(), ShortRun(20.0, 7));
  const ScenarioOutput b = RunScenario(world, TestRobot(), ShortRun(20.0, 7));
  const ScenarioOutput c = RunScenario(world, TestRobot(), ShortRun(20.0, 8));
  ASSERT_EQ(a.odometry.size(), b.odometry.size());
  ASSERT_EQ(a.scanner.size(), b.scanner.size());
  ASSERT_EQ(a.ground_truth.size(), b.ground_truth.size());
  for (size_t i = 0; i < a.odometry.size(); ++i) {
    EXPECT_EQ(a.odometry[i].left_ticks, b.odometry[i].left_ticks);
    EXPECT_EQ(a.odometry[i].right_ticks, b.odometry[i].right_ticks);
    EXPECT_EQ(a.odometry[i].gyro_raw, b.odometry[i].gyro_raw);
  }
  for (size_t i = 0; i < a.scanner.size(); ++i) {
    EXPECT_EQ(a.scanner[i].raw, b.scanner[i].raw);
    EXPECT_EQ(a.scanner[i].angle_raw, b.scanner[i].angle_raw);
  }
  for (size_t i = 0; i < a.ground_truth.size(); ++i) {
    EXPECT_EQ(a.ground_truth[i].pose.x, b.ground_truth[i].pose.x);
    EXPECT_EQ(a.ground_truth[i].pose.theta, b.ground_truth[i].pose.theta);
  }
  int differing = 0;
  for (size_t i = 0; i < a.scanner.size(); ++i) differing += a.scanner[i].raw != c.scanner[i].raw;
  EXPECT_GT(differing, static_cast<int>(a.scanner.size()) / 2);
  EXPECT_NE(a.ground_truth.back().pose.x, c.ground_truth.back().pose.x);
}

TEST(ScenarioTest, RobotKeepsClearOfObstaclesAndMovesAround) {
  for (const std::string& name : BuiltinWorldNames()) {
    for (const uint64_t seed : {1u, 2u}) {
      SCOPED_TRACE(name + " seed " + std::to_string(seed));
      const World world = *BuiltinWorld(name);
      const ScenarioConfig config = ShortRun(120.0, seed);
      const ScenarioOutput out = RunScenario(world, TestRobot(), config);
      double min_clearance = 1e9, path_length = 0.0;
      std::set<std::pair<int, int>> cells;  // 20 cm cells visited
      for (size_t i = 0; i < out.true_path.size(); ++i) {
        const Pose2& p = out.true_path[i].pose;
        min_clearance = std::min(min_clearance, ClearanceAt(world, p.translation()));
        EXPECT_GE(p.x, world.bounds[0]);
        EXPECT_LE(p.x, world.bounds[2]);
        EXPECT_GE(p.y, world.bounds[1]);
        EXPECT_LE(p.y, world.bounds[3]);
        if (i > 0)
          path_length += (p.translation() - out.true_path[i - 1].pose.translation()).norm();
        cells.insert(
            {static_cast<int>(std::floor(p.x / 0.2)), static_cast<int>(std::floor(p.y / 0.2))});
      }
      EXPECT_GE(min_clearance, 0.085);
      EXPECT_GE(path_length, 0.4 * config.speed_m_s * config.duration_s);
      EXPECT_LE(path_length, config.speed_m_s * config.duration_s + 1e-6);
      EXPECT_GE(cells.size(), 20u);
    }
  }
}

/// Pose of a time-ordered trajectory at exactly one of its times.
Pose2 At(const std::vector<TimedPose>& path, double t) {
  for (const TimedPose& p : path) {
    if (std::abs(p.t - t) < 1e-9) return p.pose;
  }
  ADD_FAILURE() << "no pose at " << t;
  return {};
}

TEST(ScenarioTest, NoiseFreeOdometryIntegratesToTheTruePath) {
  ScenarioConfig config = ShortRun(30.0, 4);
  config.odometry.translation_slip_ratio = 0.0;
  config.odometry.rotation_slip_ratio = 0.0;
  config.odometry.gyro_noise_dps = 0.0;
  config.odometry.accel_slip_s = 0.0;
  config.odometry.gyro_bias_dps = 0.0;
  const RobotDescription robot = TestRobot();
  const ScenarioOutput out = RunScenario(*BuiltinWorld("rooms"), robot, config);
  const std::vector<TimedPose> odom = DeadReckoning(robot, out.odometry);
  const Pose2 start = out.true_path.front().pose;
  double worst = 0.0;
  for (const TimedPose& truth : out.true_path) {
    if (std::fmod(truth.t * 10.0, 1.0) > 1e-6) continue;  // every 0.1 s, on an odometry reading
    const Pose2 estimate = Compose(start, At(odom, truth.t));
    worst = std::max(worst, (estimate.translation() - truth.pose.translation()).norm());
    // The gyro reports its mean rate over each 20 ms period and the integrator's trapezoidal
    // rule lags by half a period at the current rate, without accumulating.
    double rate = 0.0;
    for (const OdometryReading& r : out.odometry) {
      if (std::abs(r.t - truth.t) < 1e-9) rate = DegToRad(r.gyro_raw * robot.base.gyro_unit_dps);
    }
    EXPECT_NEAR(NormalizeAngle(estimate.theta - truth.pose.theta), 0.0,
                0.5 * 0.02 * std::abs(rate) + 0.002);
  }
  EXPECT_LT(worst, 0.005);  // tick quantisation and gyro units only
}

TEST(ScenarioTest, NoisyOdometryDriftsWithinSlipBounds) {
  const RobotDescription robot = TestRobot();
  double largest_error = 0.0;
  for (const uint64_t seed : {1u, 2u, 3u, 4u, 5u}) {
    SCOPED_TRACE(seed);
    const ScenarioOutput out = RunScenario(*BuiltinWorld("box"), robot, ShortRun(20.0, seed));
    const std::vector<TimedPose> odom = DeadReckoning(robot, out.odometry);
    const Pose2 start = out.true_path.front().pose;
    double travelled = 0.0;
    for (size_t i = 1; i < out.true_path.size(); ++i) {
      const TimedPose& truth = out.true_path[i];
      travelled += (truth.pose.translation() - out.true_path[i - 1].pose.translation()).norm();
      if (std::fmod(truth.t * 10.0, 1.0) > 1e-6) continue;
      const Pose2 estimate = Compose(start, At(odom, truth.t));
      const double error = (estimate.translation() - truth.pose.translation()).norm();
      largest_error = std::max(largest_error, error);
      // Slip of a few percent of the distance plus the heading error of the gyro's bias.
      EXPECT_LE(error, 0.12 * travelled + 0.03) << "t = " << truth.t;
      EXPECT_LE(std::abs(NormalizeAngle(estimate.theta - truth.pose.theta)), DegToRad(6.0));
    }
  }
  EXPECT_GT(largest_error, 0.005);  // the noise is really there
}

/// Final and largest position error of dead reckoning against the true path (from the true
/// start), sampled every second.
std::pair<double, double> DeadReckoningError(const RobotDescription& robot,
                                             const ScenarioOutput& out) {
  const std::vector<TimedPose> odom = DeadReckoning(robot, out.odometry);
  const Pose2 start = out.true_path.front().pose;
  double last = 0.0, largest = 0.0;
  for (const TimedPose& truth : out.true_path) {
    if (std::fmod(truth.t, 1.0) > 1e-6) continue;
    last = (Compose(start, At(odom, truth.t)).translation() - truth.pose.translation()).norm();
    largest = std::max(largest, last);
  }
  return {last, largest};
}

TEST(ScenarioTest, TrackedOdometryDriftsDecimetresToMetresWhereGentleDriftsCentimetres) {
  // 300 s in the flat, four seeds: the tracked profile's dead reckoning ends tens of centimetres
  // to metres off (a tracked robot with a MEMS gyro), the gentle one centimetres.
  const RobotDescription robot = TestRobot();
  const World flat = *BuiltinWorld("flat");
  double gentle_sum = 0.0, tracked_sum = 0.0, tracked_min = 1e9;
  for (const uint64_t seed : {1u, 2u, 3u, 4u}) {
    SCOPED_TRACE(seed);
    const ScenarioConfig base = ShortRun(300.0, seed);
    const auto gentle = DeadReckoningError(
        robot, RunScenario(flat, robot, WithOdometryProfile(base, OdometryProfile::kGentle)));
    const auto tracked = DeadReckoningError(
        robot, RunScenario(flat, robot, WithOdometryProfile(base, OdometryProfile::kTracked)));
    gentle_sum += gentle.second;
    tracked_sum += tracked.second;
    tracked_min = std::min(tracked_min, tracked.second);
  }
  SCOPED_TRACE("largest error, mean of 4 runs: gentle " + std::to_string(gentle_sum / 4.0) +
               " m, tracked " + std::to_string(tracked_sum / 4.0) + " m (least " +
               std::to_string(tracked_min) + " m)");
  EXPECT_GE(tracked_sum / 4.0, 0.5);
  EXPECT_LE(tracked_sum / 4.0, 4.0);
  EXPECT_GE(tracked_min, 0.2);
  EXPECT_GE(tracked_sum, 2.0 * gentle_sum);
}

TEST(ScenarioTest, ProfilesSetOnlyTheOdometryErrorsAndGentleIsTheDefault) {
  ScenarioConfig config;
  config.seed = 77;
  config.speed_m_s = 0.2;
  config.sensor_noise_scale = 2.0;
  const ScenarioConfig gentle = WithOdometryProfile(config, OdometryProfile::kGentle);
  const ScenarioConfig tracked = WithOdometryProfile(config, OdometryProfile::kTracked);
  for (const ScenarioConfig& c : {gentle, tracked}) {
    EXPECT_EQ(c.seed, 77u);
    EXPECT_EQ(c.speed_m_s, 0.2);
    EXPECT_EQ(c.sensor_noise_scale, 2.0);
    EXPECT_TRUE(c.Validate().empty());
  }
  const ScenarioConfig defaults;
  EXPECT_EQ(gentle.odometry.gyro_bias_dps, defaults.odometry.gyro_bias_dps);
  EXPECT_EQ(gentle.odometry.skid_s, 0.0);
  EXPECT_EQ(gentle.odometry.profile, "gentle");
  EXPECT_GT(tracked.odometry.skid_s, 0.0);
  EXPECT_GT(tracked.odometry.gyro_bias_dps, defaults.odometry.gyro_bias_dps);
  EXPECT_EQ(tracked.odometry.profile, "tracked");
  EXPECT_EQ(OdometryProfileFromName("tracked"), OdometryProfile::kTracked);
  EXPECT_FALSE(OdometryProfileFromName("bumpy").has_value());
  // The same seed and profile give the same readings.
  const ScenarioOutput a =
      RunScenario(*BuiltinWorld("studio"), TestRobot(),
                  WithOdometryProfile(ShortRun(20.0, 5), OdometryProfile::kTracked));
  const ScenarioOutput b =
      RunScenario(*BuiltinWorld("studio"), TestRobot(),
                  WithOdometryProfile(ShortRun(20.0, 5), OdometryProfile::kTracked));
  ASSERT_EQ(a.odometry.size(), b.odometry.size());
  for (size_t i = 0; i < a.odometry.size(); ++i) {
    EXPECT_EQ(a.odometry[i].left_ticks, b.odometry[i].left_ticks);
    EXPECT_EQ(a.odometry[i].gyro_raw, b.odometry[i].gyro_raw);
  }
  EXPECT_EQ(a.true_path.back().pose.x, b.true_path.back().pose.x);
}

TEST(ScenarioTest, UnequalWheelsTurnAnEncoderHeadingPerMetreAndLeaveAGyroRobotAlone) {
  // Noise-free but for the wheels: a robot that turns by its encoders sees its heading err in
  // proportion to the distance it drove (each run draws its own difference of the wheels); the
  // same runs of a robot with a gyro read exactly as they did before the wheels were modelled.
  RobotDescription encoders = TestRobot();
  encoders.base.heading_from_gyro = false;
  const RobotDescription gyro = TestRobot();
  const World box = *BuiltinWorld("box");
  double sum_sq = 0.0;
  std::vector<double> slopes;
  for (const uint64_t seed : {1u, 2u, 3u, 4u, 5u, 6u, 7u, 8u}) {
    SCOPED_TRACE(seed);
    ScenarioConfig config = ShortRun(40.0, seed);
    config.odometry.translation_slip_ratio = 0.0;
    config.odometry.rotation_slip_ratio = 0.0;
    config.odometry.accel_slip_s = 0.0;
    ScenarioConfig plain = config;
    config.odometry.wheel_diameter_sigma = 0.02;
    const ScenarioOutput out = RunScenario(box, encoders, config);
    const std::vector<TimedPose> odom = DeadReckoning(encoders, out.odometry);
    double travelled = 0.0, last_error = 0.0;
    std::vector<std::pair<double, double>> samples;  // distance, heading error (unwrapped)
    for (size_t i = 1; i < out.true_path.size(); ++i) {
      const TimedPose& truth = out.true_path[i];
      travelled += (truth.pose.translation() - out.true_path[i - 1].pose.translation()).norm();
      if (std::fmod(truth.t * 10.0, 1.0) > 1e-6) continue;
      const double error =
          Compose(out.true_path.front().pose, At(odom, truth.t)).theta - truth.pose.theta;
      last_error += NormalizeAngle(error - last_error);
      samples.emplace_back(travelled, last_error);
    }
    ASSERT_GT(travelled, 2.0);
    const double slope = last_error / travelled;  // rad per metre
    for (const auto& [d, e] : samples) EXPECT_NEAR(e, slope * d, DegToRad(0.3)) << d << " m";
    slopes.push_back(slope);
    sum_sq += slope * slope;

    // The gyro's robot: the same readings with and without the wheels' difference.
    const ScenarioOutput a = RunScenario(box, gyro, config);
    const ScenarioOutput b = RunScenario(box, gyro, plain);
    ASSERT_EQ(a.odometry.size(), b.odometry.size());
    for (size_t i = 0; i < a.odometry.size(); ++i) {
      ASSERT_EQ(a.odometry[i].left_ticks, b.odometry[i].left_ticks);
      ASSERT_EQ(a.odometry[i].right_ticks, b.odometry[i].right_ticks);
    }
  }
  // A 2 % difference over the marXbot's 15 cm track: 0.13 rad (7.6 degrees) per metre, in
  // either direction, a new draw each run.
  const double rms = std::sqrt(sum_sq / static_cast<double>(slopes.size()));
  const double expected = 0.02 / TestRobot().base.track_width_m;
  EXPECT_GT(rms, 0.4 * expected);
  EXPECT_LT(rms, 2.0 * expected);
  EXPECT_LT(*std::min_element(slopes.begin(), slopes.end()), 0.0);
  EXPECT_GT(*std::max_element(slopes.begin(), slopes.end()), 0.0);
}

TEST(ScenarioTest, ACarpetMakesTheEncodersReadLong) {
  // Noise-free but for the floor: on carpet the encoders report 2.5 % more than the true path.
  ScenarioConfig config = ShortRun(60.0, 6);
  config.odometry.translation_slip_ratio = 0.0;
  config.odometry.rotation_slip_ratio = 0.0;
  config.odometry.accel_slip_s = 0.0;
  World hard = *BuiltinWorld("box");
  World carpet = hard;
  carpet.floors.push_back({hard.bounds, FloorMaterial::kCarpet});
  const RobotDescription robot = TestRobot();
  for (const auto& [world, expected] :
       {std::pair{hard, 1.0},
        std::pair{carpet, 1.0 + TractionOf(FloorMaterial::kCarpet).scale_bias}}) {
    const ScenarioOutput out = RunScenario(world, robot, config);
    double truth = 0.0;
    for (size_t i = 1; i < out.true_path.size(); ++i) {
      truth +=
          (out.true_path[i].pose.translation() - out.true_path[i - 1].pose.translation()).norm();
    }
    const OdometryReading& first = out.odometry.front();
    const OdometryReading& last = out.odometry.back();
    // The robot drives forwards only, so the treels' mean travel is the path length.
    const double ticks =
        (static_cast<double>(static_cast<int32_t>(last.left_ticks - first.left_ticks)) +
         static_cast<double>(static_cast<int32_t>(last.right_ticks - first.right_ticks))) /
        2.0;
    const double encoders = ticks / robot.base.ticks_per_m;
    EXPECT_NEAR(encoders / truth, expected, 0.004) << "floors: " << world.floors.size();
  }
}

TEST(ScenarioTest, PeopleWalkingAboutBlockALasersBeamsAndLeaveTheRobotAlone) {
  // A Pioneer-like robot with a laser in the flat for two minutes, with three people walking
  // about and without: the same motion and odometry, and beams that read shorter where a leg
  // crosses them, never longer.
  const auto pioneer =
      io::LoadRobot(std::string(SLAM_SOURCE_DIR) + "/config/pioneer-lms.robot.json");
  ASSERT_TRUE(pioneer.ok()) << pioneer.Message();
  ScenarioConfig config = ShortRun(120.0, 4);
  config.speed_m_s = 0.4;
  config.turn_rate_rad_s = 0.5;
  config.scans_per_s = 1.0;
  const World flat = *BuiltinWorld("flat");
  const ScenarioOutput empty = RunScenario(flat, pioneer.value(), config);
  config.people = 3;
  const ScenarioOutput busy = RunScenario(flat, pioneer.value(), config);
  ASSERT_EQ(busy.odometry.size(), empty.odometry.size());
  ASSERT_EQ(busy.true_path.size(), empty.true_path.size());
  ASSERT_EQ(busy.sweeps.size(), empty.sweeps.size());
  for (size_t i = 0; i < busy.odometry.size(); ++i) {
    ASSERT_EQ(busy.odometry[i].left_ticks, empty.odometry[i].left_ticks) << i;
    ASSERT_EQ(busy.odometry[i].right_ticks, empty.odometry[i].right_ticks) << i;
  }
  for (size_t i = 0; i < busy.true_path.size(); ++i) {
    ASSERT_EQ(busy.true_path[i].pose.x, empty.true_path[i].pose.x) << i;
  }
  int beams = 0, shorter = 0, longer = 0, sweeps_seeing_people = 0;
  for (size_t s = 0; s < busy.sweeps.size(); ++s) {
    bool seen = false;
    for (size_t b = 0; b < busy.sweeps[s].ranges.size(); ++b) {
      const double with = busy.sweeps[s].ranges[b], without = empty.sweeps[s].ranges[b];
      ++beams;
      shorter += with < without - 0.05;
      longer += with > without + 0.05;
      seen = seen || with < without - 0.05;
    }
    sweeps_seeing_people += seen;
  }
  EXPECT_EQ(longer, 0);
  EXPECT_GT(shorter, beams / 1000);  // seen: legs a few beams wide each
  EXPECT_LT(shorter, beams / 20);    // but a few legs, not walls
  EXPECT_GT(sweeps_seeing_people, static_cast<int>(busy.sweeps.size()) / 10);
  // Their number is checked.
  ScenarioConfig crowd;
  crowd.people = 51;
  EXPECT_EQ(crowd.Validate(), std::vector<std::string>{"/people: must be in [0, 50]"});
  crowd.people = -1;
  EXPECT_EQ(crowd.Validate(), std::vector<std::string>{"/people: must be in [0, 50]"});
}

TEST(DatasetTest, SetsAreDisjointAndHoldTheirWorlds) {
  std::map<std::pair<std::string, uint64_t>, std::string> owner;
  for (const DatasetKind kind : {DatasetKind::kArenas, DatasetKind::kTraining,
                                 DatasetKind::kValidation, DatasetKind::kReference}) {
    const DatasetPlan plan = PlanDataset(kind);
    std::set<std::string> worlds;
    for (const DatasetRun& run : plan.runs) {
      EXPECT_TRUE(BuiltinWorld(run.world).has_value()) << run.world;
      const auto [it, fresh] =
          owner.emplace(std::pair{run.world, run.seed}, std::string(DatasetKindName(kind)));
      EXPECT_TRUE(fresh) << run.world << " seed " << run.seed << " is in " << it->second << " and "
                         << DatasetKindName(kind);
      worlds.insert(run.world);
    }
    EXPECT_EQ(plan.duration_s, 300.0);
    EXPECT_EQ(DatasetKindFromName(DatasetKindName(kind)), kind);
    if (kind == DatasetKind::kArenas) {
      EXPECT_EQ(plan.odometry, OdometryProfile::kGentle);
      EXPECT_EQ(plan.runs.size(), 15u);
    } else {
      EXPECT_EQ(plan.odometry, OdometryProfile::kTracked);
      EXPECT_TRUE(worlds.count("flat") && worlds.count("corridor") && worlds.count("office"));
    }
    // The studio is never trained on; the lab is only reported on.
    EXPECT_EQ(worlds.count("studio"),
              kind == DatasetKind::kValidation || kind == DatasetKind::kReference ? 1u : 0u);
    EXPECT_EQ(worlds.count("lab"), kind == DatasetKind::kReference ? 1u : 0u);
    // The building is for the laser family's tuning (scripts/tune-laser), not the infrared sets.
    EXPECT_EQ(worlds.count("building"), 0u);
  }
  // More runs per world extend the same seed series.
  const DatasetPlan more = PlanDataset(DatasetKind::kTraining, 3);
  EXPECT_EQ(more.runs.size(), 18u);
  EXPECT_EQ(more.runs[2].seed, more.runs[0].seed + 2);
}

TEST(ScenarioTest, NoiseFreeReadingsMatchTheGeometry) {
  // Oracle: recast every beam from the true pose and check the raw value against the table.
  ScenarioConfig config = ShortRun(30.0, 5);
  config.sensor_noise_scale = 0.0;
  config.corner_hole_probability = 1.0;  // every beam near a corner reads as a hole
  config.floor_noise_raw = 0.0;
  const RobotDescription robot = TestRobot();
  const World world = *BuiltinWorld("cluttered");
  const std::vector<Vec2> corners = Corners(world);
  const ScenarioOutput out = RunScenario(world, robot, config);
  int in_range = 0, holes = 0, floors = 0, near = 0;
  for (size_t i = 0; i < out.scanner.size(); ++i) {
    const Pose2& p = out.true_path[i].pose;
    const double platform = kPi * config.scans_per_s * out.scanner[i].t;
    for (size_t s = 0; s < kScannerSensors; ++s) {
      const SensorTypeDescription& type = robot.sensor_types.at(robot.scanner.sensors[s].type);
      const double angle = p.theta + platform + DegToRad(robot.scanner.sensors[s].angle_deg);
      const Vec2 origin = p.translation() + 0.05 * Vec2(std::cos(angle), std::sin(angle));
      const std::optional<double> d = RayDistance(world, origin, angle, 10.0);
      const int raw = out.scanner[i].raw[s];
      const int floor_raw = type.calibration.back().raw - 15;
      if (!d || *d > type.calibration.back().distance_m) {
        EXPECT_EQ(raw, floor_raw);
        ++floors;
        continue;
      }
      const Vec2 hit = origin + *d * Vec2(std::cos(angle), std::sin(angle));
      bool at_corner = false;
      for (const Vec2& c : corners) at_corner = at_corner || (c - hit).norm() <= 0.03;
      if (at_corner) {
        EXPECT_EQ(raw, floor_raw);
        ++holes;
      } else if (*d < type.calibration.front().distance_m) {
        // Non-injective zone: reads like something further away (or nothing).
        const std::optional<double> reads = CalibratedDistance(type.calibration, raw);
        EXPECT_TRUE(!reads || *reads > *d);
        ++near;
      } else {
        const std::optional<double> reads = CalibratedDistance(type.calibration, raw);
        ASSERT_TRUE(reads);
        EXPECT_NEAR(*reads, *d, 0.015 * *d + 0.002);
        ++in_range;
      }
    }
  }
  EXPECT_GT(in_range, 1000);
  EXPECT_GT(holes, 0);
  EXPECT_GT(floors, 100);
  EXPECT_GT(near, 0);
}

TEST(ScenarioTest, SensorNoiseFollowsTheRobotsSigma) {
  // The long sensors' readings scatter around the truth with about the robot's sigma.
  ScenarioConfig config = ShortRun(60.0, 6);
  config.corner_hole_probability = 0.0;
  const RobotDescription robot = TestRobot();
  const World world = *BuiltinWorld("box");
  const ScenarioOutput out = RunScenario(world, robot, config);
  double sum_z2 = 0.0;
  int n = 0;
  for (size_t i = 0; i < out.scanner.size(); ++i) {
    const Pose2& p = out.true_path[i].pose;
    const double platform = kPi * config.scans_per_s * out.scanner[i].t;
    for (const size_t s : {size_t{1}, size_t{3}}) {
      const SensorTypeDescription& type = robot.sensor_types.at("long");
      const double angle = p.theta + platform + DegToRad(robot.scanner.sensors[s].angle_deg);
      const Vec2 origin = p.translation() + 0.05 * Vec2(std::cos(angle), std::sin(angle));
      const std::optional<double> d = RayDistance(world, origin, angle, 10.0);
      if (!d || *d < 0.3 || *d > 0.9) continue;
      const std::optional<double> reads =
          CalibratedDistance(type.calibration, out.scanner[i].raw[s]);
      ASSERT_TRUE(reads);
      const double sigma = type.sigma_m[0] + type.sigma_m[2] * *d * *d;
      sum_z2 += (*reads - *d) * (*reads - *d) / (sigma * sigma);
      ++n;
    }
  }
  ASSERT_GT(n, 500);
  const double rms_z = std::sqrt(sum_z2 / n);
  EXPECT_GT(rms_z, 0.8);  // the ADC's quantisation adds a little
  EXPECT_LT(rms_z, 1.5);
}

TEST(ScenarioTest, GroundTruthIsTheTruePathWithTrackerNoise) {
  const ScenarioOutput out = RunScenario(*BuiltinWorld("box"), TestRobot(), ShortRun(10.0, 9));
  double sum2 = 0.0;
  int n = 0;
  for (const TimedPose& g : out.ground_truth) {
    for (const TimedPose& p : out.true_path) {
      if (std::abs(p.t - g.t) < 1e-9) {
        sum2 += (g.pose.translation() - p.pose.translation()).squaredNorm();
        ++n;
      }
    }
  }
  ASSERT_GT(n, 100);
  const double rms = std::sqrt(sum2 / (2 * n));  // per axis
  EXPECT_GT(rms, 0.0005);
  EXPECT_LT(rms, 0.002);
}

// ---------------------------------------------------------------------------------------------
// Kidnapping: the robot lifted and set down elsewhere, which the odometry does not see.

constexpr double kKidnapT = 25.0;

ScenarioConfig KidnapRun(uint64_t seed) {
  ScenarioConfig config = ShortRun(40.0, seed);
  config.kidnap_t_s = kKidnapT;
  return config;
}

/// Encoder counts from one reading to the next, wrapping as the counters do.
int64_t TickDelta(int32_t now, int32_t before) {
  return static_cast<int32_t>(static_cast<uint32_t>(now) - static_cast<uint32_t>(before));
}

/// How much the odometry's rates change from one reading to the next, at most, over the readings
/// i with from_t <= t_i < to_t: the encoders' counts per reading (either wheel) and the gyro's.
struct RateChanges {
  int64_t ticks = 0;
  int64_t gyro = 0;
};
RateChanges LargestRateChanges(const std::vector<OdometryReading>& odometry, double from_t,
                               double to_t) {
  RateChanges largest;
  for (size_t i = 2; i < odometry.size(); ++i) {
    if (odometry[i].t < from_t - 1e-9 || odometry[i].t >= to_t - 1e-9) continue;
    const auto change = [&](auto ticks) {
      return std::abs(TickDelta(ticks(odometry[i]), ticks(odometry[i - 1])) -
                      TickDelta(ticks(odometry[i - 1]), ticks(odometry[i - 2])));
    };
    largest.ticks =
        std::max({largest.ticks, change([](const OdometryReading& r) { return r.left_ticks; }),
                  change([](const OdometryReading& r) { return r.right_ticks; })});
    largest.gyro =
        std::max(largest.gyro, std::abs(int64_t{odometry[i].gyro_raw} - odometry[i - 1].gyro_raw));
  }
  return largest;
}

// What the wanderer's acceleration limits (0.6 m/s^2, 8 rad/s^2 over the 7.5 cm half track)
// let the rates change in one 20 ms reading, the encoders running ahead by 20 ms times the
// acceleration (accel_slip_s), with 11375 ticks/m: 2 x (0.6 + 0.6) x 0.02 x 0.02 x 11375 = 11
// ticks, plus slip and rounding; the gyro 0.16 rad/s (917 units of 0.01 deg/s) plus its noise.
// A robot set down facing a wall turns away at once, as it does whenever it comes upon one.
constexpr int64_t kTurnStartTicks = 14;
constexpr int64_t kTurnStartGyro = 1100;

/// The pose of `path` before `before_t` farthest from `from`: a place the robot stood on.
Pose2 FarthestBefore(const std::vector<TimedPose>& path, const Pose2& from, double before_t) {
  Pose2 farthest = from;
  for (const TimedPose& p : path) {
    if (p.t < before_t && (p.pose.translation() - from.translation()).norm() >
                              (farthest.translation() - from.translation()).norm()) {
      farthest = p.pose;
    }
  }
  return farthest;
}

/// Checks a run kidnapped at kKidnapT to `to` against the same seed's run without: bit for bit
/// the same before, the ground truth jumping to `to` at kKidnapT, the odometry not seeing it,
/// the robot clear of obstacles after.
void ExpectKidnapped(const World& world, const ScenarioOutput& plain,
                     const ScenarioOutput& kidnapped, const Pose2& to) {
  ASSERT_EQ(kidnapped.kidnaps.size(), 1u);
  const Kidnapping& k = kidnapped.kidnaps.front();
  EXPECT_NEAR(k.t, kKidnapT, 1e-9);
  const Pose2 from = At(plain.true_path, kKidnapT);
  EXPECT_NEAR(k.from.x, from.x, 1e-12);
  EXPECT_NEAR(k.from.y, from.y, 1e-12);
  EXPECT_NEAR(NormalizeAngle(k.from.theta - from.theta), 0.0, 1e-12);
  EXPECT_NEAR(k.to.x, to.x, 1e-12);
  EXPECT_NEAR(k.to.y, to.y, 1e-12);
  EXPECT_NEAR(NormalizeAngle(k.to.theta - to.theta), 0.0, 1e-12);

  // Before kKidnapT: every reading and pose bit for bit the same.
  const auto before = [](const auto& r) { return r.t < kKidnapT - 1e-9; };
  ASSERT_EQ(kidnapped.odometry.size(), plain.odometry.size());
  ASSERT_EQ(kidnapped.scanner.size(), plain.scanner.size());
  ASSERT_EQ(kidnapped.ground_truth.size(), plain.ground_truth.size());
  ASSERT_EQ(kidnapped.true_path.size(), plain.true_path.size());
  size_t first_after = 0;  // the first odometry reading at or after kKidnapT
  for (size_t i = 0; i < plain.odometry.size() && before(plain.odometry[i]); ++i) {
    ASSERT_EQ(kidnapped.odometry[i], plain.odometry[i]) << i;
    first_after = i + 1;
  }
  for (size_t i = 0; i < plain.scanner.size() && before(plain.scanner[i]); ++i) {
    ASSERT_EQ(kidnapped.scanner[i], plain.scanner[i]) << i;
  }
  for (const auto* paths : {&plain.ground_truth, &plain.true_path}) {
    const auto& other = paths == &plain.ground_truth ? kidnapped.ground_truth : kidnapped.true_path;
    for (size_t i = 0; i < paths->size() && before((*paths)[i]); ++i) {
      ASSERT_EQ(other[i].t, (*paths)[i].t);
      ASSERT_EQ(other[i].pose.x, (*paths)[i].pose.x) << i;
      ASSERT_EQ(other[i].pose.y, (*paths)[i].pose.y) << i;
      ASSERT_EQ(other[i].pose.theta, (*paths)[i].pose.theta) << i;
    }
  }

  // The odometry does not see it: the reading at kKidnapT counts as without, and the rates
  // change across it no more than they did before or than the wanderer's turning away from an
  // obstacle makes them; dead reckoning moves as little there as a robot at cruising speed does
  // in 20 ms.
  const OdometryReading& at = kidnapped.odometry[first_after];
  ASSERT_NEAR(at.t, kKidnapT, 1e-9);
  EXPECT_EQ(at.left_ticks, plain.odometry[first_after].left_ticks);
  EXPECT_EQ(at.right_ticks, plain.odometry[first_after].right_ticks);
  EXPECT_NEAR(at.gyro_raw, plain.odometry[first_after].gyro_raw, 1);
  const RateChanges across = LargestRateChanges(kidnapped.odometry, kKidnapT - 0.1, kKidnapT + 0.1);
  const RateChanges earlier = LargestRateChanges(kidnapped.odometry, 0.0, kKidnapT);
  EXPECT_LE(across.ticks, std::max(earlier.ticks, kTurnStartTicks));
  EXPECT_LE(across.gyro, std::max(earlier.gyro, kTurnStartGyro));
  const std::vector<TimedPose> odom = DeadReckoning(TestRobot(), kidnapped.odometry);
  for (size_t i = first_after - 5; i < first_after + 5; ++i) {
    EXPECT_LT((odom[i + 1].pose.translation() - odom[i].pose.translation()).norm(), 0.01) << i;
    EXPECT_LT(std::abs(NormalizeAngle(odom[i + 1].pose.theta - odom[i].pose.theta)), 0.1) << i;
  }

  // The ground truth does: at kKidnapT the tracker sees the robot at `to` (within its noise),
  // the true path is there exactly.
  const Pose2 true_at = At(kidnapped.true_path, kKidnapT);
  EXPECT_NEAR((true_at.translation() - to.translation()).norm(), 0.0, 1e-9);
  EXPECT_NEAR(NormalizeAngle(true_at.theta - to.theta), 0.0, 1e-9);
  size_t j = 0;
  while (before(kidnapped.ground_truth[j])) ++j;
  ASSERT_GT(j, 0u);
  const Pose2& seen = kidnapped.ground_truth[j].pose;
  const Pose2& seen_before = kidnapped.ground_truth[j - 1].pose;
  EXPECT_NEAR(kidnapped.ground_truth[j].t, kKidnapT, 1e-9);
  EXPECT_LT((seen.translation() - to.translation()).norm(), 0.006);
  EXPECT_LT(std::abs(NormalizeAngle(seen.theta - to.theta)), 0.025);
  const double moved = (to.translation() - from.translation()).norm();
  const double turned = std::abs(NormalizeAngle(to.theta - from.theta));
  if (moved > 0.4 || turned > DegToRad(30.0)) {
    EXPECT_TRUE((seen.translation() - seen_before.translation()).norm() > 0.3 ||
                std::abs(NormalizeAngle(seen.theta - seen_before.theta)) > DegToRad(20.0))
        << "moved " << moved << " m, turned " << RadToDeg(turned) << " degrees";
  }

  // Set down there, it drives on clear of the obstacles.
  double min_clearance = 1e9;
  for (const TimedPose& p : kidnapped.true_path) {
    if (before(p)) continue;
    min_clearance = std::min(min_clearance, ClearanceAt(world, p.pose.translation()));
    EXPECT_TRUE(p.pose.x >= world.bounds[0] && p.pose.x <= world.bounds[2] &&
                p.pose.y >= world.bounds[1] && p.pose.y <= world.bounds[3]);
  }
  EXPECT_GE(min_clearance, 0.085);
  EXPECT_GT((kidnapped.true_path.back().pose.translation() - to.translation()).norm(), 0.05)
      << "it does not drive on";
}

TEST(KidnapTest, InEveryBuiltinWorldTheTruthJumpsAndTheOdometryDoesNot) {
  const RobotDescription robot = TestRobot();
  for (const std::string& name : BuiltinWorldNames()) {
    SCOPED_TRACE(name);
    const World world = *BuiltinWorld(name);
    const ScenarioOutput plain = RunScenario(world, robot, ShortRun(40.0, 1));
    // Set down where it was at half the kidnapping's time, with that heading.
    const ScenarioOutput back = RunScenario(world, robot, KidnapRun(1));
    ExpectKidnapped(world, plain, back, At(plain.true_path, kKidnapT / 2.0));
    // And at the place farthest from where it was lifted, with another heading.
    ScenarioConfig config = KidnapRun(1);
    Pose2 far = FarthestBefore(plain.true_path, At(plain.true_path, kKidnapT), kKidnapT);
    far.theta = NormalizeAngle(far.theta + 2.0);
    ASSERT_GT((far.translation() - At(plain.true_path, kKidnapT).translation()).norm(), 0.4);
    config.kidnap_to = far;
    ASSERT_TRUE(config.Validate().empty());
    ASSERT_TRUE(CheckFreePose(world, config.robot_radius_m, far).ok());
    ExpectKidnapped(world, plain, RunScenario(world, robot, config), far);
  }
}

TEST(KidnapTest, TheSameKidnappingGivesTheSameRun) {
  const World world = *BuiltinWorld("cluttered");
  const ScenarioOutput a = RunScenario(world, TestRobot(), KidnapRun(3));
  const ScenarioOutput b = RunScenario(world, TestRobot(), KidnapRun(3));
  ASSERT_EQ(a.odometry.size(), b.odometry.size());
  EXPECT_EQ(a.odometry, b.odometry);
  EXPECT_EQ(a.scanner, b.scanner);
  ASSERT_EQ(a.kidnaps.size(), 1u);
  EXPECT_EQ(a.kidnaps[0].to.x, b.kidnaps[0].to.x);
  EXPECT_EQ(a.ground_truth.back().pose.x, b.ground_truth.back().pose.x);
}

TEST(KidnapTest, ConfigValidationNamesTheKidnapKeys) {
  ScenarioConfig config = ShortRun(40.0, 1);
  for (const double t : {0.0, -1.0, 40.0, 41.0, std::nan("")}) {
    config.kidnap_t_s = t;
    EXPECT_EQ(config.Validate(),
              std::vector<std::string>{"/kidnap_t_s: must be in (0, duration_s)"})
        << t;
  }
  config.kidnap_t_s = 39.9;
  EXPECT_TRUE(config.Validate().empty());
  config.kidnap_to = Pose2{0.0, std::numeric_limits<double>::infinity(), 0.0};
  EXPECT_EQ(config.Validate(), std::vector<std::string>{"/kidnap_to: must be finite"});
  config.kidnap_t_s.reset();
  config.kidnap_to = Pose2{0.5, 0.5, 0.0};
  EXPECT_EQ(config.Validate(), std::vector<std::string>{"/kidnap_to: needs kidnap_t_s"});
}

TEST(KidnapTest, ATargetInAWallOrOutsideIsRefused) {
  const World rooms = *BuiltinWorld("rooms");
  const World cluttered = *BuiltinWorld("cluttered");
  ASSERT_FALSE(rooms.segments.empty());
  ASSERT_FALSE(cluttered.circles.empty());
  const Segment& wall = rooms.segments.front();
  const Vec2 on_wall = 0.5 * (wall.a + wall.b);
  const Circle& pillar = cluttered.circles.front();
  const double radius = ScenarioConfig{}.robot_radius_m;
  const auto refused = [&](const World& world, const Pose2& pose) {
    return !CheckFreePose(world, radius, pose).ok();
  };
  EXPECT_TRUE(refused(rooms, {on_wall.x(), on_wall.y(), 0.0}));
  // Beside the wall, the disc overlapping it by a millimetre; two millimetres farther it fits.
  const Vec2 along = (wall.b - wall.a).normalized();
  const Vec2 normal(-along.y(), along.x());
  for (const double side : {1.0, -1.0}) {
    const Vec2 near = on_wall + side * (radius - 0.001) * normal;
    const Vec2 clear = on_wall + side * (radius + 0.001) * normal;
    if (!(ClearanceAt(rooms, clear) > radius)) continue;  // another wall there
    EXPECT_TRUE(refused(rooms, {near.x(), near.y(), 0.0}));
  }
  EXPECT_TRUE(refused(cluttered, {pillar.center.x(), pillar.center.y(), 1.0}));
  EXPECT_TRUE(refused(rooms, {rooms.bounds[2] + 1.0, rooms.bounds[3] - 0.5, 0.0}));   // outside
  EXPECT_TRUE(refused(rooms, {rooms.bounds[0] + 0.05, rooms.bounds[1] + 0.5, 0.0}));  // the edge
  EXPECT_TRUE(refused(rooms, {std::nan(""), 0.5, 0.0}));
  const ScenarioOutput plain = RunScenario(rooms, TestRobot(), ShortRun(40.0, 1));
  const Pose2 visited = At(plain.true_path, 10.0);
  EXPECT_TRUE(CheckFreePose(rooms, radius, visited).ok());
  const Result<void> message = CheckFreePose(rooms, radius, {on_wall.x(), on_wall.y(), 0.0});
  EXPECT_NE(message.Message().find("overlaps a wall"), std::string::npos) << message.Message();

  // The simulator refuses it and goes on as without.
  Simulator simulator(rooms, TestRobot(), ShortRun(40.0, 1));
  ScenarioOutput out;
  while (simulator.time() < 10.0 - 1e-9) simulator.Step(out);
  EXPECT_FALSE(simulator.Kidnap({on_wall.x(), on_wall.y(), 0.0}).ok());
  while (simulator.time() < 20.0 - 1e-9) simulator.Step(out);
  EXPECT_TRUE(out.kidnaps.empty());
  ASSERT_GE(plain.odometry.size(), out.odometry.size());
  for (size_t i = 0; i < out.odometry.size(); ++i) ASSERT_EQ(out.odometry[i], plain.odometry[i]);
  // A config whose target is in a wall is no kidnapping (RunScenario's precondition).
  ScenarioConfig config = KidnapRun(1);
  config.kidnap_to = Pose2{on_wall.x(), on_wall.y(), 0.0};
  const ScenarioOutput walled = RunScenario(rooms, TestRobot(), config);
  EXPECT_TRUE(walled.kidnaps.empty());
  EXPECT_EQ(walled.odometry, plain.odometry);
}

TEST(KidnapTest, TheSimulatorSetsTheRobotDownAtTheNextStep) {
  const World world = *BuiltinWorld("box");
  const ScenarioOutput plain = RunScenario(world, TestRobot(), ShortRun(20.0, 2));
  const Pose2 target{At(plain.true_path, 3.0).x, At(plain.true_path, 3.0).y, 2.5};
  Simulator simulator(world, TestRobot(), ShortRun(20.0, 2));
  ScenarioOutput out;
  while (simulator.time() < 12.0 - 1e-9) simulator.Step(out);
  const Pose2 lifted = simulator.pose();
  ASSERT_TRUE(simulator.Kidnap(target).ok());
  EXPECT_EQ(simulator.pose().x, lifted.x);  // not before the next step
  simulator.Step(out);
  ASSERT_EQ(out.kidnaps.size(), 1u);
  EXPECT_NEAR(out.kidnaps[0].t, 12.0, 1e-9);
  EXPECT_EQ(out.kidnaps[0].from.x, lifted.x);
  EXPECT_EQ(out.kidnaps[0].to.x, target.x);
  EXPECT_NEAR(out.kidnaps[0].to.theta, 2.5, 1e-12);
  // One step (10 ms) on from the target.
  EXPECT_LT((simulator.pose().translation() - target.translation()).norm(), 0.002);
  EXPECT_LT(std::abs(NormalizeAngle(simulator.pose().theta - target.theta)), 0.03);
  EXPECT_NEAR(out.true_path.back().pose.x, target.x, 0.002);
}

TEST(BuildScansTest, HalfTurnsOfFortySamplesWithOdometryPoses) {
  const RobotDescription robot = TestRobot();
  const ScenarioOutput out = RunScenario(*BuiltinWorld("rooms"), robot, ShortRun(20.0, 11));
  const std::vector<Scan> scans = BuildScans(robot, out.odometry, out.scanner);
  // 1201 samples at 40 per half turn: 30 complete scans, the 31st has a single sample.
  ASSERT_EQ(scans.size(), 30u);
  const std::vector<TimedPose> odom = DeadReckoning(robot, out.odometry);
  for (size_t k = 0; k < scans.size(); ++k) {
    SCOPED_TRACE(k);
    const Scan& scan = scans[k];
    EXPECT_EQ(scan.index, static_cast<int64_t>(k));
    ASSERT_EQ(scan.samples.size(), 40u);
    EXPECT_DOUBLE_EQ(scan.t_begin, k == 0 ? 0.0 : scans[k - 1].t_end);
    EXPECT_DOUBLE_EQ(scan.t_end, scan.samples.back().t);
    EXPECT_DOUBLE_EQ(scan.samples.front().t, static_cast<double>(40 * k) / 60.0);
    EXPECT_EQ(scan.odom_end.x, scan.samples.back().odom.x);
    if (k > 0) {
      EXPECT_EQ(scan.odom_begin.x, scans[k - 1].odom_end.x);
    }
    // Half a turn: platform angles span [0, 180) or [180, 360) degrees.
    const double first = RadToDeg(scan.samples.front().platform_angle_rad);
    const double last = RadToDeg(scan.samples.back().platform_angle_rad);
    EXPECT_NEAR(first, k % 2 == 0 ? 0.0 : 180.0, 0.01);
    EXPECT_NEAR(last, k % 2 == 0 ? 175.5 : 355.5, 0.01);
    for (size_t i = 0; i < scan.samples.size(); ++i) {
      const ScanSample& sample = scan.samples[i];
      EXPECT_EQ(sample.raw, out.scanner[40 * k + i].raw);
      // Samples at odometry times carry exactly the dead-reckoned pose.
      if (std::fmod(sample.t * 10.0, 1.0) < 1e-6) {
        const Pose2 expected = At(odom, sample.t);
        EXPECT_NEAR(sample.odom.x, expected.x, 1e-9);
        EXPECT_NEAR(sample.odom.theta, expected.theta, 1e-9);
      }
    }
  }
  EXPECT_EQ(scans.front().odom_begin.x, 0.0);
  EXPECT_EQ(scans.front().odom_begin.theta, 0.0);
}

TEST(BuildScansTest, InterpolatesBetweenOdometryReadings) {
  RobotDescription robot = TestRobot();
  // Straight line along x at 0.1 m/s: 1137.5 ticks per second per treel, no rotation.
  std::vector<OdometryReading> odometry;
  for (int i = 0; i <= 10; ++i) {
    OdometryReading r;
    r.t = 0.5 + 0.1 * i;
    const int64_t ticks = int64_t{2147483000} + std::llround(113.75 * i);  // wraps past 2^31
    r.left_ticks = r.right_ticks = static_cast<int32_t>(static_cast<uint32_t>(ticks));
    odometry.push_back(r);
  }
  std::vector<ScannerReading> scanner;
  for (int i = 0; i < 50; ++i) {
    ScannerReading r;
    r.t = 0.46 + 0.025 * i;  // starts before the odometry, ends after it
    r.angle_raw = static_cast<uint16_t>((65536 - 8000 + 4000 * i) % 65536);  // wraps around
    scanner.push_back(r);
  }
  const std::vector<Scan> scans = BuildScans(robot, odometry, scanner);
  // The 40 samples within [0.5, 1.5] s turn by 4000 raw units each: half turns (32768 units)
  // of 9, 8, 8, 8 samples, then an incomplete one that is left out.
  ASSERT_EQ(scans.size(), 4u);
  EXPECT_DOUBLE_EQ(scans[0].t_begin, 0.51);
  EXPECT_EQ(scans[0].samples.size(), 9u);
  for (size_t k = 1; k < 4; ++k) EXPECT_EQ(scans[k].samples.size(), 8u);
  EXPECT_DOUBLE_EQ(scans[1].t_begin, scans[0].t_end);
  for (const Scan& scan : scans) {
    for (const ScanSample& s : scan.samples) {
      EXPECT_NEAR(s.odom.x, 0.1 * (s.t - 0.5), 1e-4);  // through the counters' wrap
      EXPECT_NEAR(s.odom.y, 0.0, 1e-12);
    }
  }
}

}  // namespace
}  // namespace slam::sim

// Found by fuzz_json_config: a number beyond a double made nlohmann throw out_of_range, which
// escaped ParseWorld and ended the program.
TEST(WorldJsonRegression, NumberTooLargeIsAnErrorNotACrash) {
  const slam::Result<slam::sim::World> result = slam::sim::ParseWorld(
      R"({"name": "w", "bounds": [0, 0, 1e400, 1], "segments": [], "circles": []})", "w.json");
  EXPECT_FALSE(result.ok());
  ASSERT_EQ(result.errors().size(), 1u);
  EXPECT_NE(result.errors()[0].detail.find("w.json: invalid JSON"), std::string::npos)
      << result.errors()[0].detail;
}
