// The Foxglove protocol's messages as slamd builds them (server/foxglove_messages.hpp): base64,
// the binary message-data frame, times, the map as a foxglove.Grid (cells, origin, merging of
// large maps), poses, the trajectory's thinning, the budget as parameters and back, client
// pose estimates (clientPublish) read and passed on. The official
// client and schemas check the same messages end to end (tests/foxglove/).

#include "server/foxglove_messages.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <memory>

#include "engine/cell_encoding.hpp"
#include "engine/occupancy_grid.hpp"
#include "server/api_json.hpp"
#include "server/foxglove_protocol.hpp"

namespace slam::server::foxglove {
namespace {

using json = nlohmann::json;

std::string Decode64(const std::string& text) {
  std::string out;
  int bits = 0, value = 0;
  for (const char c : text) {
    if (c == '=') break;
    const std::string alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    value = (value << 6) | static_cast<int>(alphabet.find(c));
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out.push_back(static_cast<char>((value >> bits) & 0xff));
    }
  }
  return out;
}

TEST(FoxgloveMessagesTest, Base64MatchesRfc4648Vectors) {
  EXPECT_EQ(Base64(""), "");
  EXPECT_EQ(Base64("f"), "Zg==");
  EXPECT_EQ(Base64("fo"), "Zm8=");
  EXPECT_EQ(Base64("foo"), "Zm9v");
  EXPECT_EQ(Base64("foob"), "Zm9vYg==");
  EXPECT_EQ(Base64("fooba"), "Zm9vYmE=");
  EXPECT_EQ(Base64("foobar"), "Zm9vYmFy");
  const std::string bytes = {'\0', '\xff', '\x80', '\x7f', '\x01'};
  EXPECT_EQ(Base64(bytes), "AP+AfwE=");
}

TEST(FoxgloveMessagesTest, MessageDataFrameIsOpcodeSubscriptionTimestampPayload) {
  const std::string frame = MessageData(0x04030201u, 0x0c0b0a0908070605ull, "{}");
  ASSERT_EQ(frame.size(), 1u + 4u + 8u + 2u);
  const std::string expected = {'\x01', '\x01', '\x02', '\x03', '\x04', '\x05', '\x06', '\x07',
                                '\x08', '\x09', '\x0a', '\x0b', '\x0c', '{',    '}'};
  EXPECT_EQ(frame, expected);
}

TEST(FoxgloveMessagesTest, TimeSplitsSecondsAndClampsAtZero) {
  EXPECT_EQ(Time(1.5), (json{{"sec", 1}, {"nsec", 500000000}}));
  EXPECT_EQ(Time(-3.0), (json{{"sec", 0}, {"nsec", 0}}));
  EXPECT_EQ(Time(std::nan("")), (json{{"sec", 0}, {"nsec", 0}}));
  EXPECT_EQ(Time(2.9999999999), (json{{"sec", 3}, {"nsec", 0}}));  // rounding carries
}

TEST(FoxgloveMessagesTest, PoseIsARotationAboutZ) {
  const json p = Pose({1.0, -2.0, kPi / 2});
  EXPECT_DOUBLE_EQ(p["position"]["x"].get<double>(), 1.0);
  EXPECT_DOUBLE_EQ(p["position"]["y"].get<double>(), -2.0);
  EXPECT_DOUBLE_EQ(p["orientation"]["z"].get<double>(), std::sqrt(0.5));
  EXPECT_DOUBLE_EQ(p["orientation"]["w"].get<double>(), std::sqrt(0.5));
  const json tf = FrameTransform({4.0, {1.0, 2.0, 0.0}});
  EXPECT_EQ(tf["parent_frame_id"], "map");
  EXPECT_EQ(tf["child_frame_id"], "base_link");
  EXPECT_EQ(tf["translation"], (json{{"x", 1.0}, {"y", 2.0}, {"z", 0.0}}));
}

/// A snapshot with one tile at `index`: the cell (x, y) of the tile holds `value`.
SlamSnapshot OneTile(TileIndex index, std::vector<std::tuple<int, int, LogOdds>> cells) {
  auto tile = std::make_shared<Tile>();
  for (const auto& [x, y, value] : cells) {
    tile->cells[static_cast<size_t>(y * kTileSize + x)] = value;
  }
  SlamSnapshot s;
  s.resolution_m = 0.05;
  s.tiles.push_back({index, tile});
  return s;
}

TEST(FoxgloveMessagesTest, GridHoldsTheCellsAtTheTilesCorner) {
  const SlamSnapshot s = OneTile(
      {1, -1},
      {{0, 0, EncodeLogOdds(3.0)}, {5, 2, EncodeLogOdds(-3.0)}, {63, 63, EncodeLogOdds(0.5)}});
  const json grid = Grid(s, 1 << 20, 2.0);
  EXPECT_EQ(grid["frame_id"], "map");
  EXPECT_EQ(grid["column_count"], kTileSize);
  EXPECT_EQ(grid["row_stride"], kTileSize);
  EXPECT_EQ(grid["cell_stride"], 1);
  EXPECT_DOUBLE_EQ(grid["cell_size"]["x"].get<double>(), 0.05);
  EXPECT_DOUBLE_EQ(grid["pose"]["position"]["x"].get<double>(), kTileSize * 0.05);
  EXPECT_DOUBLE_EQ(grid["pose"]["position"]["y"].get<double>(), -kTileSize * 0.05);
  EXPECT_EQ(grid["fields"][0]["type"], 2);  // INT8
  const std::string data = Decode64(grid["data"].get<std::string>());
  ASSERT_EQ(data.size(), static_cast<size_t>(kTileSize * kTileSize));
  const auto at = [&](int x, int y) {
    return static_cast<int8_t>(data[static_cast<size_t>(y * kTileSize + x)]);
  };
  EXPECT_EQ(at(0, 0), 95);    // p = 1 / (1 + e^-3)
  EXPECT_EQ(at(5, 2), 5);     // p = 1 / (1 + e^3)
  EXPECT_EQ(at(63, 63), 62);  // p = 1 / (1 + e^-0.5)
  EXPECT_EQ(at(1, 0), -1);    // never seen
  EXPECT_EQ(grid["timestamp"], Time(2.0));
}

TEST(FoxgloveMessagesTest, LargeGridsMergeBlocksKeepingTheMostOccupiedKnownCell) {
  const SlamSnapshot s = OneTile(
      {0, 0},
      {{0, 0, EncodeLogOdds(-3.0)}, {1, 1, EncodeLogOdds(3.0)}, {2, 0, EncodeLogOdds(-3.0)}});
  const json grid = Grid(s, kTileSize * kTileSize / 4, 0.0);  // room for a quarter: 2 x 2 blocks
  EXPECT_EQ(grid["column_count"], kTileSize / 2);
  EXPECT_DOUBLE_EQ(grid["cell_size"]["x"].get<double>(), 0.1);
  const std::string data = Decode64(grid["data"].get<std::string>());
  ASSERT_EQ(data.size(), static_cast<size_t>(kTileSize * kTileSize / 4));
  EXPECT_EQ(static_cast<int8_t>(data[0]), 95);  // free and occupied: occupied
  EXPECT_EQ(static_cast<int8_t>(data[1]), 5);   // free only
  EXPECT_EQ(static_cast<int8_t>(data[2]), -1);  // nothing known
}

TEST(FoxgloveMessagesTest, AnEmptyMapIsOneUnknownCell) {
  const json grid = Grid(SlamSnapshot{}, 1 << 20, 0.0);
  EXPECT_EQ(grid["column_count"], 1);
  EXPECT_EQ(Decode64(grid["data"].get<std::string>()), std::string(1, '\xff'));
}

TEST(FoxgloveMessagesTest, TrajectoryIsThinnedEvenlyKeepingBothEnds) {
  std::vector<TimedPose> poses;
  for (int i = 0; i < 10; ++i) poses.push_back({i * 1.0, {i * 1.0, 0.0, 0.0}});
  const json message = PosesInFrame(poses, 4);
  ASSERT_EQ(message["poses"].size(), 4u);
  for (const auto& [k, x] :
       std::vector<std::pair<size_t, double>>{{0, 0}, {1, 3}, {2, 6}, {3, 9}}) {
    EXPECT_DOUBLE_EQ(message["poses"][k]["position"]["x"].get<double>(), x);
  }
  EXPECT_EQ(message["timestamp"], Time(9.0));
  EXPECT_EQ(PosesInFrame(poses, 100)["poses"].size(), 10u);
}

TEST(FoxgloveMessagesTest, ScanPointsArePackedFloat32) {
  const json cloud = PointCloud({Vec2(1.0, -0.5), Vec2(0.25, 2.0)}, 1.0);
  EXPECT_EQ(cloud["frame_id"], "base_link");
  EXPECT_EQ(cloud["point_stride"], 12);
  const std::string data = Decode64(cloud["data"].get<std::string>());
  ASSERT_EQ(data.size(), 24u);
  float values[6];
  std::memcpy(values, data.data(), sizeof values);
  EXPECT_EQ(values[0], 1.0f);
  EXPECT_EQ(values[1], -0.5f);
  EXPECT_EQ(values[2], 0.0f);
  EXPECT_EQ(values[3], 0.25f);
  EXPECT_EQ(values[4], 2.0f);
}

TEST(FoxgloveMessagesTest, ChannelsCarryTheOfficialSchemaNames) {
  const auto channels = Channels(false);
  ASSERT_EQ(channels.size(), 5u);
  EXPECT_EQ(channels[0].topic, "/map");
  EXPECT_EQ(channels[0].schema_name, "foxglove.Grid");
  EXPECT_EQ(channels[4].schema_name, "foxglove.PointCloud");
  const auto simulated = Channels(true);
  ASSERT_EQ(simulated.size(), 6u);
  EXPECT_EQ(simulated.back().topic, "/ground_truth");
  const json advertise = Advertise(simulated);
  EXPECT_EQ(advertise["op"], "advertise");
  for (const json& c : advertise["channels"]) {
    EXPECT_EQ(c["encoding"], "json");
    EXPECT_EQ(c["schemaEncoding"], "jsonschema");
    const json schema = json::parse(c["schema"].get<std::string>());
    EXPECT_EQ(schema["title"], c["schemaName"]);
  }
}

TEST(FoxgloveMessagesTest, BudgetParametersAreTheBudgetWithNumbersAsFloat64) {
  BudgetSettings b;
  b.rays_per_scan = 16250;
  b.policy = BudgetPolicy::kAdaptive;
  const json p = BudgetParameters(b);
  ASSERT_EQ(p.size(), 5u);
  EXPECT_EQ(p[0], (json{{"name", "budget.mode"}, {"value", "rays"}}));
  EXPECT_EQ(p[1],
            (json{{"name", "budget.rays_per_scan"}, {"value", 16250.0}, {"type", "float64"}}));
  EXPECT_EQ(p[3], (json{{"name", "budget.policy"}, {"value", "adaptive"}}));
  EXPECT_TRUE(IsBudgetParameter("budget.max_particles"));
  EXPECT_FALSE(IsBudgetParameter("budget"));
}

TEST(FoxgloveMessagesTest, SetParametersBecomeAMergePatchOfTheBudget) {
  const Result<json> patch = BudgetPatch(json::parse(R"([
      {"name": "budget.rays_per_scan", "value": 32500.0, "type": "float64"},
      {"name": "budget.cpu_share", "value": 0.5},
      {"name": "budget.max_particles"}])"));
  ASSERT_TRUE(patch.ok()) << patch.Message();
  EXPECT_EQ(patch.value(), json::parse(R"({"rays_per_scan": 32500, "cpu_share": 0.5,
                                           "max_particles": null})"));
  EXPECT_TRUE(patch.value()["rays_per_scan"].is_number_integer());
  // A fractional value stays fractional: the budget's validation refuses it.
  EXPECT_TRUE(BudgetPatch(json::parse(R"([{"name": "budget.rays_per_scan", "value": 1000.5}])"))
                  .value()["rays_per_scan"]
                  .is_number_float());
  const Result<json> unknown =
      BudgetPatch(json::parse(R"([{"name": "budget.speed", "value": 1}])"));
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.errors()[0].pointer, "/budget.speed");
  EXPECT_FALSE(BudgetPatch(json::parse(R"({"name": "budget.mode"})")).ok());
  EXPECT_FALSE(BudgetPatch(json::parse(R"([{"value": 3}])")).ok());
}

