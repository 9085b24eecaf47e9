#include "server/access_policy.hpp"

#include <algorithm>

#include "server/api_json.hpp"
#include "server/request_guard.hpp"

namespace slam::server {

std::optional<AccessPolicy::Refusal> AccessPolicy::CheckHost(const std::string& host_header) const {
  const std::string host = Lower(HostName(host_header));
  if (IsLoopback(host) || IsIpAddress(host) ||
      std::find(allowed_hosts_.begin(), allowed_hosts_.end(), host) != allowed_hosts_.end()) {
    return std::nullopt;
  }
  return Refusal{403, "Forbidden",
                 "slamd answers only to loopback names (localhost, 127.0.0.1, [::1]), IP "
                 "addresses and --allow-host names, not to '" +
                     host + "'",
                 ""};
}

std::optional<AccessPolicy::Refusal> AccessPolicy::CheckToken(
    const std::string& authorization) const {
  if (token_.empty()) return std::nullopt;
  if (authorization.empty()) {
    return Refusal{401, "Unauthorized", "a token is configured: send Authorization: Bearer <token>",
                   "Bearer realm=\"slamd\""};
  }
  const std::string prefix = "bearer ";
  if (Lower(authorization.substr(0, prefix.size())) != prefix ||
      !ConstantTimeEquals(authorization.substr(std::min(prefix.size(), authorization.size())),
                          token_)) {
    return Refusal{401, "Unauthorized", "wrong token",
                   "Bearer realm=\"slamd\", error=\"invalid_token\""};
  }
  return std::nullopt;
}

bool AccessPolicy::SameOrigin(const std::string& origin, const std::string& host_header) {
  std::string origin_host = origin;
  if (const size_t scheme = origin.find("://"); scheme != std::string::npos) {
    origin_host = origin.substr(scheme + 3);
  }
  return Lower(origin_host) == Lower(host_header);
}

}  // namespace slam::server
