#include "hw_link/aseba.hpp"

#include <algorithm>
#include <cassert>

namespace slam::hw {
namespace {

CanFrame MakeFrame(FragmentType type, uint8_t source, const uint8_t* bytes, size_t n) {
  CanFrame frame;
  frame.id = AsebaCanId(type, source);
  frame.len = static_cast<uint8_t>(n);
  std::copy(bytes, bytes + n, frame.data.begin());
  return frame;
}

}  // namespace

std::vector<uint8_t> WordsToBytes(std::span<const uint16_t> words) {
  std::vector<uint8_t> bytes;
  bytes.reserve(2 * words.size());
  for (const uint16_t w : words) {
    bytes.push_back(static_cast<uint8_t>(w & 0xFF));
    bytes.push_back(static_cast<uint8_t>(w >> 8));
  }
  return bytes;
}

std::vector<CanFrame> FragmentAseba(uint8_t source, uint16_t type,
                                    std::span<const uint8_t> payload) {
  assert(2 + payload.size() <= static_cast<size_t>(kAsebaMaxMessageBytes));
  std::vector<uint8_t> bytes;
  bytes.reserve(2 + payload.size());
  bytes.push_back(static_cast<uint8_t>(type & 0xFF));
  bytes.push_back(static_cast<uint8_t>(type >> 8));
  bytes.insert(bytes.end(), payload.begin(), payload.end());

  std::vector<CanFrame> frames;
  if (bytes.size() <= static_cast<size_t>(kCanMaxData)) {
    frames.push_back(MakeFrame(FragmentType::kSingle, source, bytes.data(), bytes.size()));
    return frames;
  }
  frames.push_back(MakeFrame(FragmentType::kStart, source, bytes.data(), kCanMaxData));
  size_t pos = kCanMaxData;
  while (bytes.size() - pos > static_cast<size_t>(kCanMaxData)) {
    frames.push_back(MakeFrame(FragmentType::kMiddle, source, bytes.data() + pos, kCanMaxData));
    pos += kCanMaxData;
  }
  frames.push_back(MakeFrame(FragmentType::kStop, source, bytes.data() + pos, bytes.size() - pos));
  return frames;
}

std::optional<AsebaMessage> AsebaReassembler::Push(const CanFrame& frame, double t) {
  ++counters_.frames;
  if (frame.fd) {
    ++counters_.fd;
    return std::nullopt;
  }
  if (frame.extended) {
    ++counters_.extended;
    return std::nullopt;
  }
  if (frame.remote) {
    ++counters_.remote;
    return std::nullopt;
  }
  if ((frame.id & 0x400U) != 0) {  // Aseba ids are 10 bits: another protocol on the bus
    ++counters_.foreign;
    return std::nullopt;
  }
  const auto type = static_cast<FragmentType>((frame.id >> 8) & 0x3);
  const auto source = static_cast<uint8_t>(frame.id & 0xFF);
  Partial& partial = partial_[source];
  const auto data = std::span<const uint8_t>(frame.data.data(), frame.len);

  const auto emit = [&](std::vector<uint8_t>& bytes) {
    AsebaMessage message;
    message.source = source;
    message.type = static_cast<uint16_t>(bytes[0] | (bytes[1] << 8));
    message.payload.assign(bytes.begin() + 2, bytes.end());
    message.t = t;
    ++counters_.messages;
    return message;
  };

  switch (type) {
    case FragmentType::kSingle: {
      if (frame.len < 2 || frame.len > kCanMaxData) {
        ++counters_.bad_length;
        return std::nullopt;
      }
      if (partial.active) {
        ++counters_.abandoned;
        partial.active = false;
      }
      std::vector<uint8_t> bytes(data.begin(), data.end());
      return emit(bytes);
    }
    case FragmentType::kStart: {
      if (frame.len != kCanMaxData) {
        ++counters_.bad_length;
        return std::nullopt;
      }
      if (partial.active) ++counters_.abandoned;
      partial.active = true;
      partial.bytes.assign(data.begin(), data.end());
      return std::nullopt;
    }
    case FragmentType::kMiddle:
    case FragmentType::kStop: {
      const bool stop = type == FragmentType::kStop;
      if (!partial.active) {
        ++(stop ? counters_.stop_without_start : counters_.middle_without_start);
        return std::nullopt;
      }
      if (stop ? (frame.len < 1 || frame.len > kCanMaxData) : frame.len != kCanMaxData) {
        // The message in progress cannot be completed correctly any more.
        ++counters_.bad_length;
        partial.active = false;
        ++counters_.abandoned;
        return std::nullopt;
      }
      if (partial.bytes.size() + data.size() > static_cast<size_t>(kAsebaMaxMessageBytes)) {
        ++counters_.oversize;
        partial.active = false;
        return std::nullopt;
      }
      partial.bytes.insert(partial.bytes.end(), data.begin(), data.end());
      if (!stop) return std::nullopt;
      partial.active = false;
      return emit(partial.bytes);
    }
  }
  return std::nullopt;
}

void AsebaReassembler::Gap() {
  for (Partial& partial : partial_) {
    if (!partial.active) continue;
    partial.active = false;
    ++counters_.abandoned;
  }
}

}  // namespace slam::hw