/// A client over a budget held here, changed as the REST route changes it.
struct Budgeted {
  BudgetSettings budget;
  int patches = 0;
  BudgetAccess Access() {
    return {[this] { return budget; },
            [this](const json& patch) {
              ++patches;
              Result<BudgetSettings> merged = MergeBudget(budget, patch);
              if (merged.ok()) budget = merged.value();
              return merged;
            }};
  }
};

TEST(FoxgloveProtocolTest, SubscriptionsAreReportedCheckedAndCapped) {
  Budgeted b;
  ClientProtocol client(Channels(false), true, b.Access());
  Effects e = client.OnText(R"({"op": "subscribe", "subscriptions": [
      {"id": 7, "channelId": 1}, {"id": 8, "channelId": 6}, {"id": 7, "channelId": 2}]})");
  EXPECT_EQ(e.subscribed, std::vector<uint32_t>{7});  // no channel 6 unsimulated; 7 in use
  EXPECT_TRUE(e.refused);
  ASSERT_EQ(e.replies.size(), 2u);
  EXPECT_EQ(e.replies[0]["message"], "no channel 6");
  EXPECT_EQ(client.subscriptions().at(7), Channel::kMap);
  e = client.OnText(R"({"op": "unsubscribe", "subscriptionIds": [7, 9]})");
  EXPECT_EQ(e.unsubscribed, std::vector<uint32_t>{7});
  EXPECT_TRUE(client.subscriptions().empty());
  // A client cannot subscribe without end.
  json many = json::array();
  for (uint32_t id = 0; id < 100; ++id) many.push_back({{"id", id}, {"channelId", 2}});
  e = client.OnText(json{{"op", "subscribe"}, {"subscriptions", many}}.dump());
  EXPECT_EQ(e.subscribed.size(), kMaxSubscriptions);
  EXPECT_EQ(client.subscriptions().size(), kMaxSubscriptions);
  EXPECT_TRUE(e.refused);
}

