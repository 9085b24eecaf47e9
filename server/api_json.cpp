#include "server/api_json.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <vector>

namespace slam::server {

using json = nlohmann::json;

std::string Lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

std::string MediaType(const std::string& content_type) {
  std::string type = content_type.substr(0, content_type.find(';'));
  type.erase(0, type.find_first_not_of(" \t"));
  type.erase(type.find_last_not_of(" \t") + 1);
  return Lower(type);
}

std::string Dump(const json& body) {
  return body.dump(-1, ' ', false, json::error_handler_t::replace);
}

void SendJson(httplib::Response& res, const json& body, int status) {
  res.status = status;
  res.set_content(Dump(body), kJson);
}

void SendProblem(httplib::Response& res, int status, const std::string& title,
                 const std::string& detail, const ConfigErrors& errors) {
  json body = {{"type", "about:blank"}, {"title", title}, {"status", status}, {"detail", detail}};
  if (!errors.empty()) {
    json list = json::array();
    for (const ConfigError& e : errors)
      list.push_back({{"pointer", e.pointer}, {"detail", e.detail}});
    body["errors"] = std::move(list);
  }
  res.status = status;
  res.set_content(Dump(body), kProblem);
}

json PoseJson(const TimedPose& p) {
  return {{"t", p.t}, {"x", p.pose.x}, {"y", p.pose.y}, {"theta", p.pose.theta}};
}

Result<json> ParseJsonBounded(std::string_view text, int max_depth) {
  bool too_deep = false;
  json out = json::parse(
      text,
      [&](int depth, json::parse_event_t, json&) {
        if (depth > max_depth) too_deep = true;
        return !too_deep;
      },
      false);
  if (too_deep) return Error("JSON nesting deeper than " + std::to_string(max_depth) + " levels");
  if (out.is_discarded()) return Error("not valid JSON");
  return out;
}

json BudgetJson(const BudgetSettings& b) {
  return {{"mode", ToString(b.mode)},
          {"rays_per_scan", b.rays_per_scan},
          {"cpu_share", b.cpu_share},
          {"policy", ToString(b.policy)},
          {"max_particles", b.max_particles}};
}

namespace {

// A JSON integer as int64, or nothing beyond its range: 2^64 - 1 arrives as an unsigned number,
// which get<int64_t>() would wrap to -1. Precondition: is_number_integer().
std::optional<int64_t> Int64Of(const json& integer) {
  if (integer.is_number_unsigned() &&
      integer.get<uint64_t>() > static_cast<uint64_t>(std::numeric_limits<int64_t>::max())) {
    return std::nullopt;
  }
  return integer.get<int64_t>();
}

}  // namespace

Result<BudgetSettings> BudgetFromJson(const json& body) {
  ConfigErrors errors;
  if (!body.is_object()) return ConfigErrors{{"", "must be a JSON object", 0}};
  static const std::vector<std::string> kKeys{"mode", "rays_per_scan", "cpu_share", "policy",
                                              "max_particles"};
  for (const auto& [key, value] : body.items()) {
    if (std::find(kKeys.begin(), kKeys.end(), key) == kKeys.end()) {
      errors.push_back({"/" + key, "unknown field", 0});
    }
  }
  bool missing = false;
  for (const std::string& key : kKeys) {
    if (!body.contains(key)) {
      errors.push_back({"/" + key, "required", 0});
      missing = true;
    }
  }
  if (missing) return errors;
  const size_t unknown = errors.size();
  BudgetSettings b;
  const auto mode =
      body["mode"].is_string() ? ParseQuotaMode(body["mode"].get<std::string>()) : std::nullopt;
  if (!mode) {
    errors.push_back({"/mode", "must be \"rays\" or \"cpu_share\"", 0});
  } else {
    b.mode = *mode;
  }
  const auto policy = body["policy"].is_string()
                          ? ParseBudgetPolicy(body["policy"].get<std::string>())
                          : std::nullopt;
  if (!policy) {
    errors.push_back({"/policy", "must be \"fixed\" or \"adaptive\"", 0});
  } else {
    b.policy = *policy;
  }
  const json& rays = body["rays_per_scan"];
  if (!rays.is_number_integer()) {
    errors.push_back({"/rays_per_scan", "must be an integer", 0});
  } else {
    const std::optional<int64_t> n = Int64Of(rays);
    if (!n) {
      errors.push_back({"/rays_per_scan",
                        rays.dump() + " is outside [1, " + std::to_string(kMaxRaysPerScan) + "]",
                        0});
    } else {
      b.rays_per_scan = *n;
    }
  }
  const json& share = body["cpu_share"];
  if (!share.is_number()) {
    errors.push_back({"/cpu_share", "must be a number", 0});
  } else {
    b.cpu_share = share.get<double>();
  }
  const json& particles = body["max_particles"];
  if (!particles.is_number_integer()) {
    errors.push_back({"/max_particles", "must be an integer", 0});
  } else {
    // Beyond the int range, the bound's message names what was sent, not what it was cut to.
    const std::optional<int64_t> n = Int64Of(particles);
    if (!n || *n > std::numeric_limits<int>::max() || *n < std::numeric_limits<int>::min()) {
      errors.push_back(
          {"/max_particles",
           particles.dump() + " is outside [1, " + std::to_string(kMaxParticlesCap) + "]", 0});
    } else {
      b.max_particles = static_cast<int>(*n);
    }
  }
  // Ranges of the values whose type was right (a mistyped value has no range to check).
  std::vector<std::string> mistyped;
  for (size_t i = unknown; i < errors.size(); ++i) mistyped.push_back(errors[i].pointer);
  for (ConfigError& e : Validate(b)) {
    if (std::find(mistyped.begin(), mistyped.end(), e.pointer) == mistyped.end()) {
      errors.push_back(std::move(e));
    }
  }
  if (!errors.empty()) return errors;
  return b;
}

Result<BudgetSettings> MergeBudget(const BudgetSettings& current, const json& patch) {
  if (!patch.is_object()) return ConfigErrors{{"", "must be a JSON object", 0}};
  json target = BudgetJson(current);
  target.merge_patch(patch);
  const json defaults = BudgetJson(BudgetSettings{});
  for (const auto& [key, value] : defaults.items()) {
    if (!target.contains(key)) target[key] = value;
  }
  return BudgetFromJson(target);
}

Result<PoseRequest> PoseRequestFromJson(const json& body, double resolution_m) {
  if (!body.is_object()) return ConfigErrors{{"", "must be a JSON object", 0}};
  ConfigErrors errors;
  static const std::vector<std::string> kKeys{"x", "y", "theta_deg", "sigma_m", "sigma_deg"};
  for (const auto& [key, value] : body.items()) {
    if (std::find(kKeys.begin(), kKeys.end(), key) == kKeys.end()) {
      errors.push_back({"/" + key, "unknown field", 0});
    }
  }
  PoseRequest request;
  const auto number = [&](const std::string& key, bool required) -> std::optional<double> {
    if (!body.contains(key)) {
      if (required) errors.push_back({"/" + key, "required", 0});
      return std::nullopt;
    }
    if (!body[key].is_number()) {
      errors.push_back({"/" + key, "must be a number", 0});
      return std::nullopt;
    }
    return body[key].get<double>();
  };
  const std::optional<double> x = number("x", true), y = number("y", true),
                              theta_deg = number("theta_deg", true);
  request.sigma_m = number("sigma_m", false);
  request.sigma_deg = number("sigma_deg", false);
  if (!errors.empty()) return errors;
  // JSON numbers beyond a double's range (1e999) read as infinite: ValidatePoseRequest says so.
  request.pose =
      Pose2{*x, *y, std::isfinite(*theta_deg) ? NormalizeAngle(DegToRad(*theta_deg)) : *theta_deg};
  errors = ValidatePoseRequest(request, resolution_m);
  if (!errors.empty()) return errors;
  return request;
}

namespace {

json RecordJson(const RelocalizationRecord& r) {
  return {{"cause", ToString(r.cause)},
          {"t", r.t},
          {"x", r.pose.x},
          {"y", r.pose.y},
          {"theta", r.pose.theta},
          {"score", r.score},
          {"runner_up_score", r.runner_up_score},
          {"points", r.points},
          {"searches", r.searches},
          {"lookups", r.lookups},
          {"scans", r.scans},
          {"search_s", r.search_s}};
}

}  // namespace

json RelocalizationJson(const SlamSnapshot& s) {
  json places = json::array();
  for (const GlobalMatch& p : s.relocalization_places) {
    places.push_back(
        {{"x", p.pose.x}, {"y", p.pose.y}, {"theta", p.pose.theta}, {"score", p.score}});
  }
  return {{"active", s.relocalizing.has_value()},
          {"cause", s.relocalizing ? json(ToString(*s.relocalizing)) : json(nullptr)},
          {"last", s.last_relocalization ? RecordJson(*s.last_relocalization) : json(nullptr)},
          {"places", std::move(places)},
          {"places_t",
           s.relocalization_places.empty() ? json(nullptr) : json(s.relocalization_places_t)}};
}

json MetricsEventJson(const SlamSnapshot& s) {
  const ScanMetrics& m = *s.last;
  return {{"scan", m.scan},
          {"t", s.pose.t},
          {"rays_planned", m.rays_planned},
          {"rays_used", m.rays_used},
          {"quota", m.quota},
          {"latency_ms", m.latency_s * 1e3},
          {"cpu_share", m.cpu_share},
          {"realtime_ratio", m.realtime_ratio},
          {"particles", m.particles},
          {"candidates", m.candidates},
          {"ess", m.ess},
          {"relocalizing", m.relocalizing},
          {"lookups", m.lookups},
          {"pose_error_m", m.pose_error_m ? json(*m.pose_error_m) : json(nullptr)},
          {"ate_m", m.ate_m ? json(*m.ate_m) : json(nullptr)}};
}

json PoseEventJson(const SlamSnapshot& s) {
  json j = PoseJson(s.pose);
  j["scan"] = s.last ? s.last->scan : 0;
  j["localized"] = !s.relocalizing.has_value();  // false: the pose is the last known, searching
  j["truth"] = s.truth ? json{{"x", s.truth->x}, {"y", s.truth->y}, {"theta", s.truth->theta}}
                       : json(nullptr);
  return j;
}

std::string SseEvent(const std::string& name, uint64_t id, const json& data) {
  return "event: " + name + "\nid: " + std::to_string(id) + "\ndata: " + Dump(data) + "\n\n";
}

}  // namespace slam::server
