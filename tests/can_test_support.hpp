#pragma once
// CAN frames built by hand, shared by the hw_link test suites.

#include <algorithm>
#include <cstdint>
#include <vector>

#include "hw_link/can_frame.hpp"

namespace slam::testing {

/// A data frame with these bytes.
inline hw::CanFrame Frame(uint32_t id, std::vector<uint8_t> data, bool extended = false,
                          bool fd = false) {
  hw::CanFrame f;
  f.id = id;
  f.extended = extended;
  f.fd = fd;
  f.len = static_cast<uint8_t>(data.size());
  std::copy(data.begin(), data.end(), f.data.begin());
  return f;
}

/// A remote frame requesting `len` bytes.
inline hw::CanFrame Remote(uint32_t id, uint8_t len, bool extended = false) {
  hw::CanFrame f;
  f.id = id;
  f.len = len;
  f.extended = extended;
  f.remote = true;
  return f;
}

}  // namespace slam::testing
