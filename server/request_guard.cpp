#include "server/request_guard.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>

#include <algorithm>
#include <cctype>
#include <cstdio>

#include "server/api_json.hpp"
#include "server/bounded_server.hpp"
#include "server/http_server_impl.hpp"

namespace slam::server {

bool FieldNameIs(std::string_view line, std::string_view name) {
  return line.size() > name.size() && line[name.size()] == ':' &&
         std::equal(name.begin(), name.end(), line.begin(), [](char a, char b) {
           return std::tolower(static_cast<unsigned char>(a)) ==
                  std::tolower(static_cast<unsigned char>(b));
         });
}

bool HeadHasField(const httplib::Request& req, std::string_view name) {
  if (req.has_header(std::string(name).c_str())) return true;
  const std::string* head = RequestHeadAsReceived();
  if (head == nullptr) return false;
  bool found = false;
  ForEachFieldLine(*head, [&](std::string_view line) {
    found = FieldNameIs(line, name);
    return !found;
  });
  return found;
}

bool IsLoopback(const std::string& address) {
  if (address == "localhost" || address == "::1") return true;
  in_addr v4{};
  if (inet_pton(AF_INET, address.c_str(), &v4) == 1) return (ntohl(v4.s_addr) >> 24) == 127;
  return false;
}

std::string HostName(const std::string& host_header) {
  if (!host_header.empty() && host_header.front() == '[') {
    const size_t close = host_header.find(']');
    return close == std::string::npos ? host_header : host_header.substr(1, close - 1);
  }
  const size_t colon = host_header.find(':');
  // More than one colon: an IPv6 address without brackets (no port can be told from it).
  if (colon == std::string::npos || host_header.find(':', colon + 1) != std::string::npos) {
    return host_header;
  }
  return host_header.substr(0, colon);
}

bool IsIpAddress(const std::string& host) {
  in_addr v4{};
  in6_addr v6{};
  return inet_pton(AF_INET, host.c_str(), &v4) == 1 || inet_pton(AF_INET6, host.c_str(), &v6) == 1;
}

bool IsPublicWebPath(std::string_view path) {
  size_t at = 0;
  while (at < path.size()) {
    while (at < path.size() && path[at] == '/') ++at;
    const size_t end = std::min(path.find('/', at), path.size());
    const std::string_view segment = path.substr(at, end - at);
    if (segment.starts_with('.') || segment == "node_modules" || segment == "package.json" ||
        segment == "package-lock.json") {
      return false;
    }
    at = end;
  }
  return true;
}

bool EntityTagListMatches(std::string_view list, std::string_view etag, bool weak) {
  const auto trim = [](std::string_view s) {
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
    return s;
  };
  const auto opaque = [](std::string_view tag, bool& is_weak) {
    is_weak = tag.starts_with("W/");
    if (is_weak) tag.remove_prefix(2);
    return tag;
  };
  bool etag_weak = false;
  const std::string_view ours = opaque(etag, etag_weak);
  for (size_t at = 0; at <= list.size();) {
    const size_t comma = std::min(list.find(',', at), list.size());
    const std::string_view item = trim(list.substr(at, comma - at));
    at = comma + 1;
    if (item.empty()) continue;
    if (item == "*") return true;
    bool item_weak = false;
    const std::string_view theirs = opaque(item, item_weak);
    if (theirs == ours && (weak || (!item_weak && !etag_weak))) return true;
  }
  return false;
}

Result<void> CheckFraming(std::string_view head) {
  const auto is_token_char = [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) != 0 ||
           std::string_view("!#$%&'*+-.^_`|~").find(c) != std::string_view::npos;
  };
  // Control characters but HTAB: a CR not before LF (a bare CR), an LF not after CR, a NUL.
  // Parsers end lines and values at different ones, or keep them in a value passed on.
  const auto control_in = [](std::string_view text) -> std::optional<std::string> {
    for (const char c : text) {
      const auto byte = static_cast<unsigned char>(c);
      if ((byte < 0x20 && c != '\t') || byte == 0x7f) {
        char hex[8];
        std::snprintf(hex, sizeof(hex), "0x%02X", byte);
        return std::string(byte == '\r'   ? "a bare CR"
                           : byte == '\n' ? "a bare LF"
                           : byte == 0    ? "a NUL"
                                          : "the control character " + std::string(hex));
      }
    }
    return std::nullopt;
  };
  const size_t line_end = head.find("\r\n");
  if (line_end == std::string_view::npos) return {};  // the parser judges it
  const std::string_view request_line = head.substr(0, line_end);
  if (const auto control = control_in(request_line)) {
    return Error(*control + " in the request line");
  }
  const bool http11 = request_line.ends_with(" HTTP/1.1");
  int content_lengths = 0, hosts = 0;
  std::optional<std::string> problem;
  ForEachFieldLine(head, [&](std::string_view line) {
    if (const auto control = control_in(line)) {
      problem = *control + " in the header line '" +
                std::string(line.substr(0, std::min<size_t>(line.find(':'), 64))) + "'";
      return false;
    }
    if (line.front() == ' ' || line.front() == '\t') {
      problem = "a header line folded onto the previous one (obsolete line folding)";
      return false;
    }
    const size_t colon = line.find(':');
    if (colon == std::string_view::npos) {
      problem = "a header line without a colon";
      return false;
    }
    const std::string_view name = line.substr(0, colon);
    if (name.empty() || !std::all_of(name.begin(), name.end(), is_token_char)) {
      problem = "the header name '" + std::string(name.substr(0, 64)) +
                "' is not a token (no whitespace before the colon)";
      return false;
    }
    if (FieldNameIs(line, "content-length")) {
      ++content_lengths;
      // 1*DIGIT between optional whitespace (RFC 9110 8.6): "+2", "2, 2" or "0x2" read as a
      // number by one parser and refused or read otherwise by another.
      std::string_view value = line.substr(colon + 1);
      while (!value.empty() && (value.front() == ' ' || value.front() == '\t'))
        value.remove_prefix(1);
      while (!value.empty() && (value.back() == ' ' || value.back() == '\t'))
        value.remove_suffix(1);
      if (value.empty() || !std::all_of(value.begin(), value.end(), [](char c) {
            return std::isdigit(static_cast<unsigned char>(c)) != 0;
          })) {
        problem = "a Content-Length that is not a decimal number ('" +
                  std::string(value.substr(0, 32)) + "')";
        return false;
      }
    }
    hosts += FieldNameIs(line, "host");
    return true;
  });
  if (problem) return Error(*problem);
  if (content_lengths > 1) return Error("more than one Content-Length");
  if (http11 && hosts != 1) {
    return Error(hosts == 0 ? "a request of HTTP version 1.1 needs a Host header"
                            : "more than one Host header");
  }
  return {};
}

