#pragma once
// Simulated worlds: walls as line segments and round obstacles as circles, in metres
// (docs/design.md section 5, world.json), with exact ray casting for the simulated sensors and the
// built-in arenas of about 2 m modelled on the paper's Fig. 9.

#include <array>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "engine/pose.hpp"
#include "engine/result.hpp"

namespace slam::sim {

/// A wall: the segment from a to b.
struct Segment {
  Vec2 a = Vec2::Zero();
  Vec2 b = Vec2::Zero();
};

/// A round obstacle (solid disc).
struct Circle {
  Vec2 center = Vec2::Zero();
  double radius_m = 0.0;
};

struct World {
  std::string name;
  std::array<double, 4> bounds{0.0, 0.0, 0.0, 0.0};  // x0, y0, x1, y1: the area the robot may use
  std::vector<Segment> segments;
  std::vector<Circle> circles;
};

/// Distance from `origin` along `angle` (radians) to the first segment or circle, when one lies
/// within `max_range_m`. A ray starting inside a circle or on a segment gives 0; a ray running
/// along a segment hits its nearer end.
std::optional<double> RayDistance(const World& world, const Vec2& origin, double angle,
                                  double max_range_m);

/// Distance from `p` to the nearest obstacle (0 inside a circle); +infinity in an empty world.
double ClearanceAt(const World& world, const Vec2& p);

/// Points where two or more segment ends meet (within 1 mm): the corners of walls and boxes.
std::vector<Vec2> Corners(const World& world);

/// Structural problems of a world (bounds order, degenerate segments, non-positive radii,
/// non-finite numbers) as "/pointer: detail" lines; empty when valid.
std::vector<std::string> Validate(const World& world);

/// Parses world.json text; `source` names the input in error messages, each error's detail
/// being "source:line: /pointer: detail" ("source: /pointer: detail" when the line is unknown).
/// Unknown keys are errors.
Result<World> ParseWorld(std::string_view json_text, std::string_view source);

/// Reads and parses a world.json file.
Result<World> LoadWorld(const std::string& path);

/// The world as world.json text (pretty-printed, exact round trip of every number).
std::string WorldToJson(const World& world);

/// Writes world.json atomically (temporary file + rename).
Result<void> SaveWorld(const std::string& path, const World& world);

/// Names of the built-in arenas: "box", "rooms", "cluttered".
std::vector<std::string> BuiltinArenaNames();

/// A built-in arena by name, nullopt for an unknown name.
std::optional<World> BuiltinArena(std::string_view name);

/// A built-in arena when `name_or_path` names one, else the world.json file at that path.
Result<World> ResolveWorld(const std::string& name_or_path);

}  // namespace slam::sim
