#include "sim/world.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>

#include "engine/config_error.hpp"
#include "engine/io/atomic_file.hpp"
#include "engine/io/json_reader.hpp"
#include "sim/builtin_worlds.hpp"

namespace slam::sim {
namespace {

using Json = nlohmann::json;

double Cross(const Vec2& a, const Vec2& b) { return a.x() * b.y() - a.y() * b.x(); }

/// Distance from p to the segment [a, b].
double PointSegmentDistance(const Vec2& p, const Vec2& a, const Vec2& b) {
  const Vec2 e = b - a;
  const double len2 = e.squaredNorm();
  const double s = len2 > 0.0 ? std::clamp((p - a).dot(e) / len2, 0.0, 1.0) : 0.0;
  return (a + s * e - p).norm();
}

/// Ray parameter t >= 0 where origin + t * d meets the segment, if it does.
std::optional<double> RaySegment(const Vec2& origin, const Vec2& d, const Segment& seg) {
  const Vec2 e = seg.b - seg.a;
  const Vec2 w = seg.a - origin;
  const double denom = Cross(d, e);
  const double e_norm = e.norm();
  if (std::abs(denom) <= 1e-12 * e_norm) {
    // Parallel: only a collinear segment can be hit.
    if (std::abs(Cross(w, d)) > 1e-12 * (1.0 + w.norm())) return std::nullopt;
    const double ta = w.dot(d);
    const double tb = (seg.b - origin).dot(d);
    if (ta < 0.0 && tb < 0.0) return std::nullopt;
    if ((ta <= 0.0) != (tb <= 0.0) || ta == 0.0 || tb == 0.0) return 0.0;
    return std::min(ta, tb);
  }
  const double t = Cross(w, e) / denom;
  const double s = Cross(w, d) / denom;
  if (t < 0.0 || s < 0.0 || s > 1.0) return std::nullopt;
  return t;
}

/// Ray parameter t >= 0 where origin + t * d enters the circle (0 when starting inside).
std::optional<double> RayCircle(const Vec2& origin, const Vec2& d, const Circle& circle) {
  const Vec2 f = origin - circle.center;
  const double b = f.dot(d);
  const double c = f.squaredNorm() - circle.radius_m * circle.radius_m;
  if (c <= 0.0) return 0.0;
  const double disc = b * b - c;
  if (disc < 0.0) return std::nullopt;
  const double t = -b - std::sqrt(disc);
  if (t < 0.0) return std::nullopt;
  return t;
}

std::string Pointer(std::string_view base, size_t index) {
  return std::string(base) + "/" + std::to_string(index);
}

/// Reads an array of exactly n finite numbers at `pointer`, recording errors.
std::optional<std::vector<double>> ReadNumbers(const Json& value, size_t n,
                                               const std::string& pointer, ConfigErrors& errors) {
  if (!value.is_array() || value.size() != n) {
    errors.push_back({pointer, "expected an array of " + std::to_string(n) + " numbers"});
    return std::nullopt;
  }
  std::vector<double> numbers;
  bool ok = true;
  for (size_t i = 0; i < n; ++i) {
    if (!value[i].is_number()) {
      errors.push_back({Pointer(pointer, i), "expected a number"});
      ok = false;
      continue;
    }
    numbers.push_back(value[i].get<double>());
  }
  if (!ok) return std::nullopt;
  return numbers;
}

/// The structural problems of a world, each with its pointer.
// Plausible bounds: a building, not a city. Map quality samples every surface each centimetre
// or so, and the robot's start is searched within the bounds: a world of 1e6 m made both
// allocate or loop without bound.
constexpr double kMaxCoordinateM = 1000.0;  // |x|, |y| of every point, and radii
constexpr double kMaxSurfaceM = 10000.0;    // total length of walls and circle perimeters

std::string Num(double value) {
  std::ostringstream out;
  out << value;
  return out.str();
}

ConfigErrors WorldErrors(const World& world) {
  ConfigErrors errors;
  const auto within = [&](const std::string& pointer, double value) {
    if (std::isfinite(value) && std::abs(value) > kMaxCoordinateM) {
      errors.push_back({pointer, Num(value) + " m is beyond the plausible +-" +
                                     Num(kMaxCoordinateM) + " m of a world"});
    }
  };
  const auto& b = world.bounds;
  for (size_t i = 0; i < 4; ++i) {
    if (!std::isfinite(b[i])) errors.push_back({Pointer("/bounds", i), "must be finite"});
    within(Pointer("/bounds", i), b[i]);
  }
  if (!(b[0] < b[2]) || !(b[1] < b[3])) {
    errors.push_back({"/bounds", "expected x0 < x1 and y0 < y1"});
  }
  double surface_m = 0.0;
  for (size_t i = 0; i < world.segments.size(); ++i) {
    const Segment& s = world.segments[i];
    const std::string at = Pointer("/segments", i);
    if (!s.a.allFinite() || !s.b.allFinite()) {
      errors.push_back({at, "coordinates must be finite"});
      continue;
    }
    if ((s.b - s.a).norm() <= 0.0) errors.push_back({at, "the two ends must differ"});
    const double coordinates[4] = {s.a.x(), s.a.y(), s.b.x(), s.b.y()};
    for (size_t k = 0; k < 4; ++k) within(Pointer(at, k), coordinates[k]);
    surface_m += (s.b - s.a).norm();
  }
  for (size_t i = 0; i < world.circles.size(); ++i) {
    const Circle& c = world.circles[i];
    const std::string at = Pointer("/circles", i);
    if (!c.center.allFinite() || !std::isfinite(c.radius_m)) {
      errors.push_back({at, "values must be finite"});
      continue;
    }
    if (c.radius_m <= 0.0) errors.push_back({at + "/2", "the radius must be positive"});
    within(at + "/0", c.center.x());
    within(at + "/1", c.center.y());
    within(at + "/2", c.radius_m);
    surface_m += 2.0 * kPi * std::abs(c.radius_m);
  }
  for (size_t i = 0; i < world.floors.size(); ++i) {
    const auto& a = world.floors[i].area;
    const std::string at = Pointer("/floors", i) + "/area";
    bool finite = true;
    for (size_t k = 0; k < 4; ++k) {
      if (!std::isfinite(a[k])) {
        errors.push_back({Pointer(at, k), "must be finite"});
        finite = false;
      }
      within(Pointer(at, k), a[k]);
    }
    if (finite && (!(a[0] < a[2]) || !(a[1] < a[3]))) {
      errors.push_back({at, "expected x0 < x1 and y0 < y1"});
    }
  }
  if (surface_m > kMaxSurfaceM) {
    errors.push_back({"/segments", "the walls and circles measure " + Num(surface_m) +
                                       " m in all, beyond the plausible " + Num(kMaxSurfaceM) +
                                       " m"});
  }
  return errors;
}

/// Appends the four walls of an axis-aligned rectangle (counter-clockwise).
void AddRectangle(World& world, double x0, double y0, double x1, double y1) {
  const Vec2 p00(x0, y0), p10(x1, y0), p11(x1, y1), p01(x0, y1);
  world.segments.push_back({p00, p10});
  world.segments.push_back({p10, p11});
  world.segments.push_back({p11, p01});
  world.segments.push_back({p01, p00});
}

/// Appends the walls of a square of side `side` centred on `center`, turned by `angle_deg`.
void AddSquare(World& world, const Vec2& center, double side, double angle_deg) {
  const Pose2 frame{center.x(), center.y(), DegToRad(angle_deg)};
  const double h = side / 2.0;
  const Vec2 corners[4] = {frame.Transform({-h, -h}), frame.Transform({h, -h}),
                           frame.Transform({h, h}), frame.Transform({-h, h})};
  for (int i = 0; i < 4; ++i) world.segments.push_back({corners[i], corners[(i + 1) % 4]});
}

/// A room with a rectangular box in it.
World BoxArena() {
  World world;
  world.name = "box";
  world.bounds = {0.0, 0.0, 2.0, 1.8};
  AddRectangle(world, 0.0, 0.0, 2.0, 1.8);
  AddRectangle(world, 0.8, 0.7, 1.3, 1.05);
  return world;
}

/// Three rooms separated by walls with 50 cm doorways.
World RoomsArena() {
  World world;
  world.name = "rooms";
  world.bounds = {0.0, 0.0, 2.4, 2.0};
  AddRectangle(world, 0.0, 0.0, 2.4, 2.0);
  // Vertical wall at x = 1.1 with a doorway for y in [0.3, 0.8].
  world.segments.push_back({{1.1, 0.0}, {1.1, 0.3}});
  world.segments.push_back({{1.1, 0.8}, {1.1, 2.0}});
  // Horizontal wall at y = 1.1 across the right half, doorway for x in [1.6, 2.1].
  world.segments.push_back({{1.1, 1.1}, {1.6, 1.1}});
  world.segments.push_back({{2.1, 1.1}, {2.4, 1.1}});
  return world;
}

/// A room with round and square obstacles, every gap at least 25 cm.
World ClutteredArena() {
  World world;
  world.name = "cluttered";
  world.bounds = {0.0, 0.0, 2.0, 2.0};
  AddRectangle(world, 0.0, 0.0, 2.0, 2.0);
  AddSquare(world, {1.0, 0.95}, 0.22, 0.0);
  AddSquare(world, {1.5, 1.5}, 0.2, 30.0);
  AddSquare(world, {0.4, 1.0}, 0.16, 0.0);
  world.circles.push_back({{0.45, 0.45}, 0.10});
  world.circles.push_back({{1.55, 0.45}, 0.08});
  world.circles.push_back({{0.45, 1.55}, 0.12});
  world.circles.push_back({{1.0, 1.6}, 0.06});
  world.circles.push_back({{1.0, 0.35}, 0.07});
  return world;
}

/// The arenas of the paper's size, built in code; with the files of BuiltinWorldFiles(), the one
/// table of built-in worlds that the names, the lookup, help texts and errors all come from.
struct BuiltinArena {
  std::string_view name;
  World (*make)();
};
constexpr BuiltinArena kBuiltinArenas[] = {
    {"box", BoxArena}, {"rooms", RoomsArena}, {"cluttered", ClutteredArena}};

}  // namespace

std::optional<double> RayDistance(const World& world, const Vec2& origin, double angle,
                                  double max_range_m) {
  const Vec2 d(std::cos(angle), std::sin(angle));
  double best = std::numeric_limits<double>::infinity();
  for (const Segment& seg : world.segments) {
    if (const auto t = RaySegment(origin, d, seg)) best = std::min(best, *t);
  }
  for (const Circle& circle : world.circles) {
    if (const auto t = RayCircle(origin, d, circle)) best = std::min(best, *t);
  }
  if (best > max_range_m) return std::nullopt;
  return best;
}

FloorTraction TractionOf(FloorMaterial material) {
  switch (material) {
    case FloorMaterial::kCarpet:
      return {0.025, 1.5, 2.0};
    case FloorMaterial::kRug:
      return {0.04, 2.5, 3.0};
    case FloorMaterial::kHard:
      break;
  }
  return {};
}

std::optional<FloorMaterial> FloorMaterialFromName(std::string_view name) {
  if (name == "hard") return FloorMaterial::kHard;
  if (name == "carpet") return FloorMaterial::kCarpet;
  if (name == "rug") return FloorMaterial::kRug;
  return std::nullopt;
}

std::string_view FloorMaterialName(FloorMaterial material) {
  switch (material) {
    case FloorMaterial::kCarpet:
      return "carpet";
    case FloorMaterial::kRug:
      return "rug";
    case FloorMaterial::kHard:
      break;
  }
  return "hard";
}

FloorMaterial FloorAt(const World& world, const Vec2& p) {
  for (auto it = world.floors.rbegin(); it != world.floors.rend(); ++it) {
    const auto& a = it->area;
    if (p.x() >= a[0] && p.x() <= a[2] && p.y() >= a[1] && p.y() <= a[3]) return it->material;
  }
  return FloorMaterial::kHard;
}

double ClearanceAt(const World& world, const Vec2& p) {
  double best = std::numeric_limits<double>::infinity();
  for (const Segment& seg : world.segments) {
    best = std::min(best, PointSegmentDistance(p, seg.a, seg.b));
  }
  for (const Circle& circle : world.circles) {
    best = std::min(best, std::max(0.0, (p - circle.center).norm() - circle.radius_m));
  }
  return best;
}

std::vector<Vec2> Corners(const World& world) {
  constexpr double kTouch = 1e-3;
  std::vector<Vec2> corners;
  for (size_t i = 0; i < world.segments.size(); ++i) {
    for (const Vec2& end : {world.segments[i].a, world.segments[i].b}) {
      bool touches = false;
      for (size_t j = 0; j < world.segments.size() && !touches; ++j) {
        if (j != i) {
          touches = PointSegmentDistance(end, world.segments[j].a, world.segments[j].b) <= kTouch;
        }
      }
      const bool known = std::any_of(corners.begin(), corners.end(),
                                     [&](const Vec2& c) { return (c - end).norm() <= kTouch; });
      if (touches && !known) corners.push_back(end);
    }
  }
  return corners;
}

std::vector<std::string> Validate(const World& world) {
  std::vector<std::string> errors;
  for (const ConfigError& error : WorldErrors(world)) {
    errors.push_back(error.pointer + ": " + error.detail);
  }
  return errors;
}

Result<World> ParseWorld(std::string_view json_text, std::string_view source) {
  const std::string prefix = std::string(source) + ": ";
  Json doc;
  try {
    doc = Json::parse(json_text);
  } catch (const Json::exception& e) {  // parse_error, and out_of_range for 1e400
    return Error(prefix + "invalid JSON: " + e.what());
  }
  if (!doc.is_object()) {
    return Error(prefix + "expected a JSON object");
  }
  ConfigErrors errors;
  World world;
  for (const auto& [key, value] : doc.items()) {
    if (key != "name" && key != "bounds" && key != "segments" && key != "circles" &&
        key != "floors") {
      errors.push_back({io::detail::Child("", key), "unknown key"});
    }
  }
  if (!doc.contains("name")) {
    errors.push_back({"/name", "missing"});
  } else if (!doc["name"].is_string()) {
    errors.push_back({"/name", "expected a string"});
  } else {
    world.name = doc["name"].get<std::string>();
  }
  if (!doc.contains("bounds")) {
    errors.push_back({"/bounds", "missing"});
  } else if (const auto b = ReadNumbers(doc["bounds"], 4, "/bounds", errors)) {
    std::copy(b->begin(), b->end(), world.bounds.begin());
  }
  if (doc.contains("segments")) {
    const Json& list = doc["segments"];
    if (!list.is_array()) {
      errors.push_back({"/segments", "expected an array of [x1, y1, x2, y2]"});
    } else {
      for (size_t i = 0; i < list.size(); ++i) {
        if (const auto v = ReadNumbers(list[i], 4, Pointer("/segments", i), errors)) {
          world.segments.push_back({{(*v)[0], (*v)[1]}, {(*v)[2], (*v)[3]}});
        }
      }
    }
  }
  if (doc.contains("circles")) {
    const Json& list = doc["circles"];
    if (!list.is_array()) {
      errors.push_back({"/circles", "expected an array of [cx, cy, r]"});
    } else {
      for (size_t i = 0; i < list.size(); ++i) {
        if (const auto v = ReadNumbers(list[i], 3, Pointer("/circles", i), errors)) {
          world.circles.push_back({{(*v)[0], (*v)[1]}, (*v)[2]});
        }
      }
    }
  }
  if (doc.contains("floors")) {
    const Json& list = doc["floors"];
    if (!list.is_array()) {
      errors.push_back({"/floors",
                        "expected an array of {\"area\": [x0, y0, x1, y1], "
                        "\"material\": \"hard\"|\"carpet\"|\"rug\"}"});
    } else {
      for (size_t i = 0; i < list.size(); ++i) {
        const std::string at = Pointer("/floors", i);
        const Json& item = list[i];
        if (!item.is_object()) {
          errors.push_back({at, "expected an object with \"area\" and \"material\""});
          continue;
        }
        for (const auto& [key, value] : item.items()) {
          if (key != "area" && key != "material") {
            errors.push_back({io::detail::Child(at, key), "unknown key"});
          }
        }
        FloorPatch patch;
        bool ok = true;
        if (!item.contains("area")) {
          errors.push_back({at + "/area", "missing"});
          ok = false;
        } else if (const auto v = ReadNumbers(item["area"], 4, at + "/area", errors)) {
          std::copy(v->begin(), v->end(), patch.area.begin());
        } else {
          ok = false;
        }
        if (!item.contains("material")) {
          errors.push_back({at + "/material", "missing"});
          ok = false;
        } else if (!item["material"].is_string()) {
          errors.push_back({at + "/material", "expected \"hard\", \"carpet\" or \"rug\""});
          ok = false;
        } else if (const auto m = FloorMaterialFromName(item["material"].get<std::string>())) {
          patch.material = *m;
        } else {
          errors.push_back({at + "/material", "unknown material \"" +
                                                  item["material"].get<std::string>() +
                                                  "\" (expected hard, carpet or rug)"});
          ok = false;
        }
        if (ok) world.floors.push_back(patch);
      }
    }
  }
  if (errors.empty()) errors = WorldErrors(world);
  if (!errors.empty()) {
    io::detail::AddLines(errors, json_text);
    ConfigErrors located;
    for (const ConfigError& e : errors) {
      // "source:line: /pointer: detail", or "source: /pointer: detail" when the line is unknown.
      const std::string at =
          e.line > 0 ? std::string(source) + ':' + std::to_string(e.line) + ": " : prefix;
      located.push_back({"", at + e.pointer + ": " + e.detail, 0});
    }
    return located;
  }
  return world;
}

Result<World> LoadWorld(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Error(path + ": cannot open: " + std::strerror(errno));
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) return Error(path + ": read error");
  return ParseWorld(text.str(), path);
}

