#pragma once
// What slamd checks of a request before any route sees it (HttpServer's pre-routing guard, in
// request_guard.cpp, applies these): loopback and Host names against DNS rebinding, the
// token's constant-time comparison, paths the page may serve, entity tags of conditional
// requests, and request heads whose framing two parsers could read differently.

#include <optional>
#include <string>
#include <string_view>

#include "engine/result.hpp"
#include "server/http_library.hpp"

namespace slam::server {

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

/// Checks that a request head (request line and header lines as received, CRLF-separated, up to
/// the blank line) reads one way only (RFC 9112); the error says what makes it ambiguous: a
/// header line folded onto the
/// previous one, a header line without a colon, a field name that is not a token (whitespace
/// before the colon: "Transfer-Encoding : chunked" is one header to one parser and none to
/// another), more than one Content-Length, an HTTP/1.1 request without exactly one Host. Two
/// parsers reading such a request differently is how a request is smuggled inside another.
Result<void> CheckFraming(std::string_view head);

/// Constant-time comparison (the time does not depend on where the strings differ).
bool ConstantTimeEquals(const std::string& a, const std::string& b);

/// Calls `visit(line)` for each field line of a request head as received (the lines after the
/// request line, up to the blank line or the end of what arrived), until it returns false.
template <typename Visit>
void ForEachFieldLine(std::string_view head, Visit visit) {
  size_t line_end = head.find("\r\n");
  if (line_end == std::string_view::npos) return;
  for (size_t at = line_end + 2; at < head.size(); at = line_end + 2) {
    line_end = head.find("\r\n", at);
    if (line_end == std::string_view::npos) line_end = head.size();
    const std::string_view line = head.substr(at, line_end - at);
    if (line.empty() || !visit(line)) return;
  }
}

/// Whether a field line names `name` (case-insensitive), with the colon right after it.
bool FieldNameIs(std::string_view line, std::string_view name);

/// Whether the request head as received has a `name` field: httplib drops fields whose value is
/// empty ("If-Match:" must still fail the precondition, not skip it).
bool HeadHasField(const httplib::Request& req, std::string_view name);

}  // namespace slam::server
