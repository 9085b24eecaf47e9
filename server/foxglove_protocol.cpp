#include "server/foxglove_protocol.hpp"

#include <algorithm>
#include <cstdio>
#include <utility>

#include "server/api_json.hpp"

namespace slam::server::foxglove {

using json = nlohmann::json;

json Status(int level, const std::string& message) {
  return {{"op", "status"}, {"level", level}, {"message", message}};
}

ClientProtocol::ClientProtocol(std::vector<ChannelSpec> channels, bool writer, BudgetAccess budget,
                               PoseAccess pose)
    : channels_(std::move(channels)),
      writer_(writer),
      budget_(std::move(budget)),
      pose_(std::move(pose)) {}

Effects ClientProtocol::OnBinary(std::string_view data) {
  Effects out;
  const auto refuse = [&](const std::string& why) {
    out.refused = true;
    out.replies.push_back(Status(kError, why));
    return out;
  };
  constexpr uint8_t kClientMessageData = 0x01;
  if (data.empty() || static_cast<uint8_t>(data[0]) != kClientMessageData) {
    return refuse(data.empty() ? "an empty binary message"
                               : "slamd takes no binary message of opcode " +
                                     std::to_string(static_cast<uint8_t>(data[0])) +
                                     " (only client message data, opcode 1)");
  }
  if (data.size() < 5) return refuse("a client message data frame needs a channel id");
  uint32_t id = 0;
  for (size_t i = 4; i > 0; --i) id = (id << 8) | static_cast<uint8_t>(data[i]);
  const auto channel = client_channels_.find(id);
  if (channel == client_channels_.end()) {
    return refuse("message data on channel " + std::to_string(id) +
                  ", which this client has not advertised");
  }
  const Result<json> parsed = ParseJsonBounded(data.substr(5));
  if (!parsed.ok()) return refuse("a pose estimate must be JSON: " + parsed.Message());
  Result<PoseRequest> request = ConfigErrors{};
  try {
    request = PoseEstimate(channel->second, parsed.value(), pose_.resolution_m);
  } catch (const json::exception& e) {
    return refuse(std::string("a malformed pose estimate: ") + e.what());
  }
  if (!request.ok()) {
    std::string why;  // on one line: a status is one notification in Foxglove
    for (const ConfigError& e : request.errors()) {
      why += (why.empty() ? "" : "; ") + (e.pointer.empty() ? "" : e.pointer + ": ") + e.detail;
    }
    return refuse("the pose was not changed: " + why);
  }
  pose_.request(request.value());
  out.pose_requested = true;
  const PoseRequest& r = request.value();
  char text[200];
  std::snprintf(text, sizeof text, "pose estimate taken: x %.3f m, y %.3f m, theta %.1f deg%s",
                r.pose.x, r.pose.y, RadToDeg(r.pose.theta),
                r.sigma_m || r.sigma_deg ? " (relocalising around it)" : "");
  out.replies.push_back(Status(kInfo, text));
  return out;
}

void ClientProtocol::AdvertiseClient(const json& list, Effects& out) {
  if (!list.is_array()) throw json::type_error::create(302, "channels must be an array", &list);
  const auto refuse = [&](const std::string& why) {
    out.refused = true;
    out.replies.push_back(Status(kError, why));
  };
  if (!writer_ || !pose_.request) {
    refuse(!writer_ ? "no channel advertised: this connection comes from a web page of another "
                      "origin and may not publish (give slamd a --token-file and connect with it)"
                    : "no channel advertised: slamd takes no client publishing here");
    return;
  }
  size_t refusals = 0;
  for (const json& c : list) {
    const auto id = c.at("id").get<uint32_t>();
    const auto topic = c.at("topic").get<std::string>();
    const auto encoding = c.at("encoding").get<std::string>();
    const auto schema = c.at("schemaName").get<std::string>();
    std::string why;
    if (encoding != "json") {
      why = "encoding \"" + encoding + "\" (slamd takes json)";
    } else if (!IsPoseEstimateSchema(schema)) {
      why = "schema \"" + schema +
            "\" (slamd takes pose estimates: geometry_msgs/PoseWithCovarianceStamped, "
            "geometry_msgs/msg/PoseWithCovarianceStamped, foxglove.PoseInFrame)";
    } else if (client_channels_.count(id) != 0) {
      why = "channel id " + std::to_string(id) + " is already advertised";
    } else if (client_channels_.size() >= kMaxClientChannels) {
      why = "at most " + std::to_string(kMaxClientChannels) + " channels per client";
    }
    if (!why.empty()) {
      out.refused = true;
      if (refusals++ < kMaxRefusalsNamed)
        refuse("channel " + std::to_string(id) + " (" + topic + ") not advertised: " + why);
      continue;
    }
    client_channels_[id] = schema;
  }
}

Effects ClientProtocol::OnTooLong(uint64_t bytes) {
  Effects out;
  out.refused = true;
  out.replies.push_back(
      Status(kError, "a message of " + std::to_string(bytes) + " bytes was discarded: at most " +
                         std::to_string(kMaxMessageBytes / 1024) + " KiB a message"));
  return out;
}

Effects ClientProtocol::OnText(std::string_view text) {
  Effects out;
  const Result<json> parsed = ParseJsonBounded(text);
  if (!parsed.ok()) {
    out.refused = true;
    out.replies.push_back(
        Status(kError, "not a message of the Foxglove protocol: " + parsed.Message()));
    return out;
  }
  const json& message = parsed.value();
  const std::string op = message.is_object() && message.contains("op") && message["op"].is_string()
                             ? message["op"].get<std::string>()
                             : std::string();
  try {
    if (op == "subscribe") {
      Subscribe(message.at("subscriptions"), out);
      return out;
    }
    if (op == "unsubscribe") {
      for (const json& id : message.at("subscriptionIds")) {
        const auto sub = id.get<uint32_t>();
        if (subscriptions_.erase(sub) != 0) out.unsubscribed.push_back(sub);
      }
      return out;
    }
    if (op == "getParameters") {
      GetParameters(message, out);
      return out;
    }
    if (op == "setParameters") {
      SetParameters(message, out);
      return out;
    }
    if (op == "advertise") {
      AdvertiseClient(message.at("channels"), out);
      return out;
    }
    if (op == "unadvertise") {
      for (const json& id : message.at("channelIds")) client_channels_.erase(id.get<uint32_t>());
      return out;
    }
    if (op == "subscribeParameterUpdates" || op == "unsubscribeParameterUpdates") {
      for (const json& name : message.at("parameterNames")) {
        const auto n = name.get<std::string>();
        if (op == "unsubscribeParameterUpdates") {
          parameter_updates_.erase(n);
        } else if (IsBudgetParameter(n)) {
          parameter_updates_.insert(n);
        }
      }
      return out;
    }
  } catch (const json::exception& e) {
    out.refused = true;
    out.replies.push_back(Status(kError, "malformed " + op + " message: " + e.what()));
    return out;
  }
  out.refused = true;
  out.replies.push_back(op.empty() ? Status(kError, "a message needs an \"op\"")
                                   : Status(kError, "slamd does not support \"" + op +
                                                        "\" (capabilities: parameters, "
                                                        "parametersSubscribe, clientPublish)"));
  return out;
}

void ClientProtocol::Subscribe(const json& list, Effects& out) {
  if (!list.is_array())
    throw json::type_error::create(302, "subscriptions must be an array", &list);
  size_t refusals = 0;
  const auto refuse = [&](const std::string& why) {
    out.refused = true;
    if (refusals++ < kMaxRefusalsNamed) out.replies.push_back(Status(kError, why));
  };
  // The refusals beyond the first few in one status, also when a later entry is malformed.
  const auto tell = [&] {
    if (refusals <= kMaxRefusalsNamed) return;
    out.replies.push_back(Status(kError, std::to_string(refusals - kMaxRefusalsNamed) +
                                             " more subscriptions of this message refused"));
  };
  try {
    for (const json& s : list) {
      const auto id = s.at("id").get<uint32_t>();
      const auto channel_id = s.at("channelId").get<uint32_t>();
      const auto spec = std::find_if(channels_.begin(), channels_.end(), [&](const auto& c) {
        return static_cast<uint32_t>(c.id) == channel_id;
      });
      if (spec == channels_.end()) {
        refuse("no channel " + std::to_string(channel_id));
        continue;
      }
      if (subscriptions_.count(id) != 0) {
        refuse("subscription " + std::to_string(id) + " is already in use");
        continue;
      }
      if (subscriptions_.size() >= kMaxSubscriptions) {
        refuse("at most " + std::to_string(kMaxSubscriptions) + " subscriptions per client");
        break;
      }
      subscriptions_[id] = spec->id;
      out.subscribed.push_back(id);
    }
  } catch (const json::exception&) {
    tell();
    throw;
  }
  tell();
}

void ClientProtocol::GetParameters(const json& message, Effects& out) const {
  const json& names = message.at("parameterNames");
  if (!names.is_array())
    throw json::type_error::create(302, "parameterNames must be an array", &names);
  json values = json::array();
  for (const json& p : BudgetParameters(budget_.get())) {
    const bool wanted = names.empty() ||
                        std::any_of(names.begin(), names.end(),
                                    [&](const json& n) { return n.is_string() && n == p["name"]; });
    if (wanted) values.push_back(p);
  }
  json reply = {{"op", "parameterValues"}, {"parameters", std::move(values)}};
  if (message.contains("id") && message["id"].is_string()) reply["id"] = message["id"];
  out.replies.push_back(std::move(reply));
}

void ClientProtocol::SetParameters(const json& message, Effects& out) {
  if (!writer_) {
    out.refused = true;
    out.replies.push_back(
        Status(kError,
               "the budget was not changed: this connection comes from a web page of another "
               "origin (give slamd a --token-file and connect with it)"));
    return;
  }
  const json& parameters = message.at("parameters");
  const Result<json> patch = BudgetPatch(parameters);
  const Result<BudgetSettings> changed =
      patch.ok() ? budget_.patch(patch.value()) : Result<BudgetSettings>(patch.errors());
  if (!changed.ok()) {
    // Named as the client knows them: "/rays_per_scan" is budget.rays_per_scan.
    std::string why;
    for (const ConfigError& e : changed.errors()) {
      std::string name = e.pointer.empty() ? std::string() : e.pointer.substr(1);
      if (!name.empty() && name.rfind("budget.", 0) != 0 && name != "parameters") {
        name = "budget." + name;
      }
      why += (why.empty() ? "" : "; ") + name + (name.empty() ? "" : ": ") + e.detail;
    }
    out.refused = true;
    out.replies.push_back(Status(kError, "the budget was not changed: " + why));
    return;
  }
  out.budget_changed = true;
  if (message.contains("id") && message["id"].is_string()) {
    // The answer to a request with an id: the values of the parameters it set.
    json values = json::array();
    for (const json& p : BudgetParameters(changed.value())) {
      const bool named = std::any_of(parameters.begin(), parameters.end(), [&](const json& q) {
        return q.is_object() && q.contains("name") && q["name"] == p["name"];
      });
      if (named) values.push_back(p);
    }
    out.replies.push_back(
        {{"op", "parameterValues"}, {"parameters", std::move(values)}, {"id", message["id"]}});
  }
}

}  // namespace slam::server::foxglove