std::string WorldToJson(const World& world) {
  // One obstacle per line; numbers go through nlohmann so that they round-trip exactly.
  const auto row = [](std::initializer_list<double> values) {
    std::string out = "[";
    for (const double v : values) out += (out.size() > 1 ? ", " : "") + Json(v).dump();
    return out + "]";
  };
  std::string out = "{\n  \"name\": " + Json(world.name).dump() + ",\n";
  const auto& b = world.bounds;
  out += "  \"bounds\": " + row({b[0], b[1], b[2], b[3]}) + ",\n  \"segments\": [";
  for (size_t i = 0; i < world.segments.size(); ++i) {
    const Segment& s = world.segments[i];
    out += (i ? ",\n    " : "\n    ") + row({s.a.x(), s.a.y(), s.b.x(), s.b.y()});
  }
  out += world.segments.empty() ? "],\n  \"circles\": [" : "\n  ],\n  \"circles\": [";
  for (size_t i = 0; i < world.circles.size(); ++i) {
    const Circle& c = world.circles[i];
    out += (i ? ",\n    " : "\n    ") + row({c.center.x(), c.center.y(), c.radius_m});
  }
  out += world.circles.empty() ? "]" : "\n  ]";
  if (!world.floors.empty()) {
    out += ",\n  \"floors\": [";
    for (size_t i = 0; i < world.floors.size(); ++i) {
      const auto& a = world.floors[i].area;
      out += std::string(i ? ",\n    " : "\n    ") + "{\"area\": " + row({a[0], a[1], a[2], a[3]}) +
             ", \"material\": \"" + std::string(FloorMaterialName(world.floors[i].material)) +
             "\"}";
    }
    out += "\n  ]";
  }
  return out + "\n}\n";
}

