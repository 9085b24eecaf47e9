#pragma once
// One Foxglove client's side of the protocol, without a socket: what its text messages ask
// (subscriptions, parameters) and what slamd answers. The server (foxglove_server.cpp) moves the
// bytes; this part is what a fuzzer can reach in memory (fuzz/fuzz_foxglove.cpp).

#include <cstdint>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "engine/result.hpp"
#include "scheduler/ray_budget_scheduler.hpp"
#include "server/foxglove_messages.hpp"

namespace slam::server::foxglove {

/// At most this many subscriptions per client (slamd has six channels; a client may subscribe
/// to one more than once): a client cannot grow slamd's memory by subscribing without end.
inline constexpr size_t kMaxSubscriptions = 64;

/// A client message longer than this (text or binary) is read and discarded, not parsed: the
/// client is answered with a status error and the connection stays.
inline constexpr size_t kMaxMessageBytes = 64 * 1024;

/// A subscribe message's refused parts are answered with a status error each up to this many,
/// the rest with one status that counts them: a message of 1800 bad subscriptions costs a few
/// short replies, not 1800 (which a client that does not read them piled up in slamd).
inline constexpr size_t kMaxRefusalsNamed = 8;

/// How a client reaches the budget.
struct BudgetAccess {
  std::function<BudgetSettings()> get;
  /// A merge patch of the budget object, validated; the new budget or what is wrong.
  std::function<Result<BudgetSettings>(const nlohmann::json&)> patch;
};

/// A client may advertise at most this many channels of its own (clientPublish).
inline constexpr size_t kMaxClientChannels = 16;

/// How a client's pose estimates reach the SLAM (SlamService::RequestPose). Without `request`,
/// slamd takes no client publishing.
struct PoseAccess {
  double resolution_m = 0.05;  // the map's cell size: the bound a pose is checked against
  std::function<void(const PoseRequest&)> request;
};

/// What one client message did.
struct Effects {
  std::vector<nlohmann::json> replies;  // status and parameterValues messages, in order
  std::vector<uint32_t> subscribed;     // new subscription ids
  std::vector<uint32_t> unsubscribed;   // subscription ids removed
  bool refused = false;                 // the message, or part of it, was refused
  bool budget_changed = false;
  bool pose_requested = false;  // a pose estimate was passed on
};

class ClientProtocol {
 public:
  /// `writer`: whether this client may change the budget and publish pose estimates.
  ClientProtocol(std::vector<ChannelSpec> channels, bool writer, BudgetAccess budget,
                 PoseAccess pose = {});

  /// A text message from the client.
  Effects OnText(std::string_view text);
  /// A binary message from the client: message data (opcode 1: the client's channel id,
  /// little-endian uint32, then the payload) on a channel it advertised; a pose estimate's
  /// payload is JSON (PoseEstimate). Other opcodes (service calls) are refused.
  Effects OnBinary(std::string_view data);
  /// A message of `bytes` bytes, longer than kMaxMessageBytes, that was discarded unread.
  Effects OnTooLong(uint64_t bytes);

  const std::map<uint32_t, Channel>& subscriptions() const { return subscriptions_; }
  /// The budget's parameters this client follows.
  const std::set<std::string>& parameter_updates() const { return parameter_updates_; }
  bool writer() const { return writer_; }
  /// The channels this client advertised (clientPublish): id to schema name.
  const std::map<uint32_t, std::string>& client_channels() const { return client_channels_; }

 private:
  void Subscribe(const nlohmann::json& list, Effects& out);
  void GetParameters(const nlohmann::json& message, Effects& out) const;
  void SetParameters(const nlohmann::json& message, Effects& out);
  void AdvertiseClient(const nlohmann::json& list, Effects& out);

  std::vector<ChannelSpec> channels_;
  bool writer_;
  BudgetAccess budget_;
  PoseAccess pose_;
  std::map<uint32_t, std::string> client_channels_;
  std::map<uint32_t, Channel> subscriptions_;
  std::set<std::string> parameter_updates_;
};

/// {"op": "status", "level": level (0 info, 1 warning, 2 error), "message": message}.
nlohmann::json Status(int level, const std::string& message);
inline constexpr int kInfo = 0, kWarning = 1, kError = 2;

}  // namespace slam::server::foxglove
