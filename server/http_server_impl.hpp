#pragma once
// HttpServer's state, shared by its parts inside server/ (not for other modules): the routes
// and handlers (http_server.cpp), the request guard (request_guard.cpp) and the event stream
// (event_stream.cpp), over the bounded server (bounded_server.hpp).

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <regex>
#include <string>
#include <utility>
#include <vector>

#include "engine/thread_safety.hpp"
#include "server/access_policy.hpp"
#include "server/bounded_server.hpp"
#include "server/http_library.hpp"
#include "server/http_server.hpp"
#include "server/http_state.hpp"

namespace slam::server {

using json = nlohmann::json;
using Clock = std::chrono::steady_clock;

inline constexpr auto kStreamWake =
    std::chrono::milliseconds(250);  // <= 0.5 s: disconnects noticed
inline constexpr double kTilesEverySeconds = 0.5;
inline constexpr double kPoseEverySeconds = 0.25;
inline constexpr double kPingEverySeconds = 10.0;

inline double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

struct TileKey {
  int32_t x, y;
  friend bool operator<(const TileKey& a, const TileKey& b) {
    return a.x != b.x ? a.x < b.x : a.y < b.y;
  }
};

struct HttpServer::Impl {
  SlamService& service;
  hw::Link& link;
  JobManager& jobs;
  HttpOptions options;
  AccessPolicy access{options.token, options.allowed_hosts};
  BoundedServer server;
  Clock::time_point started = Clock::now();
  // Tells one run of slamd from the next (the page reloads everything when it changes).
  std::string instance = std::to_string(std::chrono::system_clock::now().time_since_epoch() /
                                        std::chrono::microseconds(1));
  std::atomic<bool> stopping{false};
  std::atomic<int> streams{0};
  std::atomic<uint64_t> streams_rejected{0};

  SaveCoordinator saves{service, options.state_dir};
  // A reset request waiting for the SLAM thread to apply its reset (at most one: see HandleReset).
  std::atomic<bool> reset_waiting{false};
  ExportCache exports{service,
                      {"map.pgm", "map.yaml", "map.png", "trajectory.tum", "trajectory.json"}};
  TileCache tile_pngs;
  RequestCounter requests;

  Impl(SlamService& s, hw::Link& l, JobManager& j, const HttpOptions& o)
      : service(s), link(l), jobs(j), options(o) {}

  static std::string BudgetEtag(uint64_t revision) {
    return "\"b" + std::to_string(revision) + "\"";
  }
  static std::string ParamsEtag(uint64_t revision) {
    return "\"p" + std::to_string(revision) + "\"";
  }

  /// The server's settings and handlers, then every route (the Add* below, in order).
  void Setup();
  void AddStateRoutes();
  void AddMapRoutes();
  void AddJobRoutes();
  void AddPageAndFallback();
  /// Registers a route's handler for `method` ("GET", "POST", "PUT", "PATCH" or "DELETE"), and
  /// makes its pattern a known route, which answers 405 with Allow to other methods.
  void Route(const std::string& method, const std::string& pattern,
             httplib::Server::Handler handler);
  struct KnownRoute {
    std::string pattern;
    std::regex regex;
    std::string allow;  // "GET, PATCH, PUT": its methods, in the order registered
  };
  std::vector<KnownRoute> routes;  // written by Setup only, before the server starts
  httplib::Server::HandlerResponse Guard(httplib::Request& req, httplib::Response& res);
  bool ParseBody(const httplib::Request& req, httplib::Response& res, const char* media, json& out);
  /// PUT (a whole budget) or PATCH (`patch`: a merge patch) of the budget, through
  /// SlamService::ChangeBudget, conditional on If-Match.
  void HandleBudgetChange(const httplib::Request& req, httplib::Response& res, bool patch);
  void HandleParamsPatch(const httplib::Request& req, httplib::Response& res);
  void HandleTile(const httplib::Request& req, httplib::Response& res);
  /// GET /api/v1/events: a stream of Server-Sent Events per client (event_stream.cpp), each
  /// wake-up sending what changed for it: the hello, the map's reset, tiles, pose and metrics,
  /// the budget, parameters and jobs, the link's and SLAM's states.
  void HandleEvents(const httplib::Request& req, httplib::Response& res);
  struct EventStream;
  std::string HelloEvents(EventStream& s, const SlamSnapshot& snapshot, Clock::time_point now);
  std::string MapEvents(EventStream& s, const SlamSnapshot& snapshot, Clock::time_point now);
  std::string SettingsEvents(EventStream& s);
  std::string StatusEvents(EventStream& s);
  void HandleSave(httplib::Response& res);
  void HandleReset(httplib::Response& res);
  json StatusJson();
  json SourceJson(const std::string& description) {
    return {{"spec", options.source_spec},
            {"description", description},
            {"simulated", service.simulated()}};
  }
  std::string MetricsText();
  Mutex extra_metrics_mutex;
  std::vector<std::function<std::string()>> extra_metrics SLAM_GUARDED_BY(extra_metrics_mutex);
};

}  // namespace slam::server