TEST(FoxgloveProtocolTest, BadMessagesAreRefusedWithAStatusAndChangeNothing) {
  Budgeted b;
  ClientProtocol client(Channels(true), true, b.Access());
  for (const char* text :
       {"not json", "[]", R"({"op": 3})", R"({"op": "subscribe"})",
        R"({"op": "subscribe", "subscriptions": 5})",
        R"({"op": "subscribe", "subscriptions": [1]})", R"({"op": "advertise", "channels": []})",
        R"({"op": "getParameters", "parameterNames": 1})",
        R"({"op": "setParameters", "parameters": {"name": "budget.mode"}})",
        "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]"}) {
    const Effects e = client.OnText(text);
    EXPECT_TRUE(e.refused) << text;
    ASSERT_EQ(e.replies.size(), 1u) << text;
    EXPECT_EQ(e.replies[0]["op"], "status") << text;
    EXPECT_EQ(e.replies[0]["level"], kError) << text;
  }
  EXPECT_TRUE(client.OnBinary("").refused);
  EXPECT_TRUE(client.subscriptions().empty());
  EXPECT_EQ(b.budget, BudgetSettings{});
}

TEST(FoxgloveProtocolTest, ParametersReadSetAndFollowed) {
  Budgeted b;
  ClientProtocol client(Channels(false), true, b.Access());
  Effects e = client.OnText(
      R"({"op": "getParameters", "parameterNames": ["budget.policy", "x"], "id": "g"})");
  ASSERT_EQ(e.replies.size(), 1u);
  EXPECT_EQ(e.replies[0], json::parse(R"({"op": "parameterValues", "id": "g",
      "parameters": [{"name": "budget.policy", "value": "fixed"}]})"));
  e = client.OnText(R"({"op": "setParameters", "id": "s", "parameters": [
      {"name": "budget.rays_per_scan", "value": 8125.0, "type": "float64"}]})");
  EXPECT_TRUE(e.budget_changed);
  EXPECT_EQ(b.budget.rays_per_scan, 8125);
  ASSERT_EQ(e.replies.size(), 1u);
  EXPECT_EQ(e.replies[0]["id"], "s");
  EXPECT_EQ(e.replies[0]["parameters"][0]["value"], 8125.0);
  e = client.OnText(R"({"op": "setParameters", "parameters": [
      {"name": "budget.rays_per_scan", "value": 0}]})");
  EXPECT_FALSE(e.budget_changed);
  EXPECT_EQ(b.budget.rays_per_scan, 8125);
  EXPECT_EQ(e.replies[0]["message"],
            "the budget was not changed: budget.rays_per_scan: 0 is outside [1, 100000000]");
  client.OnText(R"({"op": "subscribeParameterUpdates", "parameterNames":
      ["budget.mode", "budget.speed"]})");
  EXPECT_EQ(client.parameter_updates(), std::set<std::string>{"budget.mode"});
}

