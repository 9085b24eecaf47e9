#pragma once
// The JSON of slamd's API (docs/http-api.md): plain and problem-details responses, the budget
// object and its strict reader, and the event stream's events in Server-Sent Events framing.

#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "engine/config_error.hpp"
#include "engine/pose.hpp"
#include "engine/result.hpp"
#include "scheduler/ray_budget_scheduler.hpp"
#include "server/http_library.hpp"
#include "server/slam_service.hpp"

namespace slam::server {

inline constexpr const char* kJson = "application/json; charset=utf-8";
inline constexpr const char* kProblem = "application/problem+json";

/// `s` in lower case (ASCII).
std::string Lower(std::string s);

/// The media type of a Content-Type header, lower case, without parameters.
std::string MediaType(const std::string& content_type);

/// Parses JSON text that nests at most `max_depth` levels (copying and comparing nested values
/// recurse in nlohmann-json: 64 KiB of brackets would nest 32 000 deep). The error says whether
/// it is not JSON or nests too deep.
Result<nlohmann::json> ParseJsonBounded(std::string_view text, int max_depth = 32);

/// JSON text of `body`; bytes that are not UTF-8 (a client's path or parameter echoed in an
/// error, say) become U+FFFD instead of throwing.
std::string Dump(const nlohmann::json& body);

/// `body` as the response, application/json.
void SendJson(httplib::Response& res, const nlohmann::json& body, int status = 200);

/// An RFC 9457 problem-details response; `errors` become its "errors" list (pointer, detail).
void SendProblem(httplib::Response& res, int status, const std::string& title,
                 const std::string& detail, const ConfigErrors& errors = {});

/// {"t", "x", "y", "theta"}.
nlohmann::json PoseJson(const TimedPose& p);

/// The budget object of GET /api/v1/budget.
nlohmann::json BudgetJson(const BudgetSettings& b);

/// A whole budget object: every key required (PUT, and a PATCH after merging onto the
/// current object), no other key, right types; then the ranges of Validate.
Result<BudgetSettings> BudgetFromJson(const nlohmann::json& body);

/// `current` changed by a merge patch of its object (RFC 7396: null removes a member, and a
/// removed member takes its default), then read as BudgetFromJson reads a whole object.
Result<BudgetSettings> MergeBudget(const BudgetSettings& current, const nlohmann::json& patch);

/// A pose request's body (POST /api/v1/pose): {"x": m, "y": m, "theta_deg": d} with optional
/// "sigma_m" and "sigma_deg", numbers, no other key; then ValidatePoseRequest at
/// `resolution_m`.
Result<PoseRequest> PoseRequestFromJson(const nlohmann::json& body, double resolution_m);

/// The relocalisation's state for /status and the event stream: {"active", "cause" (null
/// when not active), "last": the last one taken or null}.
nlohmann::json RelocalizationJson(const SlamSnapshot& s);

/// The data of the event stream's `metrics` and `pose` events for a snapshot.
nlohmann::json MetricsEventJson(const SlamSnapshot& s);
nlohmann::json PoseEventJson(const SlamSnapshot& s);

/// One Server-Sent Event: its name, id and JSON data.
std::string SseEvent(const std::string& name, uint64_t id, const nlohmann::json& data);

}  // namespace slam::server
