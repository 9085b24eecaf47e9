// Fuzzes slamd's HTTP front: whole requests (request line, headers, body) through the very
// HttpServer slamd runs (httplib's parser, the guard with its limits and token check, routing,
// every handler) via HttpServer::HandleInMemory, on a SLAM service that has mapped a few seconds
// of the virtual marXbot.
//
// The first input byte chooses the token setting (odd: slamd has a token) and a template; the
// rest is either the whole request or a body sent under one of the templates (PATCH and PUT of
// the budget, PATCH of the parameters, POST of a tuning job, map/save), so that bodies reach the
// JSON validators without the fuzzer having to find a valid head first. Requests for the event
// stream or a reset are skipped: both wait on the SLAM thread by design (up to 2 s).
//
// Invariants: nothing crashes; every request of at least one line gets one HTTP/1.1 status line
// with a code in 100..599; no 500 (an exception escaped a handler); a problem+json body parses and
// carries the response's status; after each input the budget and the parameters read back as JSON
// that the server accepts again unchanged (PUT of the budget, PATCH of the parameters: 200).

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "engine/io/robot_json.hpp"
#include "fuzz/fuzz_check.hpp"
#include "hw_link/link.hpp"
#include "server/http_server.hpp"
#include "server/slam_service.hpp"
#include "server/tune_jobs.hpp"
#include "sim/virtual_marxbot.hpp"
#include "sim/world.hpp"

using slam::fuzz::Check;

namespace {

constexpr const char* kToken = "fuzz-token-0123456789";

struct Slamd {
  std::unique_ptr<slam::hw::Link> link;
  std::unique_ptr<slam::server::SlamService> service;
  std::unique_ptr<slam::server::JobManager> jobs;
  std::unique_ptr<slam::server::HttpServer> open;     // no token
  std::unique_ptr<slam::server::HttpServer> guarded;  // with kToken