TEST(FoxgloveProtocolTest, AClientThatMayNotWriteNeverReachesTheBudget) {
  Budgeted b;
  ClientProtocol client(Channels(false), false, b.Access());
  const Effects e = client.OnText(R"({"op": "setParameters", "parameters": [
      {"name": "budget.rays_per_scan", "value": 8125}]})");
  EXPECT_TRUE(e.refused);
  EXPECT_EQ(b.patches, 0);
  EXPECT_EQ(b.budget.rays_per_scan, 65000);
}

/// Foxglove's 3D panel's pose estimate at (x, y), heading yaw, with the deviations given.
json PoseEstimateMessage(double x, double y, double yaw, double sigma_xy, double sigma_yaw,
                         const std::string& frame = "map") {
  json covariance = json::array();
  for (int i = 0; i < 36; ++i) covariance.push_back(0.0);
  covariance[0] = covariance[7] = sigma_xy * sigma_xy;
  covariance[35] = sigma_yaw * sigma_yaw;
  return {{"header", {{"stamp", {{"sec", 12}, {"nsec", 0}}}, {"frame_id", frame}}},
          {"pose",
           {{"pose",
             {{"position", {{"x", x}, {"y", y}, {"z", 0.0}}},
              {"orientation",
               {{"x", 0.0}, {"y", 0.0}, {"z", std::sin(yaw / 2)}, {"w", std::cos(yaw / 2)}}}}},
            {"covariance", covariance}}}};
}

