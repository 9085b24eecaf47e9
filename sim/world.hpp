#pragma once
// Simulated worlds: walls as line segments and round obstacles as circles, in metres
// (docs/design.md section 5, world.json), with exact ray casting for the simulated sensors, the
// built-in arenas of about 2 m modelled on the paper's Fig. 9 and real-size rooms (sim/worlds/).

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

/// What the treels run on: how far the encoders' distance departs from the true one, and how
/// much the treels slip and skid, compared with a hard floor (tiles, wood, linoleum).
enum class FloorMaterial { kHard, kCarpet, kRug };

/// A rectangle of floor of one material.
struct FloorPatch {
  std::array<double, 4> area{0.0, 0.0, 0.0, 0.0};  // x0, y0, x1, y1
  FloorMaterial material = FloorMaterial::kHard;
};

/// How a floor material changes the treels' odometry (sim/scenario.cpp applies it).
struct FloorTraction {
  double scale_bias = 0.0;   // the encoders read this much more than the true distance (0.03 = 3%)
  double slip_factor = 1.0;  // times the slip noise of a hard floor
  double skid_factor = 1.0;  // times the sideways skid of a hard floor
};

/// The traction of each material: a carpet's pile compresses under the treels (they travel less
/// than their sprockets turn) and lets them skid more in turns; a loose rug more so.
FloorTraction TractionOf(FloorMaterial material);

/// "hard", "carpet", "rug"; nullopt for anything else.
std::optional<FloorMaterial> FloorMaterialFromName(std::string_view name);
std::string_view FloorMaterialName(FloorMaterial material);

struct World {
  std::string name;
  std::array<double, 4> bounds{0.0, 0.0, 0.0, 0.0};  // x0, y0, x1, y1: the area the robot may use
  std::vector<Segment> segments;
  std::vector<Circle> circles;
  // Floor patches, later ones over earlier ones; a hard floor where none lies.
  std::vector<FloorPatch> floors;
};

/// The floor material at `p`: the last patch containing it, hard where none does.
FloorMaterial FloorAt(const World& world, const Vec2& p);

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

/// Names of the built-in arenas of the paper's size (about 2 m, Fig. 9): "box", "rooms",
/// "cluttered".
std::vector<std::string> BuiltinArenaNames();

/// Names of every built-in world: the arenas, then the real-size worlds of sim/worlds/ in
/// sim/CMakeLists.txt's order.
std::vector<std::string> BuiltinWorldNames();

/// BuiltinWorldNames() joined with ", " ("box, rooms, ..."), for help texts and errors.
std::string BuiltinWorldList();

/// A built-in world by name, nullopt for an unknown name.
std::optional<World> BuiltinWorld(std::string_view name);

/// A built-in world when `name_or_path` names one, else the world.json file at that path; when
/// there is no such file, an error that lists every built-in world.
Result<World> ResolveWorld(const std::string& name_or_path);

}  // namespace slam::sim
