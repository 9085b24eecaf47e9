#pragma once
// CAN frames over UDP in cannelloni's format (big-endian): a header (version 2, op code 0 =
// data, 8-bit sequence number, 16-bit frame count), then per frame a 4-byte Linux can_id
// (0x80000000 extended, 0x40000000 remote, 0x20000000 error frame), a length byte (0x80 = CAN
// FD, then one flags byte) and the data (none for remote frames).

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "engine/result.hpp"
#include "hw_link/can_frame.hpp"

namespace slam::hw {

inline constexpr uint8_t kCannelloniVersion = 2;
inline constexpr uint8_t kCannelloniOpData = 0;

struct CannelloniDatagram {
  uint8_t sequence = 0;
  std::vector<CanFrame> frames;
};

/// The datagram carrying `frames`. Precondition: frames.size() <= 65535.
std::vector<uint8_t> EncodeCannelloni(uint8_t sequence, std::span<const CanFrame> frames);

/// The datagram, or a one-line reason why these bytes are not one (wrong version or op code,
/// truncated, frame count disagreeing with the bytes, length out of range, error frames).
Result<CannelloniDatagram> DecodeCannelloni(std::span<const uint8_t> bytes);

struct SequenceCounters {
  uint64_t datagrams = 0;
  uint64_t lost = 0;       // datagrams skipped by the sequence (later arrivals are not undone)
  uint64_t reordered = 0;  // datagrams arriving behind one already seen (late or duplicate)
};

/// Counts gaps and reordering in a stream of 8-bit sequence numbers. A jump forward by 1..127
/// counts the skipped numbers as lost; anything else is a late (reordered or duplicated)
/// datagram and leaves the expected number unchanged.
class SequenceTracker {
 public:
  /// Counts one datagram; false when it does not directly follow the previous one (datagrams
  /// were lost before it, or it comes late).
  bool Observe(uint8_t sequence);
  const SequenceCounters& counters() const { return counters_; }

 private:
  bool started_ = false;
  uint8_t expected_ = 0;
  SequenceCounters counters_;
};

}  // namespace slam::hw