constexpr const char* kPoseWithCovariance = "geometry_msgs/PoseWithCovarianceStamped";

TEST(FoxglovePoseEstimateTest, APoseWithCovarianceIsAHintAZeroCovarianceAPose) {
  Result<PoseRequest> r =
      PoseEstimate(kPoseWithCovariance, PoseEstimateMessage(1.5, -2.0, 2.0, 0.0, 0.0), 0.05);
  ASSERT_TRUE(r.ok()) << r.Message();
  EXPECT_NEAR(r.value().pose.x, 1.5, 1e-12);
  EXPECT_NEAR(r.value().pose.y, -2.0, 1e-12);
  EXPECT_NEAR(r.value().pose.theta, 2.0, 1e-12);
  EXPECT_FALSE(r.value().sigma_m);
  EXPECT_FALSE(r.value().sigma_deg);
  // Foxglove's default deviations: 0.5 m in x and y, 15 degrees in yaw.
  r = PoseEstimate("geometry_msgs/msg/PoseWithCovarianceStamped",
                   PoseEstimateMessage(0.0, 0.0, -3.0, 0.5, DegToRad(15.0)), 0.05);
  ASSERT_TRUE(r.ok()) << r.Message();
  EXPECT_NEAR(r.value().pose.theta, -3.0, 1e-12);
  EXPECT_NEAR(*r.value().sigma_m, 0.5, 1e-12);
  EXPECT_NEAR(*r.value().sigma_deg, 15.0, 1e-9);
  // Deviations beyond what the pose route takes are clamped to it: "anywhere".
  r = PoseEstimate(kPoseWithCovariance, PoseEstimateMessage(0.0, 0.0, 0.0, 80.0, 10.0), 0.05);
  ASSERT_TRUE(r.ok()) << r.Message();
  EXPECT_EQ(*r.value().sigma_m, 50.0);
  EXPECT_EQ(*r.value().sigma_deg, 180.0);
  // A foxglove.PoseInFrame puts the robot there; no frame is the map frame.
  r = PoseEstimate("foxglove.PoseInFrame", json::parse(R"({"timestamp": {"sec": 1, "nsec": 0},
      "pose": {"position": {"x": 0.25, "y": 0.5, "z": 0},
               "orientation": {"x": 0, "y": 0, "z": 1, "w": 0}}})"),
                   0.05);
  ASSERT_TRUE(r.ok()) << r.Message();
  EXPECT_NEAR(std::abs(r.value().pose.theta), kPi, 1e-12);
  EXPECT_FALSE(r.value().sigma_m);
}

