#pragma once
// slamd's HTTP server (docs/design.md section 7, docs/http-api.md): REST control of the budget and
// the parameters, map tiles and whole-map exports, the event stream, tuning jobs, /metrics and the
// web page. Built on Debian's cpp-httplib 0.11.4 with every pitfall of
// docs/design.md appendix C handled: a sized thread pool, a cap on event streams,
// providers that wake up to notice disconnects, a short keep-alive, body limits enforced before
// the body is read (chunked and compressed bodies refused), no brotli, no SO_REUSEPORT.

#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

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

/// True for 127.0.0.0/8, ::1 and "localhost".
bool IsLoopback(const std::string& address);

/// The host of a Host header value without its port: "[::1]:8080" -> "::1", "a:80" -> "a".
std::string HostName(const std::string& host_header);

/// True for an IPv4 or IPv6 address (without brackets).
bool IsIpAddress(const std::string& host);

/// Whether the page's static handler may serve `path` (decoded): not the npm folder, the npm
/// manifests or a hidden file, at any depth.
bool IsPublicWebPath(std::string_view path);

/// Whether an If-Match or If-None-Match value (a list of entity tags, or "*") matches `etag`
/// (RFC 9110 13.1): If-None-Match compares weakly (W/"1" matches "1"), If-Match strongly (a
/// weak tag matches nothing). An empty list matches nothing.
bool EntityTagListMatches(std::string_view list, std::string_view etag, bool weak);

/// What makes a request head (request line and header lines as received, CRLF-separated, up to
/// the blank line) ambiguous to read, or nothing (RFC 9112): a header line folded onto the
/// previous one, a header line without a colon, a field name that is not a token (whitespace
/// before the colon: "Transfer-Encoding : chunked" is one header to one parser and none to
/// another), more than one Content-Length, an HTTP/1.1 request without exactly one Host. Two
/// parsers reading such a request differently is how a request is smuggled inside another.
std::optional<std::string> AmbiguousFraming(std::string_view head);

/// Constant-time comparison (the time does not depend on where the strings differ).
bool ConstantTimeEquals(const std::string& a, const std::string& b);

class HttpServer {
 public:
  HttpServer(SlamService& service, hw::Link& link, JobManager& jobs, const HttpOptions& options);
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  /// Binds the listening socket; the port (useful with port 0), or -1 with `error` set.
  int Bind(std::string& error);
  /// Serves until Stop (call Bind first).
  void Run();
  /// Stops serving (from any thread); event streams end within half a second.
  void Stop();

  /// Saves the newest snapshot into --state-dir as POST /api/v1/map/save does (one save at a
  /// time): for the save at a clean stop.
  SaveOutcome SaveMap();

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
