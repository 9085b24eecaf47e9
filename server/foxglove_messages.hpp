#pragma once
// The Foxglove WebSocket protocol's messages as slamd sends them (foxglove/ws-protocol,
// docs/spec.md, subprotocol foxglove.websocket.v1 or foxglove.sdk.v1): the channels with their
// JSON schemas, the messages of each channel in the JSON encoding of the Foxglove schemas
// (foxglove.Grid, foxglove.PoseInFrame, ...), the binary message-data frame, and the budget as
// parameters. Pure functions of a snapshot: the server (foxglove_server.hpp) moves the bytes.

#include <array>
#include <cstddef>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "engine/pose.hpp"
#include "engine/result.hpp"
#include "scheduler/ray_budget_scheduler.hpp"
#include "server/slam_service.hpp"

namespace slam::server::foxglove {

/// The subprotocols slamd speaks, the newer name first.
inline constexpr std::string_view kSubprotocolSdk = "foxglove.sdk.v1";
inline constexpr std::string_view kSubprotocolV1 = "foxglove.websocket.v1";

/// The frames of slamd's messages.
inline constexpr const char* kMapFrame = "map";
inline constexpr const char* kRobotFrame = "base_link";

/// slamd's channels (their ids in the advertise message).
enum class Channel : uint32_t {
  kMap = 1,
  kPose = 2,
  kTrajectory = 3,
  kTransform = 4,
  kScan = 5,
  kGroundTruth = 6,
};

struct ChannelSpec {
  Channel id;
  std::string topic;        // "/map"
  std::string schema_name;  // "foxglove.Grid"
  nlohmann::json schema;    // its JSON schema
};

/// The channels slamd offers; /ground_truth only when the source is simulated.
std::vector<ChannelSpec> Channels(bool simulated);

/// {"op": "advertise", "channels": [...]}, each channel JSON-encoded with its JSON schema.
nlohmann::json Advertise(const std::vector<ChannelSpec>& channels);

/// The Foxglove time of `t_s` seconds: {"sec", "nsec"}, clamped at 0.
nlohmann::json Time(double t_s);

/// A foxglove.Grid of the snapshot's map in the map frame: one INT8 field "occupancy" per cell,
/// 0 (free) to 100 (occupied) from the log odds, -1 where nothing was seen (the ROS occupancy
/// grid convention). When the map has more than `max_cells` cells, blocks of cells are merged
/// (the most occupied known cell of a block; unknown if none is known) with a larger cell size.
/// `t_s` is its timestamp. An empty map gives a 1 x 1 unknown grid at the origin.
nlohmann::json Grid(const SlamSnapshot& snapshot, size_t max_cells, double t_s);

/// A foxglove.Pose of a planar pose (z = 0, a rotation about z).
nlohmann::json Pose(const Pose2& pose);

/// foxglove.PoseInFrame of `pose` in the map frame.
nlohmann::json PoseInFrame(const TimedPose& pose);

/// foxglove.PosesInFrame of the trajectory in the map frame (at most `max_poses`, evenly
/// thinned, the first and the last kept), stamped with the last pose's time.
nlohmann::json PosesInFrame(const std::vector<TimedPose>& poses, size_t max_poses);

/// foxglove.FrameTransform from the map frame to the robot's at `pose`.
nlohmann::json FrameTransform(const TimedPose& pose);

/// foxglove.PointCloud of points in the robot's frame (x, y, z as FLOAT32, z = 0).
nlohmann::json PointCloud(const std::vector<Vec2>& points, double t_s);

/// The binary message-data frame (opcode 1): subscription id and receive timestamp (ns), both
/// little-endian, then the payload.
std::string MessageData(uint32_t subscription, uint64_t timestamp_ns, std::string_view payload);

/// The size of a message-data frame's header (opcode, subscription id, timestamp).
inline constexpr size_t kMessageDataHeaderBytes = 13;

/// The header of MessageData's frame alone: the server sends it before a payload that every
/// subscriber shares, rather than a copy of the payload per client.
std::array<char, kMessageDataHeaderBytes> MessageDataHeader(uint32_t subscription,
                                                            uint64_t timestamp_ns);

/// The budget's parameters: budget.mode, budget.rays_per_scan, budget.cpu_share, budget.policy,
/// budget.max_particles (numbers with type "float64").
nlohmann::json BudgetParameters(const BudgetSettings& budget);

/// Whether `name` is one of the budget's parameters.
bool IsBudgetParameter(std::string_view name);

/// A setParameters request's parameters as a merge patch of the budget (GET /api/v1/budget's
/// object): names checked, whole numbers of float64 parameters made integers where the budget
/// wants them, a parameter without a value (or null) reset to its default. Errors name the
/// parameter (pointer "/budget.rays_per_scan"); the patch's values are checked by the budget's
/// own validation.
Result<nlohmann::json> BudgetPatch(const nlohmann::json& parameters);

/// The schemas of the pose estimates slamd takes from a client (capability clientPublish,
/// encoding "json"): Foxglove's 3D panel's "Pose estimate" tool publishes
/// geometry_msgs/PoseWithCovarianceStamped (named as ROS 1 or ROS 2 name it), and
/// foxglove.PoseInFrame is slamd's own /pose channel's.
bool IsPoseEstimateSchema(std::string_view schema_name);

/// A client's pose estimate (a message of IsPoseEstimateSchema, JSON) as a pose request in the
/// map frame: its position and its rotation about z (a tilted quaternion is refused), in frame
/// "map" or no frame. A PoseWithCovarianceStamped whose covariance gives x, y or yaw a positive
/// variance is a hint: sigma_m the larger of the x and y deviations, sigma_deg the yaw's, each
/// clamped to what POST /api/v1/pose takes (50 m, 180 degrees); a zero covariance, or a
/// PoseInFrame, puts the robot there. Errors point into the message ("/pose/pose/position/x");
/// the request is checked as POST /api/v1/pose checks it (ValidatePoseRequest).
Result<PoseRequest> PoseEstimate(std::string_view schema_name, const nlohmann::json& message,
                                 double resolution_m);

/// Standard base64 (RFC 4648, with padding) of `bytes`.
std::string Base64(std::string_view bytes);

}  // namespace slam::server::foxglove