TEST(FoxglovePoseEstimateTest, WhatIsNotAPlanarPoseInTheMapFrameIsRefusedNamingWhere) {
  const auto error = [](const json& message, const char* schema = kPoseWithCovariance) {
    const Result<PoseRequest> r = PoseEstimate(schema, message, 0.05);
    return r.ok() ? std::string("accepted") : r.errors().front().pointer;
  };
  EXPECT_EQ(error(PoseEstimateMessage(0, 0, 0, 0, 0, "odom")), "/header/frame_id");
  json m = PoseEstimateMessage(0, 0, 0, 0, 0);
  m["pose"]["pose"]["orientation"] = {{"x", 0.3}, {"y", 0.0}, {"z", 0.0}, {"w", 0.95}};
  EXPECT_EQ(error(m), "/pose/pose/orientation");  // tilted by 35 degrees
  m["pose"]["pose"]["orientation"] = {{"x", 0.0}, {"y", 0.0}, {"z", 0.0}, {"w", 0.0}};
  EXPECT_EQ(error(m), "/pose/pose/orientation");
  m = PoseEstimateMessage(0, 0, 0, 0, 0);
  m["pose"]["pose"]["position"].erase("y");
  EXPECT_EQ(error(m), "/pose/pose/position/y");
  m = PoseEstimateMessage(0, 0, 0, 0, 0);
  m["pose"]["pose"]["position"]["x"] = "1";
  EXPECT_EQ(error(m), "/pose/pose/position/x");
  m = PoseEstimateMessage(0, 0, 0, 0.1, 0);
  m["pose"]["covariance"].erase(35);
  EXPECT_EQ(error(m), "/pose/covariance");
  m = PoseEstimateMessage(0, 0, 0, 0.1, 0);
  m["pose"]["covariance"][7] = -1.0;
  EXPECT_EQ(error(m), "/pose/covariance");
  EXPECT_EQ(error(PoseEstimateMessage(1e9, 0, 0, 0, 0)), "");  // beyond the map's bound
  EXPECT_EQ(error(json::array()), "");
  EXPECT_EQ(error(PoseEstimateMessage(0, 0, 0, 0, 0), "geometry_msgs/PoseStamped"), "");
  EXPECT_EQ(error(PoseEstimateMessage(0, 0, 0, 0, 0)), "accepted");
}

/// A client message data frame: opcode 1, the channel id (little-endian), the payload.
std::string ClientData(uint32_t channel, const std::string& payload) {
  std::string frame(1, '\x01');
  for (int i = 0; i < 4; ++i) frame.push_back(static_cast<char>((channel >> (8 * i)) & 0xff));
  return frame + payload;
}

std::string AdvertiseText(uint32_t id, const std::string& schema, const std::string& encoding) {
  return json{
      {"op", "advertise"},
      {"channels",
       {{{"id", id}, {"topic", "/initialpose"}, {"encoding", encoding}, {"schemaName", schema}}}}}
      .dump();
}