  Slamd() {
    const auto robot =
        slam::io::LoadRobot(std::string(SLAM_SOURCE_DIR) + "/config/marxbot.robot.json");
    Check(robot.ok(), "the shipped robot.json does not load");
    slam::sim::ScenarioConfig scenario;
    scenario.seed = 3;
    slam::sim::VirtualMarxbotOptions options;
    options.paced = false;
    options.duration_s = 4.0;
    auto source = std::make_unique<slam::sim::VirtualMarxbotSource>(
        *slam::sim::BuiltinWorld("box"), "box", robot.value(), scenario, options);
    slam::sim::VirtualMarxbotSource* truth = source.get();
    slam::hw::LinkOptions link_options;
    link_options.queue_capacity = 1 << 16;
    link = std::make_unique<slam::hw::Link>(std::move(source), robot.value(), link_options);
    slam::server::ServiceOptions service_options;
    service_options.robot = robot.value();
    service_options.budget.rays_per_scan = 4000;
    service = std::make_unique<slam::server::SlamService>(*link, truth, service_options);
    jobs = std::make_unique<slam::server::JobManager>("", "");
    link->Start();
    service->Start();
    // Map the whole run, so that tiles and exports have something to show.
    auto snapshot = service->Snapshot();
    for (int i = 0; i < 200 && !(link->Drained() && snapshot->last); ++i) {
      snapshot = service->WaitNewer(snapshot->sequence, std::chrono::milliseconds(100));
    }
    slam::server::HttpOptions http;
    open = std::make_unique<slam::server::HttpServer>(*service, *link, *jobs, http);
    http.token = kToken;
    guarded = std::make_unique<slam::server::HttpServer>(*service, *link, *jobs, http);
  }
};

Slamd& Instance() {
  static Slamd* slamd = new Slamd();  // never destroyed: the fuzzer exits from anywhere
  return *slamd;
}

/// The status code of a raw response, or -1 if it is not one HTTP/1.1 status line.
int StatusOf(const std::string& response) {
  if (response.compare(0, 9, "HTTP/1.1 ") != 0 || response.size() < 12) return -1;
  int code = 0;
  for (size_t i = 9; i < 12; ++i) {
    if (response[i] < '0' || response[i] > '9') return -1;
    code = code * 10 + (response[i] - '0');
  }
  return code;
}

/// `text` with every %XX escape decoded.
std::string Decoded(const std::string& text) {
  std::string out;
  for (size_t i = 0; i < text.size(); ++i) {
    if (text[i] == '%' && i + 2 < text.size() &&
        std::isxdigit(static_cast<unsigned char>(text[i + 1])) &&
        std::isxdigit(static_cast<unsigned char>(text[i + 2]))) {
      out += static_cast<char>(std::stoi(text.substr(i + 1, 2), nullptr, 16));
      i += 2;
    } else {
      out += text[i];
    }
  }
  return out;
}

std::string HeaderOf(const std::string& response, const std::string& name) {
  const size_t end = response.find("\r\n\r\n");
  const std::string head = response.substr(0, end);
  const std::string key = "\r\n" + name + ": ";
  const size_t at = head.find(key);
  if (at == std::string::npos) return "";
  const size_t from = at + key.size();
  return head.substr(from, head.find("\r\n", from) - from);
}

std::string BodyOf(const std::string& response) {
  const size_t end = response.find("\r\n\r\n");
  return end == std::string::npos ? "" : response.substr(end + 4);
}

std::string Request(const std::string& head, const std::string& type, const std::string& body,
                    bool token) {
  std::string r = head + " HTTP/1.1\r\nHost: 127.0.0.1\r\n";
  if (!type.empty()) r += "Content-Type: " + type + "\r\n";
  if (token) r += std::string("Authorization: Bearer ") + kToken + "\r\n";
  return r + "Content-Length: " + std::to_string(body.size()) + "\r\n\r\n" + body;
}

void CheckResponse(const std::string& request, const std::string& response) {
  // Without a single line there is no request: httplib closes the connection unanswered.
  if (request.find('\n') == std::string::npos && response.empty()) return;
  const int status = StatusOf(response);
  Check(status >= 100 && status <= 599, "no HTTP/1.1 status line in the response");
  Check(status != 500, "a handler failed with 500");
  const bool head = request.rfind("HEAD ", 0) == 0;  // headers only, no body
  if (!head && HeaderOf(response, "Content-Type").rfind("application/problem+json", 0) == 0) {
    const nlohmann::json problem = nlohmann::json::parse(BodyOf(response), nullptr, false);
    Check(problem.is_object(), "a problem+json body is not a JSON object");
    Check(problem.contains("status") && problem["status"].is_number_integer() &&
              problem["status"].get<int>() == status,
          "a problem's status differs from the response's");
  }
}

/// The budget and the parameters read back, and are accepted again as they are.
void CheckSettingsRoundTrip(slam::server::HttpServer& server, bool token) {
  for (const char* what : {"budget", "params"}) {
    const std::string path = std::string("/api/v1/") + what;
    const std::string got = server.HandleInMemory(Request("GET " + path, "", "", false));
    Check(StatusOf(got) == 200, "GET of the settings failed");
    const nlohmann::json settings = nlohmann::json::parse(BodyOf(got), nullptr, false);
    Check(settings.is_object(), "the settings are not a JSON object");
    const std::string again =
        what == std::string("budget")
            ? server.HandleInMemory(
                  Request("PUT " + path, "application/json", settings.dump(), token))
            : server.HandleInMemory(
                  Request("PATCH " + path, "application/merge-patch+json", settings.dump(), token));
    Check(StatusOf(again) == 200, "the server refuses its own settings back");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  Slamd& slamd = Instance();
  const bool token = (data[0] & 1) != 0;
  slam::server::HttpServer& server = token ? *slamd.guarded : *slamd.open;
  const std::string rest(reinterpret_cast<const char*>(data + 1), size - 1);

  std::string request;
  switch ((data[0] >> 1) % 8) {
    case 0:
      request = Request("PATCH /api/v1/budget", "application/merge-patch+json", rest, token);
      break;
    case 1:
      request = Request("PUT /api/v1/budget", "application/json", rest, token);
      break;
    case 2:
      request = Request("PATCH /api/v1/params", "application/merge-patch+json", rest, token);
      break;
    case 3:
      request = Request("POST /api/v1/jobs/tune", "application/json", rest, token);
      break;
    case 4:
      request = Request("POST /api/v1/map/save", "application/json", rest, token);
      break;
    default:
      request = rest;
      break;  // the whole request
  }
  // The event stream and reset wait on the SLAM thread by design (percent escapes decoded, as
  // the router sees the path).
  const std::string line = Decoded(request.substr(0, request.find('\n')));
  if (line.find("events") != std::string::npos || line.find("reset") != std::string::npos) {
    return 0;
  }
  CheckResponse(request, server.HandleInMemory(request));
  CheckSettingsRoundTrip(server, token);
  return 0;
}
