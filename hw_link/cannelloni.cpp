#include "hw_link/cannelloni.hpp"

#include <algorithm>
#include <cstddef>
#include <optional>

// Decisions beyond the header's contract:
// - A datagram holding an error frame (can_id & 0x20000000) is rejected as a whole, like any
//   other malformed datagram: the link counts it as one bad datagram.
// - A standard frame's id must fit in 11 bits (no silent masking). Classic lengths are 0..8
//   (for remote frames the requested length); FD lengths must be valid FD lengths (0..8, 12, 16,
//   20, 24, 32, 48, 64); a remote FD frame is an error. The FD flags byte is read and dropped
//   (CanFrame keeps no FD flags); Encode writes 0 there.

namespace slam::hw {
namespace {

constexpr size_t kHeaderBytes = 5;  // version, op code, sequence, count (u16)
constexpr uint32_t kEffFlag = 0x80000000;
constexpr uint32_t kRtrFlag = 0x40000000;
constexpr uint32_t kErrFlag = 0x20000000;
constexpr uint8_t kFdLengthFlag = 0x80;

bool IsValidFdLength(size_t n) {
  return n <= 8 || n == 12 || n == 16 || n == 20 || n == 24 || n == 32 || n == 48 || n == 64;
}

void PutU32(std::vector<uint8_t>& out, uint32_t v) {
  out.push_back(static_cast<uint8_t>(v >> 24));
  out.push_back(static_cast<uint8_t>(v >> 16));
  out.push_back(static_cast<uint8_t>(v >> 8));
  out.push_back(static_cast<uint8_t>(v));
}

// Bounds-checked big-endian reader over the datagram.
class Reader {
 public:
  explicit Reader(std::span<const uint8_t> bytes) : bytes_(bytes) {}

  size_t remaining() const { return bytes_.size() - pos_; }

  std::optional<uint8_t> U8() {
    if (remaining() < 1) return std::nullopt;
    return bytes_[pos_++];
  }

  std::optional<uint32_t> U32() {
    if (remaining() < 4) return std::nullopt;
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v = (v << 8) | bytes_[pos_++];
    return v;
  }

  std::optional<std::span<const uint8_t>> Bytes(size_t n) {
    if (remaining() < n) return std::nullopt;
    const auto out = bytes_.subspan(pos_, n);
    pos_ += n;
    return out;
  }

 private:
  std::span<const uint8_t> bytes_;
  size_t pos_ = 0;
};

// Reads one frame; returns the reason when the bytes are not one.
std::optional<std::string> ReadFrame(Reader& in, CanFrame& frame) {
  const auto can_id = in.U32();
  const auto len_byte = can_id ? in.U8() : std::nullopt;
  if (!len_byte) return "truncated frame header";
  if (*can_id & kErrFlag) return "error frame";
  frame.extended = (*can_id & kEffFlag) != 0;
  frame.remote = (*can_id & kRtrFlag) != 0;
  frame.fd = (*len_byte & kFdLengthFlag) != 0;
  frame.id = *can_id & kCanExtendedIdMax;
  if (!frame.extended && frame.id > kCanStandardIdMax) return "standard id out of range";
  const int len = *len_byte & ~kFdLengthFlag;
  if (frame.fd) {
    if (frame.remote) return "remote CAN FD frame";
    if (!IsValidFdLength(static_cast<size_t>(len))) {
      return "invalid CAN FD length " + std::to_string(len);
    }
    if (!in.U8()) return "truncated CAN FD flags";
  } else if (len > kCanMaxData) {
    return "CAN length " + std::to_string(len) + " > 8";
  }
  frame.len = static_cast<uint8_t>(len);
  if (frame.remote) return std::nullopt;
  const auto data = in.Bytes(frame.len);
  if (!data) return "truncated frame data";
  std::copy(data->begin(), data->end(), frame.data.begin());
  return std::nullopt;
}

}  // namespace

std::vector<uint8_t> EncodeCannelloni(uint8_t sequence, std::span<const CanFrame> frames) {
  const size_t count = std::min<size_t>(frames.size(), 0xFFFF);  // precondition
  std::vector<uint8_t> out{kCannelloniVersion, kCannelloniOpData, sequence,
                           static_cast<uint8_t>(count >> 8), static_cast<uint8_t>(count)};
  for (size_t i = 0; i < count; ++i) {
    const CanFrame& f = frames[i];
    const uint32_t id = f.id & (f.extended ? kCanExtendedIdMax : kCanStandardIdMax);
    PutU32(out, id | (f.extended ? kEffFlag : 0u) | (f.remote ? kRtrFlag : 0u));
    const uint8_t len = std::min<uint8_t>(f.len, static_cast<uint8_t>(kCanFdMaxData));
    if (f.fd) {
      out.push_back(static_cast<uint8_t>(len | kFdLengthFlag));
      out.push_back(0);  // FD flags: we keep none
    } else {
      out.push_back(len);
    }
    if (!f.remote) out.insert(out.end(), f.data.begin(), f.data.begin() + len);
  }
  return out;
}

Result<CannelloniDatagram> DecodeCannelloni(std::span<const uint8_t> bytes) {
  if (bytes.size() < kHeaderBytes) {
    return Error("truncated header (" + std::to_string(bytes.size()) + " bytes)");
  }
  if (bytes[0] != kCannelloniVersion)
    return Error("unsupported version " + std::to_string(bytes[0]));
  if (bytes[1] != kCannelloniOpData)
    return Error("unsupported op code " + std::to_string(bytes[1]));
  CannelloniDatagram out;
  out.sequence = bytes[2];
  const size_t count = (static_cast<size_t>(bytes[3]) << 8) | bytes[4];
  Reader in(bytes.subspan(kHeaderBytes));
  // Every frame takes at least 5 bytes: a count the bytes cannot hold is rejected up front.
  if (count > in.remaining() / 5) {
    return Error("frame count " + std::to_string(count) + " exceeds the datagram");
  }
  out.frames.resize(count);
  for (size_t i = 0; i < count; ++i) {
    if (auto reason = ReadFrame(in, out.frames[i])) {
      return Error("frame " + std::to_string(i) + " of " + std::to_string(count) + ": " + *reason);
    }
  }
  if (in.remaining() != 0) {
    return Error(std::to_string(in.remaining()) + " trailing bytes after " + std::to_string(count) +
                 " frames");
  }
  return out;
}

bool SequenceTracker::Observe(uint8_t sequence) {
  ++counters_.datagrams;
  if (!started_) {
    started_ = true;
    expected_ = static_cast<uint8_t>(sequence + 1);
    return true;
  }
  // Forward distance from the last number seen (expected_ - 1): 1..127 is new.
  const auto skipped = static_cast<uint8_t>(sequence - expected_);
  if (skipped <= 126) {
    counters_.lost += skipped;
    expected_ = static_cast<uint8_t>(sequence + 1);
    return skipped == 0;
  }
  ++counters_.reordered;
  return false;
}

}  // namespace slam::hw
