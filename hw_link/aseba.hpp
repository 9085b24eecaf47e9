#pragma once
// Aseba messages over CAN (docs/design.md section 5, docs/design.md appendix A): the fragmenter
// that cuts a message into frames and the per-source reassembler that puts them back together.

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include "hw_link/can_frame.hpp"

namespace slam::hw {

/// Largest message the reassembler accepts: type (2 bytes) + payload, 65 frames.
inline constexpr int kAsebaMaxMessageBytes = 518;

/// Bits 9..8 of the CAN id.
enum class FragmentType : uint8_t { kMiddle = 0, kStart = 1, kStop = 2, kSingle = 3 };

/// The 11-bit CAN id of a fragment: (type << 8) | source.
constexpr uint32_t AsebaCanId(FragmentType type, uint8_t source) {
  return (static_cast<uint32_t>(type) << 8) | source;
}

/// An Aseba message: its sender (the CAN id's low byte), type, and payload bytes (for events,
/// 16-bit little-endian words).
struct AsebaMessage {
  uint8_t source = 0;
  uint16_t type = 0;
  std::vector<uint8_t> payload;
  double t = 0.0;  // time of the message's last frame

  friend bool operator==(const AsebaMessage&, const AsebaMessage&) = default;
};

/// Cuts a message into frames: one single frame when type + payload fit in 8 bytes, otherwise a
/// start frame, middle frames and a stop frame. Precondition: 2 + payload.size() <=
/// kAsebaMaxMessageBytes.
std::vector<CanFrame> FragmentAseba(uint8_t source, uint16_t type,
                                    std::span<const uint8_t> payload);

/// Payload bytes of 16-bit words, little-endian.
std::vector<uint8_t> WordsToBytes(std::span<const uint16_t> words);

/// What the reassembler saw. Every frame lands in exactly one of: part of an emitted message,
/// part of an abandoned or oversize message, or one of the rejection counters.
struct ReassemblyCounters {
  uint64_t frames = 0;    // frames pushed
  uint64_t messages = 0;  // messages emitted
  uint64_t extended = 0;  // frames dropped because they are not Aseba frames ...
  uint64_t remote = 0;
  uint64_t fd = 0;
  uint64_t foreign = 0;     // standard frames with id bit 10 set: not Aseba's (it uses bits 0..9)
  uint64_t bad_length = 0;  // DLC not allowed for its fragment type: frame dropped
  uint64_t middle_without_start = 0;  // fragment with no message in progress: dropped
  uint64_t stop_without_start = 0;
  uint64_t oversize = 0;   // messages abandoned for growing beyond kAsebaMaxMessageBytes
  uint64_t abandoned = 0;  // messages in progress cut off by a new start, a single frame or a gap

  /// Frames or messages rejected for any reason.
  uint64_t Rejected() const {
    return extended + remote + fd + foreign + bad_length + middle_without_start +
           stop_without_start + oversize + abandoned;
  }
};

/// Reassembles messages per source node, each source's frames in arrival order (frames of
/// different sources may interleave). Anomalies are counted and never spoil the next message.
class AsebaReassembler {
 public:
  /// Feeds one frame received at time t; returns the message this frame completes, if any.
  std::optional<AsebaMessage> Push(const CanFrame& frame, double t);

  /// Frames were lost: every message in progress is abandoned (counted), so that none is
  /// finished with a later message's frames (the stop of one and the start of the next lost,
  /// the first message's start and the second's stop would make a message of the right size).
  void Gap();

  const ReassemblyCounters& counters() const { return counters_; }

 private:
  struct Partial {
    bool active = false;
    std::vector<uint8_t> bytes;  // type + payload so far
  };
  std::array<Partial, 256> partial_{};
  ReassemblyCounters counters_;
};

}  // namespace slam::hw
