#pragma once
// Which connection gives way when one more arrives: the rule of slamd's Foxglove port, in the
// shape of the HTTP gate's (server/bounded_server.cpp: at most so many waiting connections per
// address, the oldest of that address closed first), kept free of sockets so that it is tested
// on its own (tests/slamd_foxglove_hardening_test.cpp).
//
// Connections are grouped by the client's address: one address holds at most `per_address`
// connections, all addresses together at most `total`. A newcomer beyond its address's cap
// displaces the oldest connection of its own address; beyond the total only, the oldest of the
// address that holds the most (its own on a tie), so a client from an address with fewer
// connections always gets in, whatever one address holds. Each connection has a rank (on the
// Foxglove port, 0 for a page of another site that may only watch, 1 for a client that may change
// the budget): the lowest rank gives way first, and a newcomer never displaces a connection of a
// higher rank than its own; it is refused when only such connections could make room.

#include <chrono>
#include <cstddef>
#include <optional>
#include <set>
#include <span>
#include <string_view>
#include <unordered_map>

namespace slam::server {

/// A connection already held, as the admission rule sees it.
struct HeldConnection {
  std::string_view address;                       // the client's IP address, as text
  std::chrono::steady_clock::time_point since{};  // accepted (older ones give way first)
  int rank = 0;                                   // lower ranks give way first
};

/// The caps; both at least 1.
struct AdmissionLimits {
  size_t per_address = 1;
  size_t total = 1;
};

/// What to do with a newcomer.
struct Admission {
  bool admit = true;
  std::optional<size_t> evict;  // the index in `held` to close first, when admitted
};

/// Whether a newcomer from `address` of rank `rank` is admitted beside `held`, and which one of
/// them is closed to make room (the rule above).
inline Admission Admit(std::span<const HeldConnection> held, std::string_view address, int rank,
                       AdmissionLimits limits) {
  std::unordered_map<std::string_view, size_t> per_address;
  for (const HeldConnection& c : held) ++per_address[c.address];
  const bool address_full = per_address[address] >= limits.per_address;
  if (!address_full && held.size() < limits.total) return {};
  std::set<int> ranks;  // the ranks this newcomer may displace, lowest first
  for (const HeldConnection& c : held) {
    if (c.rank <= rank) ranks.insert(c.rank);
  }
  for (const int r : ranks) {
    // The address that gives way: the newcomer's own at its cap, else the one holding the most
    // connections among those with one of this rank.
    std::string_view from = address;
    if (!address_full) {
      size_t most = 0;
      for (const HeldConnection& c : held) {
        const size_t n = per_address[c.address];
        if (c.rank == r && (n > most || (n == most && c.address == address))) {
          most = n;
          from = c.address;
        }
      }
    }
    std::optional<size_t> oldest;
    for (size_t i = 0; i < held.size(); ++i) {
      if (held[i].rank == r && held[i].address == from &&
          (!oldest || held[i].since < held[*oldest].since)) {
        oldest = i;
      }
    }
    if (oldest) return {true, oldest};
  }
  return {false, std::nullopt};
}

}  // namespace slam::server