bool ConstantTimeEquals(const std::string& a, const std::string& b) {
  // Walk the longer length whatever the contents, so that the time reveals nothing but it.
  const size_t n = std::max(a.size(), b.size());
  unsigned char diff = a.size() == b.size() ? 0 : 1;
  for (size_t i = 0; i < n; ++i) {
    const unsigned char x = i < a.size() ? static_cast<unsigned char>(a[i]) : 0;
    const unsigned char y = i < b.size() ? static_cast<unsigned char>(b[i]) : 0;
    diff = static_cast<unsigned char>(diff | (x ^ y));
  }
  return diff == 0;
}

httplib::Server::HandlerResponse HttpServer::Impl::Guard(httplib::Request& req,
                                                         httplib::Response& res) {
  using R = httplib::Server::HandlerResponse;
  // Brotli at maximum quality costs far more CPU than it saves on loopback or a robot's Wi-Fi;
  // gzip is cheap. (docs/design.md appendix C, point 7)
  if (auto it = req.headers.find("Accept-Encoding"); it != req.headers.end()) {
    if (Lower(it->second).find("br") != std::string::npos) it->second = "gzip";
  }
  // Ranges: httplib builds a multipart answer to many ranges whole in memory (4000 ranges in an
  // 8 KB header made 600 MB of one 150 KB file), and answers a range of a handler's response
  // with 200 and a truncated body. The page's files honour one range; more than one, or a range
  // of anything else, is ignored and the whole answer sent (a server may, RFC 9110 14.2).
  if (!req.ranges.empty() &&
      (req.ranges.size() > 1 || req.path.rfind("/api/", 0) == 0 || req.path == "/metrics")) {
    req.ranges.clear();
    req.headers.erase("Range");
  }
  // The trajectory is made once per snapshot (ServeExport) but httplib would compress its TUM
  // text again for every request, at a cost growing with the run: it goes out as it is.
  if (req.path == "/api/v1/trajectory") req.headers.erase("Accept-Encoding");
  const bool mutating = req.method == "POST" || req.method == "PUT" || req.method == "PATCH" ||
                        req.method == "DELETE";
  const bool bodied = req.method == "POST" || req.method == "PUT" || req.method == "PATCH";
  const auto refuse = [&](int status, const std::string& title, const std::string& detail) {
    SendProblem(res, status, title, detail);
    // The body (if any) is not read: the connection cannot carry another request. Both are
    // needed: the header tells the client, the flag makes the connection loop close.
    res.set_header("Connection", "close");
    CloseConnectionAfterResponse();
    return R::Handled;
  };
  // A request whose framing parsers may read differently: 400, and the connection closes (what
  // follows on it may be a request hidden in this one).
  if (const std::string* head = RequestHeadAsReceived(); head != nullptr) {
    if (const Result<void> framing = CheckFraming(*head); !framing.ok()) {
      return refuse(400, "Bad Request", framing.Message());
    }
  }
  if (req.has_header("Host")) {
    if (const auto refusal = access.CheckHost(req.get_header_value("Host"))) {
      return refuse(refusal->status, refusal->title, refusal->detail);
    }
  }
  // A path that decodes to a control character (a NUL: /index.html%00.js served index.html as
  // JavaScript) names no file of ours; nor do the page's npm folder and manifests, or hidden
  // files (GET /node_modules/... served the page's development tools).
  if (std::any_of(req.path.begin(), req.path.end(),
                  [](char c) { return static_cast<unsigned char>(c) < 0x20 || c == 0x7f; })) {
    return refuse(400, "Bad Request", "the path holds a control character");
  }
  if (req.path.rfind("/api/", 0) != 0 && !IsPublicWebPath(req.path)) {
    SendProblem(res, 404, "Not Found", "no such page file");
    return R::Handled;
  }
  // Body limits before the body is read: the library's own limit does not bound chunked or
  // compressed bodies (notes point 5), and a POST without a length would hang (point 6).
  if (req.has_header("Transfer-Encoding")) {
    return refuse(411, "Length Required",
                  "request bodies must have a Content-Length; chunked bodies are refused");
  }
  if (req.has_header("Content-Encoding")) {
    return refuse(415, "Unsupported Media Type", "compressed request bodies are refused");
  }
  if (bodied && !req.has_header("Content-Length")) {
    return refuse(411, "Length Required", "a request body with a Content-Length is required");
  }
  if (req.has_header("Content-Length")) {
    const std::string value = req.get_header_value("Content-Length");
    char* end = nullptr;
    const unsigned long long length = std::strtoull(value.c_str(), &end, 10);
    if (value.empty() || *end != '\0' || value[0] == '-') {
      return refuse(400, "Bad Request", "bad Content-Length");
    }
    // httplib reads the body of POST, PUT, PATCH and DELETE only: another method's body would
    // be parsed as the next request on the connection.
    if (length > 0 && !bodied && req.method != "DELETE") {
      return refuse(400, "Bad Request", "a " + req.method + " request may not have a body");
    }
    if (length > options.max_body_bytes) {
      return refuse(
          413, "Content Too Large",
          "request bodies are limited to " + std::to_string(options.max_body_bytes) + " bytes");
    }
  }
  if (mutating) {
    if (const auto refusal = access.CheckToken(req.get_header_value("Authorization"))) {
      res.set_header("WWW-Authenticate", refusal->challenge);
      return refuse(refusal->status, refusal->title, refusal->detail);
    }
    // A page from another site must not drive the robot through the user's browser.
    if (req.has_header("Origin") &&
        !AccessPolicy::SameOrigin(req.get_header_value("Origin"), req.get_header_value("Host"))) {
      return refuse(403, "Forbidden", "cross-origin requests may not change slamd");
    }
  }
  return R::Unhandled;
}

}  // namespace slam::server
