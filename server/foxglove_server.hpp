#pragma once
// slamd's Foxglove WebSocket server (docs/http-api.md, "Foxglove"): the map, pose, trajectory,
// transform, scan and ground truth as channels of the Foxglove WebSocket protocol
// (foxglove.websocket.v1, or foxglove.sdk.v1), JSON-encoded with the Foxglove schemas, the
// budget as parameters, and the clients' pose estimates (clientPublish: the 3D panel's "Pose
// estimate" tool). One thread of its own serves every client (Boost.Beast on Boost.Asio):
// it reads the SLAM's published snapshots and never makes the SLAM thread wait. Each client has
// a bounded send queue, counted at what its entries cost in memory: a slow or stuck client loses
// messages (counted, and told once in a while with a status message), never delays anyone else,
// and one that leaves its replies unread is disconnected. Connections are admitted by the rule of
// server/connection_admission.hpp (per address and in all, the oldest of the fullest address
// giving way), both while they upgrade and once they are clients: no address locks others out.

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "engine/result.hpp"
#include "scheduler/ray_budget_scheduler.hpp"
#include "server/slam_service.hpp"

namespace slam::server {

struct FoxgloveOptions {
  std::string bind = "127.0.0.1";
  int port = 8765;    // 0: any free port
  std::string token;  // when set, every connection must present it (Authorization: Bearer)
  /// Besides loopback names and IP addresses, the Host names it answers (--allow-host).
  std::vector<std::string> allowed_hosts;
  int max_clients = 16;             // beyond: the oldest of the fullest address goes, or 503
  int max_clients_per_address = 8;  // beyond: the oldest of the same address goes, or 503
  size_t max_queued_bytes = size_t{8} << 20;  // per client: messages beyond are dropped
  size_t max_grid_cells = size_t{1} << 20;    // /map is merged into larger cells beyond
  double map_period_s = 1.0;                  // /map at most this often while it changes
  double trajectory_period_s = 1.0;           // /trajectory likewise
};

/// What the server did, for /metrics.
struct FoxgloveCounters {
  int64_t clients = 0;             // connected now
  uint64_t connections = 0;        // accepted since start
  uint64_t refused = 0;            // upgrades refused (bad request, host, token, cap)
  uint64_t evicted = 0;            // connections closed to make room for a newer one
  uint64_t closed_unread = 0;      // clients disconnected for leaving their replies unread
  uint64_t messages_sent = 0;      // message-data frames queued for sending
  uint64_t messages_dropped = 0;   // message-data frames dropped at a full queue
  uint64_t messages_replaced = 0;  // /map, /trajectory replaced in the queue by a newer one
  uint64_t bytes_sent = 0;         // written to the sockets
  uint64_t parameter_changes = 0;  // setParameters requests that changed the budget
  uint64_t pose_estimates = 0;     // client-published pose estimates passed on
  uint64_t bad_requests = 0;       // client messages refused (not JSON, unknown op, ...)
};

class FoxgloveServer {
 public:
  /// Budget changes go to `service` (SlamService::ChangeBudget) and pose estimates too
  /// (SlamService::RequestPose), as the REST routes' do.
  FoxgloveServer(SlamService& service, const FoxgloveOptions& options);
  ~FoxgloveServer();  // stops
  FoxgloveServer(const FoxgloveServer&) = delete;
  FoxgloveServer& operator=(const FoxgloveServer&) = delete;

  /// Listens on the options' address and port; the port (useful with port 0).
  Result<int> Bind();
  /// Serves on a thread of its own until Stop (call Bind first).
  void Start();
  /// Closes every connection and joins the thread (from any thread; idempotent).
  void Stop();

  FoxgloveCounters Counters() const;
  /// The counters in the Prometheus text format (slamd_foxglove_*), for /metrics.
  std::string MetricsText() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace slam::server