TEST(FoxgloveProtocolTest, PoseEstimatesOnAnAdvertisedChannelArePassedOn) {
  Budgeted b;
  std::vector<PoseRequest> requests;
  ClientProtocol client(Channels(false), true, b.Access(),
                        {0.05, [&](const PoseRequest& r) { requests.push_back(r); }});
  const std::string estimate = PoseEstimateMessage(1.0, 2.0, 0.5, 0.5, 0.2).dump();
  // Nothing advertised yet.
  Effects e = client.OnBinary(ClientData(3, estimate));
  EXPECT_TRUE(e.refused);
  EXPECT_EQ(e.replies.at(0)["message"],
            "message data on channel 3, which this client has not advertised");
  // Only pose estimates, JSON-encoded.
  e = client.OnText(AdvertiseText(3, "geometry_msgs/Twist", "json"));
  EXPECT_TRUE(e.refused);
  e = client.OnText(AdvertiseText(3, kPoseWithCovariance, "cdr"));
  EXPECT_TRUE(e.refused);
  EXPECT_TRUE(client.client_channels().empty());
  e = client.OnText(AdvertiseText(3, kPoseWithCovariance, "json"));
  EXPECT_FALSE(e.refused);
  EXPECT_TRUE(e.replies.empty());
  EXPECT_TRUE(client.OnText(AdvertiseText(3, kPoseWithCovariance, "json")).refused);  // in use

  e = client.OnBinary(ClientData(3, estimate));
  EXPECT_FALSE(e.refused);
  EXPECT_TRUE(e.pose_requested);
  ASSERT_EQ(requests.size(), 1u);
  EXPECT_NEAR(requests[0].pose.x, 1.0, 1e-12);
  EXPECT_NEAR(requests[0].pose.theta, 0.5, 1e-12);
  EXPECT_NEAR(*requests[0].sigma_m, 0.5, 1e-12);
  ASSERT_EQ(e.replies.size(), 1u);
  EXPECT_EQ(e.replies[0]["level"], kInfo);
  EXPECT_EQ(e.replies[0]["message"],
            "pose estimate taken: x 1.000 m, y 2.000 m, theta 28.6 deg (relocalising around it)");

  // Bad payloads and frames change nothing.
  for (const std::string& bad :
       {ClientData(3, "{"), ClientData(3, "[1]"), ClientData(3, ""), std::string("\x01\x03"),
        std::string("\x02\x03\x00\x00\x00{}"), ClientData(3, R"({"pose": 7})")}) {
    e = client.OnBinary(bad);
    EXPECT_TRUE(e.refused);
    EXPECT_FALSE(e.pose_requested);
    ASSERT_EQ(e.replies.size(), 1u);
    EXPECT_EQ(e.replies[0]["level"], kError);
  }
  EXPECT_EQ(requests.size(), 1u);

  client.OnText(R"({"op": "unadvertise", "channelIds": [3, 4]})");
  EXPECT_TRUE(client.OnBinary(ClientData(3, estimate)).refused);
  EXPECT_EQ(requests.size(), 1u);
  // A client cannot advertise without end.
  json many = json::array();
  for (uint32_t id = 0; id < 40; ++id) {
    many.push_back({{"id", id},
                    {"topic", "/p"},
                    {"encoding", "json"},
                    {"schemaName", "foxglove.PoseInFrame"}});
  }
  e = client.OnText(json{{"op", "advertise"}, {"channels", many}}.dump());
  EXPECT_TRUE(e.refused);
  EXPECT_EQ(client.client_channels().size(), kMaxClientChannels);
  EXPECT_EQ(e.replies.size(), kMaxRefusalsNamed);
}

TEST(FoxgloveProtocolTest, AClientThatMayNotWriteCannotPublishAPose) {
  Budgeted b;
  int requests = 0;
  ClientProtocol client(Channels(false), false, b.Access(),
                        {0.05, [&](const PoseRequest&) { ++requests; }});
  const Effects e = client.OnText(AdvertiseText(1, kPoseWithCovariance, "json"));
  EXPECT_TRUE(e.refused);
  EXPECT_TRUE(client.client_channels().empty());
  EXPECT_TRUE(client.OnBinary(ClientData(1, PoseEstimateMessage(0, 0, 0, 0, 0).dump())).refused);
  EXPECT_EQ(requests, 0);
}

}  // namespace
}  // namespace slam::server::foxglove
