#pragma once
// Who may reach slamd and who may change it: the same rules for the HTTP server (its request
// guard, request_guard.cpp) and the Foxglove WebSocket server (its upgrade).
//
// - Host names: loopback names, IP addresses and --allow-host names only, with a token or
//   without. A page whose own name an attacker makes resolve to slamd's address (DNS
//   rebinding) is same-origin with itself, so the Origin check lets it through, and the token
//   guards only changes: it would read the map, the trajectory and the events. Its requests name
//   its host, which is none of these. (An address cannot be rebound: a page at
//   http://192.168.1.5/ is one the user opened.)
// - A token, when one is configured: "Authorization: Bearer <token>" (the scheme
//   case-insensitive, RFC 7235; the token compared in constant time) for every change.
// - Without a token: a page of another site (any page the user has open can reach 127.0.0.1)
//   may not change slamd; its Origin names another host than the request's.

#include <optional>
#include <string>
#include <vector>

namespace slam::server {

class AccessPolicy {
 public:
  /// `token` empty: none configured. `allowed_hosts`: lower-case names beyond loopback and IPs.
  AccessPolicy(std::string token, std::vector<std::string> allowed_hosts)
      : token_(std::move(token)), allowed_hosts_(std::move(allowed_hosts)) {}

  /// Why a request is refused: an HTTP status, its reason phrase, what to tell the client and,
  /// for 401, the WWW-Authenticate challenge.
  struct Refusal {
    int status = 403;
    std::string title;
    std::string detail;
    std::string challenge;
  };

  /// The Host header's name (`host_header` as received, port and all).
  std::optional<Refusal> CheckHost(const std::string& host_header) const;
  /// The Authorization header's value (empty when absent) for a change; none configured: none.
  std::optional<Refusal> CheckToken(const std::string& authorization) const;
  bool has_token() const { return !token_.empty(); }

  /// Whether an Origin header's value names the host a request was sent to (its Host header),
  /// case-insensitively, the scheme aside.
  static bool SameOrigin(const std::string& origin, const std::string& host_header);

 private:
  std::string token_;
  std::vector<std::string> allowed_hosts_;
};

}  // namespace slam::server
