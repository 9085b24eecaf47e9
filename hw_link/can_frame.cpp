#include "hw_link/can_frame.hpp"

#include <algorithm>
#include <chrono>

namespace slam::hw {

bool operator==(const CanFrame& a, const CanFrame& b) {
  if (a.id != b.id || a.len != b.len || a.extended != b.extended || a.remote != b.remote ||
      a.fd != b.fd) {
    return false;
  }
  if (a.remote) return true;
  const auto n = std::min<size_t>(a.len, kCanFdMaxData);
  return std::equal(a.data.begin(), a.data.begin() + static_cast<std::ptrdiff_t>(n),
                    b.data.begin());
}

std::string FormatCompact(const CanFrame& frame) {
  static constexpr char kHex[] = "0123456789ABCDEF";
  std::string out;
  const int id_digits = frame.extended ? 8 : 3;
  for (int i = id_digits - 1; i >= 0; --i) out += kHex[(frame.id >> (4 * i)) & 0xF];
  out += '#';
  if (frame.remote) {
    out += 'R';
    return out;
  }
  if (frame.fd) {
    out += '#';
    out += '0';  // FD flags nibble: we keep none
  }
  const int n = std::min<int>(frame.len, kCanFdMaxData);
  for (int i = 0; i < n; ++i) {
    out += kHex[frame.data[static_cast<size_t>(i)] >> 4];
    out += kHex[frame.data[static_cast<size_t>(i)] & 0xF];
  }
  return out;
}

int64_t SteadyNowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

}  // namespace slam::hw
