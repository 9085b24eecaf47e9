#pragma once
// slamd's HTTP server (docs/design.md section 7, docs/http-api.md): REST control of the budget and
// the parameters, map tiles and whole-map exports, the event stream, tuning jobs, /metrics and the
// web page. Built on Debian's cpp-httplib 0.11.4 with every pitfall of
// docs/design.md appendix C handled: a sized thread pool, a cap on event streams,
// providers that wake up to notice disconnects, a short keep-alive, body limits enforced before
// the body is read (chunked and compressed bodies refused), no brotli, no SO_REUSEPORT.

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "engine/result.hpp"
#include "hw_link/link.hpp"
#include "server/slam_service.hpp"
#include "server/state_store.hpp"
#include "server/tune_jobs.hpp"

namespace slam::server {

struct HttpOptions {
  std::string bind = "127.0.0.1";
  int port = 8080;        // 0: any free port
  std::string token;      // empty: mutating routes are open (loopback only)
  std::string web_root;   // the page; empty: none
  std::string state_dir;  // empty: map/save is refused (409)
  int max_streams = 16;   // concurrent event streams; 503 beyond
  size_t max_body_bytes = 64 * 1024;
  std::string source_spec;  // as given on the command line
  /// Without a token, the Host names slamd answers besides loopback ones (a reverse proxy's).
  std::vector<std::string> allowed_hosts;
};

class HttpServer {
 public:
  HttpServer(SlamService& service, hw::Link& link, JobManager& jobs, const HttpOptions& options);
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  /// Binds the listening socket; the port (useful with port 0).
  Result<int> Bind();
  /// Serves until Stop (call Bind first).
  void Run();
  /// Stops serving (from any thread); event streams end within half a second.
  void Stop();

  /// Saves the newest snapshot into --state-dir as POST /api/v1/map/save does (one save at a
  /// time): for the save at a clean stop.
  Result<SaveReport> SaveMap();

  /// Adds text (Prometheus exposition format, whole metric families) that /metrics appends to
  /// its own: another front end's metrics. Call before Run.
  void AddMetrics(std::function<std::string()> metrics);

  /// Serves one raw HTTP/1.1 request held in memory, exactly as one arriving on a connection
  /// that closes after it (parser, limits, token, routes, handlers), and returns the raw
  /// response, cut at `max_response_bytes` (an event stream ends there). No Bind or Run needed;
  /// safe beside Run. For the fuzzer (fuzz/fuzz_http.cpp) and tests.
  std::string HandleInMemory(std::string_view request, size_t max_response_bytes = 1 << 20);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace slam::server
