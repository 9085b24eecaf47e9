#pragma once
// Foxglove clients for slamd-load: each connects to slamd's Foxglove WebSocket server as
// Foxglove does (subprotocol foxglove.websocket.v1), subscribes to every channel it advertises
// and reads every message until told to stop, reconnecting if the connection ends.

#include <atomic>
#include <cstdint>
#include <string>

#include "loadgen/measures.hpp"

namespace slam::loadgen {

/// What all Foxglove clients saw, counted as it happens.
struct FoxgloveStats {
  std::atomic<int> connected{0};
  std::atomic<int64_t> connects{0};
  std::atomic<int64_t> refused{0};      // upgrades answered with an error, failed connections
  std::atomic<int64_t> disconnects{0};  // connections that ended while the run went on
  std::atomic<int64_t> messages{0};     // message-data frames
  std::atomic<int64_t> bytes{0};
  std::atomic<int64_t> maps{0};
  std::atomic<int64_t> poses{0};
  std::atomic<int64_t> statuses{0};  // status messages (a warning of dropped messages, say)
  /// The longest wait, over the clients' first connections, from connecting to the first
  /// /map and the first /pose, milliseconds (-1 while none came).
  std::atomic<int64_t> first_map_ms{-1};
  std::atomic<int64_t> first_pose_ms{-1};
};

/// Runs one client until `stop`; `token` (may be empty) goes as Authorization: Bearer.
void RunFoxgloveViewer(const Target& target, const std::string& token,
                       const std::atomic<bool>& stop, FoxgloveStats& stats);

}  // namespace slam::loadgen
