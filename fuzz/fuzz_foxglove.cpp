// Fuzzes one Foxglove client's side of slamd's Foxglove server (server/foxglove_protocol.hpp):
// its text messages, as the serving thread hands them over, against a budget changed as the REST
// route changes it (MergeBudget, the same validation).
//
// The first input byte chooses whether the client may change the budget (odd) and whether the
// source is simulated (bit 1: the /ground_truth channel); the rest is split at each newline
// into messages (text without "\n" is one message); a message starting with a NUL byte is taken
// as a binary message (the bytes after the NUL: opcode, channel id, payload), one starting with
// byte 1 as a message too long, discarded unread (its length kMaxMessageBytes plus its own).
//
// Invariants: nothing escapes (an exception would end slamd's serving thread); every reply is a
// status (level 0..2, a message) or a parameterValues whose parameters are the budget's own; at
// most kMaxSubscriptions subscriptions, each on an advertised channel; subscriptions added and
// removed are reported as such; only budget parameters are followed; the budget stays valid,
// never changes for a client that may not change it, and changes only with budget_changed;
// at most kMaxClientChannels client channels, each of a pose estimate's schema; a pose request
// only from a client that may change the budget, valid, and reported as pose_requested.

#include <cstddef>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "fuzz/fuzz_check.hpp"
#include "server/api_json.hpp"
#include "server/foxglove_protocol.hpp"

using slam::fuzz::Check;
namespace fox = slam::server::foxglove;
using json = nlohmann::json;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const bool writer = (data[0] & 1) != 0;
  const bool simulated = (data[0] & 2) != 0;
  const std::string_view input(reinterpret_cast<const char*>(data) + 1, size - 1);

  slam::BudgetSettings budget;
  int patches = 0;
  fox::BudgetAccess access{[&] { return budget; },
                           [&](const json& patch) {
                             ++patches;
                             auto merged = slam::server::MergeBudget(budget, patch);
                             if (merged.ok()) budget = merged.value();
                             return merged;
                           }};
  int poses = 0;
  constexpr double kResolution = 0.05;
  fox::PoseAccess pose_access{kResolution, [&](const slam::server::PoseRequest& request) {
                                Check(
                                    slam::server::ValidatePoseRequest(request, kResolution).empty(),
                                    "an invalid pose request passed on");
                                ++poses;
                              }};
  const auto channels = fox::Channels(simulated);
  fox::ClientProtocol client(channels, writer, access, pose_access);

  size_t start = 0;
  while (start <= input.size()) {
    size_t end = input.find('\n', start);
    if (end == std::string_view::npos) end = input.size();
    const std::string_view message = input.substr(start, end - start);
    start = end + 1;

    const auto before_subscriptions = client.subscriptions();
    const slam::BudgetSettings before_budget = budget;
    const int poses_before = poses;
    fox::Effects effects;
    try {
      // A message starting with a NUL byte stands for a binary one, byte 1 for one too long.
      if (!message.empty() && message[0] == '\0') {
        effects = client.OnBinary(message.substr(1));
      } else if (!message.empty() && message[0] == '\1') {
        effects = client.OnTooLong(fox::kMaxMessageBytes + message.size());
        Check(effects.refused && effects.replies.size() == 1 && effects.subscribed.empty() &&
                  effects.unsubscribed.empty() && !effects.budget_changed,
              "a message too long did more than one status error");
      } else {
        effects = client.OnText(message);
      }
    } catch (...) {
      Check(false, "an exception escaped the Foxglove protocol");
    }
    for (const json& reply : effects.replies) {
      Check(reply.is_object() && reply.contains("op"), "a reply without an op");
      const std::string op = reply["op"];
      if (op == "status") {
        Check(reply["level"].is_number_integer() && reply["level"] >= 0 && reply["level"] <= 2,
              "a status level outside 0..2");
        Check(reply["message"].is_string() && !reply["message"].get<std::string>().empty(),
              "a status without a message");
        (void)slam::server::Dump(reply);  // any bytes the client sent come back as valid UTF-8
      } else {
        Check(op == "parameterValues", "a reply that is neither status nor parameterValues");
        for (const json& p : reply["parameters"]) {
          Check(fox::IsBudgetParameter(p["name"].get<std::string>()),
                "a parameter that is not the budget's");
        }
      }
    }
    const auto& subscriptions = client.subscriptions();
    Check(subscriptions.size() <= fox::kMaxSubscriptions, "more subscriptions than the cap");
    for (const auto& [id, channel] : subscriptions) {
      bool advertised = false;
      for (const auto& c : channels) advertised = advertised || c.id == channel;
      Check(advertised, "a subscription to a channel never advertised");
    }
    for (const uint32_t id : effects.subscribed) {
      Check(before_subscriptions.count(id) == 0 && subscriptions.count(id) == 1,
            "a reported subscription that was not new");
    }
    for (const uint32_t id : effects.unsubscribed) {
      Check(before_subscriptions.count(id) == 1 && subscriptions.count(id) == 0,
            "a reported unsubscription of nothing");
    }
    Check(subscriptions.size() + effects.unsubscribed.size() ==
              before_subscriptions.size() + effects.subscribed.size(),
          "subscriptions changed without being reported");
    for (const std::string& name : client.parameter_updates()) {
      Check(fox::IsBudgetParameter(name), "following a parameter that is not the budget's");
    }
    Check(slam::Validate(budget).empty(), "the budget became invalid");
    if (!writer) Check(patches == 0, "a client that may not change the budget reached it");
    if (!effects.budget_changed) Check(budget == before_budget, "the budget changed unreported");
    Check(poses - poses_before == (effects.pose_requested ? 1 : 0),
          "a pose request not reported, or reported and not made");
    if (!writer) Check(poses == 0, "a client that may not change the pose reached it");
    Check(client.client_channels().size() <= fox::kMaxClientChannels,
          "more client channels than the cap");
    for (const auto& [id, schema] : client.client_channels()) {
      Check(fox::IsPoseEstimateSchema(schema), "a client channel of another schema");
    }
  }
  return 0;
}
