#include "server/foxglove_messages.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>

#include "engine/cell_encoding.hpp"
#include "engine/grid_geometry.hpp"
#include "engine/occupancy_grid.hpp"

namespace slam::server::foxglove {

using json = nlohmann::json;

namespace {

// The JSON schemas of the Foxglove message types slamd sends, written after the published
// definitions of foxglove.Grid, foxglove.PoseInFrame, ... (the fields and their types; the
// tests validate every message against the official schemas of npm's @foxglove/schemas).

json Number() { return {{"type", "number"}}; }
json Text() { return {{"type", "string"}}; }
json Count() { return {{"type", "integer"}, {"minimum", 0}}; }
json Bytes() { return {{"type", "string"}, {"contentEncoding", "base64"}}; }

json Object(const std::string& title, json properties) {
  json required = json::array();
  for (const auto& [key, value] : properties.items()) required.push_back(key);
  return {{"title", title},
          {"type", "object"},
          {"properties", std::move(properties)},
          {"required", std::move(required)}};
}

json TimeSchema() {
  return Object("time", {{"sec", Count()},
                         {"nsec", {{"type", "integer"}, {"minimum", 0}, {"maximum", 999999999}}}});
}
json Vector2Schema() { return Object("foxglove.Vector2", {{"x", Number()}, {"y", Number()}}); }
json Vector3Schema() {
  return Object("foxglove.Vector3", {{"x", Number()}, {"y", Number()}, {"z", Number()}});
}
json QuaternionSchema() {
  return Object("foxglove.Quaternion",
                {{"x", Number()}, {"y", Number()}, {"z", Number()}, {"w", Number()}});
}
json PoseSchema() {
  return Object("foxglove.Pose",
                {{"position", Vector3Schema()}, {"orientation", QuaternionSchema()}});
}
json FieldsSchema() {
  json types = json::array();
  const std::array<const char*, 9> names = {"UNKNOWN", "UINT8", "INT8",    "UINT16", "INT16",
                                            "UINT32",  "INT32", "FLOAT32", "FLOAT64"};
  for (size_t i = 0; i < names.size(); ++i) types.push_back({{"title", names[i]}, {"const", i}});
  json field = Object("foxglove.PackedElementField",
                      {{"name", Text()},
                       {"offset", Count()},
                       {"type", {{"title", "foxglove.NumericType"}, {"oneOf", types}}}});
  return {{"type", "array"}, {"items", std::move(field)}};
}

json GridSchema() {
  return Object("foxglove.Grid", {{"timestamp", TimeSchema()},
                                  {"frame_id", Text()},
                                  {"pose", PoseSchema()},
                                  {"column_count", Count()},
                                  {"cell_size", Vector2Schema()},
                                  {"row_stride", Count()},
                                  {"cell_stride", Count()},
                                  {"fields", FieldsSchema()},
                                  {"data", Bytes()}});
}
json PoseInFrameSchema() {
  return Object("foxglove.PoseInFrame",
                {{"timestamp", TimeSchema()}, {"frame_id", Text()}, {"pose", PoseSchema()}});
}
json PosesInFrameSchema() {
  return Object("foxglove.PosesInFrame", {{"timestamp", TimeSchema()},
                                          {"frame_id", Text()},
                                          {"poses", {{"type", "array"}, {"items", PoseSchema()}}}});
}
json FrameTransformSchema() {
  return Object("foxglove.FrameTransform", {{"timestamp", TimeSchema()},
                                            {"parent_frame_id", Text()},
                                            {"child_frame_id", Text()},
                                            {"translation", Vector3Schema()},
                                            {"rotation", QuaternionSchema()}});
}
json PointCloudSchema() {
  return Object("foxglove.PointCloud", {{"timestamp", TimeSchema()},
                                        {"frame_id", Text()},
                                        {"pose", PoseSchema()},
                                        {"point_stride", Count()},
                                        {"fields", FieldsSchema()},
                                        {"data", Bytes()}});
}

constexpr int kInt8 = 2;
constexpr int kFloat32 = 7;

/// The occupancy of a cell, ROS style: -1 unknown, else 0..100.
int8_t Occupancy(LogOdds value) {
  if (value == 0) return -1;
  return static_cast<int8_t>(std::lround(100.0 * OccupancyProbability(value)));
}

void AppendLittleEndian(std::string& out, uint64_t value, int bytes) {
  for (int i = 0; i < bytes; ++i) out.push_back(static_cast<char>((value >> (8 * i)) & 0xff));
}

}  // namespace

std::vector<ChannelSpec> Channels(bool simulated) {
  std::vector<ChannelSpec> channels = {
      {Channel::kMap, "/map", "foxglove.Grid", GridSchema()},
      {Channel::kPose, "/pose", "foxglove.PoseInFrame", PoseInFrameSchema()},
      {Channel::kTrajectory, "/trajectory", "foxglove.PosesInFrame", PosesInFrameSchema()},
      {Channel::kTransform, "/tf", "foxglove.FrameTransform", FrameTransformSchema()},
      {Channel::kScan, "/scan", "foxglove.PointCloud", PointCloudSchema()},
  };
  if (simulated) {
    channels.push_back(
        {Channel::kGroundTruth, "/ground_truth", "foxglove.PoseInFrame", PoseInFrameSchema()});
  }
  return channels;
}

json Advertise(const std::vector<ChannelSpec>& channels) {
  json list = json::array();
  for (const ChannelSpec& c : channels) {
    list.push_back({{"id", static_cast<uint32_t>(c.id)},
                    {"topic", c.topic},
                    {"encoding", "json"},
                    {"schemaName", c.schema_name},
                    {"schema", c.schema.dump()},
                    {"schemaEncoding", "jsonschema"}});
  }
  return {{"op", "advertise"}, {"channels", std::move(list)}};
}

json Time(double t_s) {
  if (!(t_s > 0.0)) return {{"sec", 0}, {"nsec", 0}};
  const double whole = std::floor(t_s);
  auto sec = static_cast<int64_t>(std::min(whole, 4294967295.0));
  auto nsec = static_cast<int64_t>(std::lround((t_s - whole) * 1e9));
  if (nsec >= 1000000000) {
    ++sec;
    nsec -= 1000000000;
  }
  return {{"sec", sec}, {"nsec", nsec}};
}

json Pose(const Pose2& pose) {
  return {
      {"position", {{"x", pose.x}, {"y", pose.y}, {"z", 0.0}}},
      {"orientation",
       {{"x", 0.0}, {"y", 0.0}, {"z", std::sin(pose.theta / 2)}, {"w", std::cos(pose.theta / 2)}}}};
}

json Grid(const SlamSnapshot& snapshot, size_t max_cells, double t_s) {
  const double resolution = snapshot.resolution_m;
  // The cells covered by the tiles.
  int64_t x0 = std::numeric_limits<int64_t>::max(), y0 = x0;
  int64_t x1 = std::numeric_limits<int64_t>::min(), y1 = x1;
  for (const TileRef& ref : snapshot.tiles) {
    x0 = std::min<int64_t>(x0, int64_t{ref.index.x} * kTileSize);
    y0 = std::min<int64_t>(y0, int64_t{ref.index.y} * kTileSize);
    x1 = std::max<int64_t>(x1, (int64_t{ref.index.x} + 1) * kTileSize);
    y1 = std::max<int64_t>(y1, (int64_t{ref.index.y} + 1) * kTileSize);
  }
  if (snapshot.tiles.empty()) x0 = y0 = 0, x1 = y1 = 1;
  const int64_t width = x1 - x0, height = y1 - y0;
  // Blocks of `merge` x `merge` cells, as few as keep the grid within max_cells.
  int64_t merge = 1;
  while (((width + merge - 1) / merge) * ((height + merge - 1) / merge) >
         static_cast<int64_t>(std::max<size_t>(1, max_cells))) {
    ++merge;
  }
  const int64_t columns = (width + merge - 1) / merge, rows = (height + merge - 1) / merge;
  std::string cells(static_cast<size_t>(columns * rows), static_cast<char>(-1));
  for (const TileRef& ref : snapshot.tiles) {
    const int64_t tx = int64_t{ref.index.x} * kTileSize - x0;
    const int64_t ty = int64_t{ref.index.y} * kTileSize - y0;
    for (int y = 0; y < kTileSize; ++y) {
      for (int x = 0; x < kTileSize; ++x) {
        const int8_t value = Occupancy(ref.tile->cells[static_cast<size_t>(y * kTileSize + x)]);
        if (value < 0) continue;
        char& cell = cells[static_cast<size_t>(((ty + y) / merge) * columns + (tx + x) / merge)];
        cell = static_cast<char>(std::max<int>(static_cast<int8_t>(cell), value));
      }
    }
  }
  const double cell_size = resolution * static_cast<double>(merge);
  return {{"timestamp", Time(t_s)},
          {"frame_id", kMapFrame},
          {"pose",
           Pose({static_cast<double>(x0) * resolution, static_cast<double>(y0) * resolution, 0.0})},
          {"column_count", columns},
          {"cell_size", {{"x", cell_size}, {"y", cell_size}}},
          {"row_stride", columns},
          {"cell_stride", 1},
          {"fields", json::array({{{"name", "occupancy"}, {"offset", 0}, {"type", kInt8}}})},
          {"data", Base64(cells)}};
}

json PoseInFrame(const TimedPose& pose) {
  return {{"timestamp", Time(pose.t)}, {"frame_id", kMapFrame}, {"pose", Pose(pose.pose)}};
}

json PosesInFrame(const std::vector<TimedPose>& poses, size_t max_poses) {
  json list = json::array();
  const size_t n = poses.size();
  const size_t keep = std::min(n, std::max<size_t>(2, max_poses));
  for (size_t k = 0; k < keep; ++k) {
    // Evenly spread indices from 0 to n - 1, both ends included.
    const size_t i = keep == 1 ? 0 : k * (n - 1) / (keep - 1);
    list.push_back(Pose(poses[i].pose));
  }
  return {{"timestamp", Time(poses.empty() ? 0.0 : poses.back().t)},
          {"frame_id", kMapFrame},
          {"poses", std::move(list)}};
}

json FrameTransform(const TimedPose& pose) {
  const json p = Pose(pose.pose);
  return {{"timestamp", Time(pose.t)},
          {"parent_frame_id", kMapFrame},
          {"child_frame_id", kRobotFrame},
          {"translation", p["position"]},
          {"rotation", p["orientation"]}};
}

json PointCloud(const std::vector<Vec2>& points, double t_s) {
  std::string data;
  data.reserve(points.size() * 12);
  for (const Vec2& p : points) {
    for (const float v : {static_cast<float>(p.x()), static_cast<float>(p.y()), 0.0f}) {
      uint32_t bits = 0;
      std::memcpy(&bits, &v, sizeof bits);
      AppendLittleEndian(data, bits, 4);
    }
  }
  return {{"timestamp", Time(t_s)},
          {"frame_id", kRobotFrame},
          {"pose", Pose({0.0, 0.0, 0.0})},
          {"point_stride", 12},
          {"fields", json::array({{{"name", "x"}, {"offset", 0}, {"type", kFloat32}},
                                  {{"name", "y"}, {"offset", 4}, {"type", kFloat32}},
                                  {{"name", "z"}, {"offset", 8}, {"type", kFloat32}}})},
          {"data", Base64(data)}};
}

std::array<char, kMessageDataHeaderBytes> MessageDataHeader(uint32_t subscription,
                                                            uint64_t timestamp_ns) {
  std::string frame;
  frame.push_back(1);  // opcode: message data
  AppendLittleEndian(frame, subscription, 4);
  AppendLittleEndian(frame, timestamp_ns, 8);
  std::array<char, kMessageDataHeaderBytes> header{};
  std::copy(frame.begin(), frame.end(), header.begin());
  return header;
}

std::string MessageData(uint32_t subscription, uint64_t timestamp_ns, std::string_view payload) {
  const auto header = MessageDataHeader(subscription, timestamp_ns);
  std::string frame;
  frame.reserve(header.size() + payload.size());
  frame.append(header.data(), header.size());
  frame.append(payload);
  return frame;
}

namespace {

struct BudgetParameter {
  const char* name;  // the parameter
  const char* key;   // its member of the budget object
  bool integer;      // a whole number in the budget object
  bool number;       // sent as float64
};

constexpr std::array<BudgetParameter, 5> kBudgetParameters = {{
    {"budget.mode", "mode", false, false},
    {"budget.rays_per_scan", "rays_per_scan", true, true},
    {"budget.cpu_share", "cpu_share", false, true},
    {"budget.policy", "policy", false, false},
    {"budget.max_particles", "max_particles", true, true},
}};

}  // namespace

json BudgetParameters(const BudgetSettings& budget) {
  const json object = {{"mode", ToString(budget.mode)},
                       {"rays_per_scan", budget.rays_per_scan},
                       {"cpu_share", budget.cpu_share},
                       {"policy", ToString(budget.policy)},
                       {"max_particles", budget.max_particles}};
  json list = json::array();
  for (const BudgetParameter& p : kBudgetParameters) {
    json entry = {{"name", p.name}};
    if (p.number) {
      entry["value"] = object[p.key].get<double>();
      entry["type"] = "float64";
    } else {
      entry["value"] = object[p.key];
    }
    list.push_back(std::move(entry));
  }
  return list;
}

bool IsBudgetParameter(std::string_view name) {
  return std::any_of(kBudgetParameters.begin(), kBudgetParameters.end(),
                     [&](const BudgetParameter& p) { return name == p.name; });
}

Result<json> BudgetPatch(const json& parameters) {
  if (!parameters.is_array()) return ConfigErrors{{"/parameters", "must be an array", 0}};
  ConfigErrors errors;
  json patch = json::object();
  for (const json& entry : parameters) {
    if (!entry.is_object() || !entry.contains("name") || !entry["name"].is_string()) {
      errors.push_back({"/parameters", "each parameter must be an object with a name", 0});
      continue;
    }
    const std::string name = entry["name"].get<std::string>();
    const auto* p = std::find_if(kBudgetParameters.begin(), kBudgetParameters.end(),
                                 [&](const BudgetParameter& b) { return name == b.name; });
    if (p == kBudgetParameters.end()) {
      errors.push_back({"/" + name,
                        "no such parameter (slamd has budget.mode, "
                        "budget.rays_per_scan, budget.cpu_share, budget.policy and "
                        "budget.max_particles)",
                        0});
      continue;
    }
    json value = entry.contains("value") ? entry["value"] : json();  // none: the default
    if (p->integer && value.is_number_float()) {
      const double v = value.get<double>();
      // A whole float64 within the budget's integer range stands for that integer.
      if (std::isfinite(v) && v == std::floor(v) && std::abs(v) < 9.0e15) {
        value = static_cast<int64_t>(v);
      }
    }
    patch[p->key] = std::move(value);
  }
  if (!errors.empty()) return errors;
  return patch;
}

namespace {

constexpr std::array<std::string_view, 3> kPoseEstimateSchemas = {
    "geometry_msgs/PoseWithCovarianceStamped", "geometry_msgs/msg/PoseWithCovarianceStamped",
    "foxglove.PoseInFrame"};

}  // namespace

bool IsPoseEstimateSchema(std::string_view schema_name) {
  return std::find(kPoseEstimateSchemas.begin(), kPoseEstimateSchemas.end(), schema_name) !=
         kPoseEstimateSchemas.end();
}

Result<PoseRequest> PoseEstimate(std::string_view schema_name, const json& message,
                                 double resolution_m) {
  if (!IsPoseEstimateSchema(schema_name)) {
    return ConfigErrors{{"", "not a pose estimate (" + std::string(schema_name) + ")", 0}};
  }
  if (!message.is_object()) return ConfigErrors{{"", "must be a JSON object", 0}};
  const bool with_covariance = schema_name != "foxglove.PoseInFrame";
  ConfigErrors errors;
  // The member at a JSON pointer, or null (an error added) when it is missing or not of the
  // kind wanted.
  const auto at = [&](const std::string& pointer, bool number) -> const json* {
    const json::json_pointer where(pointer);
    if (!message.contains(where)) {
      errors.push_back({pointer, "required", 0});
      return nullptr;
    }
    const json& value = message.at(where);
    if (number ? !value.is_number() : !value.is_string()) {
      errors.push_back({pointer, number ? "must be a number" : "must be a string", 0});
      return nullptr;
    }
    return &value;
  };
  const std::string frame_at = with_covariance ? "/header/frame_id" : "/frame_id";
  if (message.contains(json::json_pointer(frame_at))) {
    if (const json* frame = at(frame_at, false)) {
      const auto name = frame->get<std::string>();
      if (!name.empty() && name != kMapFrame) {
        errors.push_back(
            {frame_at,
             "must be \"" + std::string(kMapFrame) + "\" (slamd's map frame), not \"" + name + "\"",
             0});
      }
    }
  }
  const std::string pose_at = with_covariance ? "/pose/pose" : "/pose";
  std::array<double, 6> v{};  // x, y, then the quaternion's x, y, z, w
  const std::array<const char*, 6> names = {"/position/x",    "/position/y",    "/orientation/x",
                                            "/orientation/y", "/orientation/z", "/orientation/w"};
  for (size_t i = 0; i < names.size(); ++i) {
    if (const json* value = at(pose_at + names[i], true)) v[i] = value->get<double>();
  }
  if (!errors.empty()) return errors;
  const double qx = v[2], qy = v[3], qz = v[4], qw = v[5];
  const double norm = std::sqrt(qx * qx + qy * qy + qz * qz + qw * qw);
  if (!std::isfinite(norm) || norm < 1e-6) {
    return ConfigErrors{{pose_at + "/orientation", "must be a finite, non-zero quaternion", 0}};
  }
  // A rotation about z alone has x = y = 0; a robot on the floor is not tilted by degrees.
  if (std::hypot(qx, qy) / norm > std::sin(DegToRad(5.0) / 2.0)) {
    return ConfigErrors{
        {pose_at + "/orientation", "must be a rotation about z (the robot is on the floor)", 0}};
  }
  PoseRequest request;
  const double yaw = std::atan2(2.0 * (qw * qz + qx * qy), qw * qw + qx * qx - qy * qy - qz * qz);
  request.pose = Pose2{v[0], v[1], NormalizeAngle(yaw)};
  if (with_covariance && message.contains(json::json_pointer("/pose/covariance"))) {
    const json& covariance = message.at(json::json_pointer("/pose/covariance"));
    if (!covariance.is_array() || covariance.size() != 36 ||
        !std::all_of(covariance.begin(), covariance.end(),
                     [](const json& c) { return c.is_number(); })) {
      return ConfigErrors{{"/pose/covariance", "must be an array of 36 numbers", 0}};
    }
    // Row-major 6 x 6 over x, y, z and the rotations about x, y, z.
    const double var_x = covariance[0].get<double>(), var_y = covariance[7].get<double>(),
                 var_yaw = covariance[35].get<double>();
    if (!(std::isfinite(var_x) && var_x >= 0.0 && std::isfinite(var_y) && var_y >= 0.0 &&
          std::isfinite(var_yaw) && var_yaw >= 0.0)) {
      return ConfigErrors{
          {"/pose/covariance", "the variances of x, y and yaw must be finite and not negative", 0}};
    }
    const double sigma_m = std::sqrt(std::max(var_x, var_y));
    const double sigma_deg = RadToDeg(std::sqrt(var_yaw));
    if (sigma_m > 0.0) request.sigma_m = std::min(sigma_m, 50.0);
    if (sigma_deg > 0.0) request.sigma_deg = std::min(sigma_deg, 180.0);
  }
  ConfigErrors invalid = ValidatePoseRequest(request, resolution_m);
  if (!invalid.empty()) {
    for (ConfigError& e : invalid) {  // named as the message has them
      if (e.pointer == "/x") e.pointer = pose_at + "/position/x";
      if (e.pointer == "/y") e.pointer = pose_at + "/position/y";
      if (e.pointer == "/theta_deg") e.pointer = pose_at + "/orientation";
      if (e.pointer == "/sigma_m" || e.pointer == "/sigma_deg") e.pointer = "/pose/covariance";
    }
    return invalid;
  }
  return request;
}

std::string Base64(std::string_view bytes) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 3 <= bytes.size(); i += 3) {
    const uint32_t v = (uint32_t{static_cast<uint8_t>(bytes[i])} << 16) |
                       (uint32_t{static_cast<uint8_t>(bytes[i + 1])} << 8) |
                       uint32_t{static_cast<uint8_t>(bytes[i + 2])};
    for (int shift = 18; shift >= 0; shift -= 6) out.push_back(kAlphabet[(v >> shift) & 63]);
  }
  const size_t rest = bytes.size() - i;
  if (rest > 0) {
    uint32_t v = uint32_t{static_cast<uint8_t>(bytes[i])} << 16;
    if (rest == 2) v |= uint32_t{static_cast<uint8_t>(bytes[i + 1])} << 8;
    out.push_back(kAlphabet[(v >> 18) & 63]);
    out.push_back(kAlphabet[(v >> 12) & 63]);
    out.push_back(rest == 2 ? kAlphabet[(v >> 6) & 63] : '=');
    out.push_back('=');
  }
  return out;
}

}  // namespace slam::server::foxglove