Result<void> SaveWorld(const std::string& path, const World& world) {
  return io::WriteFileAtomic(path, WorldToJson(world));
}

std::vector<std::string> BuiltinArenaNames() {
  std::vector<std::string> names;
  for (const BuiltinArena& arena : kBuiltinArenas) names.emplace_back(arena.name);
  return names;
}

std::vector<std::string> BuiltinWorldNames() {
  std::vector<std::string> names = BuiltinArenaNames();
  for (const WorldFile& file : BuiltinWorldFiles()) names.emplace_back(file.name);
  return names;
}

std::string BuiltinWorldList() {
  std::string list;
  for (const std::string& name : BuiltinWorldNames()) list += (list.empty() ? "" : ", ") + name;
  return list;
}

std::optional<World> BuiltinWorld(std::string_view name) {
  for (const BuiltinArena& arena : kBuiltinArenas) {
    if (arena.name == name) return arena.make();
  }
  for (const WorldFile& file : BuiltinWorldFiles()) {
    if (file.name != name) continue;
    // The files are parsed when used; a test parses every one of them.
    Result<World> world = ParseWorld(file.json, "sim/worlds/" + std::string(name) + ".json");
    if (!world.ok()) return std::nullopt;
    return std::move(world).value();
  }
  return std::nullopt;
}

Result<World> ResolveWorld(const std::string& name_or_path) {
  if (std::optional<World> world = BuiltinWorld(name_or_path)) return std::move(*world);
  // A name that is no file either is most likely a mistyped or hoped-for built-in world: the
  // error lists them rather than only "cannot open".
  std::error_code ec;
  if (!std::filesystem::exists(std::filesystem::symlink_status(name_or_path, ec))) {
    return Error("'" + name_or_path + "' is neither a built-in world (" + BuiltinWorldList() +
                 ") nor a world.json file (" + (ec ? ec.message() : std::strerror(ENOENT)) + ")");
  }
  return LoadWorld(name_or_path);
}

}  // namespace slam::sim
