#include "hw_link/event_decoder.hpp"

#include <array>

#include "engine/sensor_model.hpp"

namespace slam::hw {
namespace {

uint16_t WordAt(const std::vector<uint8_t>& payload, size_t index) {
  return static_cast<uint16_t>(payload[2 * index] | (payload[2 * index + 1] << 8));
}

int32_t Int32At(const std::vector<uint8_t>& payload, size_t index) {
  const uint32_t lo = WordAt(payload, index);
  const uint32_t hi = WordAt(payload, index + 1);
  return static_cast<int32_t>(lo | (hi << 16));
}

uint16_t Lo(int32_t v) { return static_cast<uint16_t>(static_cast<uint32_t>(v) & 0xFFFF); }
uint16_t Hi(int32_t v) { return static_cast<uint16_t>(static_cast<uint32_t>(v) >> 16); }

AsebaMessage Message(int node, int type, std::span<const uint16_t> words, double t) {
  AsebaMessage message;
  message.source = static_cast<uint8_t>(node);
  message.type = static_cast<uint16_t>(type);
  message.payload = WordsToBytes(words);
  message.t = t;
  return message;
}

}  // namespace

EventDecoder::EventDecoder(const RobotDescription& robot)
    : base_node_(robot.base.node),
      base_event_(robot.base.event),
      scanner_node_(robot.scanner.node),
      scanner_event_(robot.scanner.event) {}

std::optional<RobotEvent> EventDecoder::Decode(const AsebaMessage& message) {
  ++counters_.messages;
  const int node = message.source;
  const int type = message.type;
  const bool from_base = node == base_node_;
  const bool from_scanner = node == scanner_node_;
  if (!from_base && !from_scanner) {
    ++counters_.unknown_node;
    return std::nullopt;
  }
  const std::vector<uint8_t>& p = message.payload;
  if (from_base && type == base_event_) {
    if (p.size() != 2 * kOdometryWords) {
      ++counters_.bad_size;
      return std::nullopt;
    }
    OdometryReading r;
    r.t = message.t;
    r.seq = WordAt(p, 0);
    r.left_ticks = Int32At(p, 1);
    r.right_ticks = Int32At(p, 3);
    r.gyro_raw = static_cast<int16_t>(WordAt(p, 5));
    ++counters_.odometry;
    return RobotEvent(r);
  }
  if (from_scanner && type == scanner_event_) {
    if (p.size() != 2 * kScannerWords) {
      ++counters_.bad_size;
      return std::nullopt;
    }
    ScannerReading r;
    r.t = message.t;
    r.seq = WordAt(p, 0);
    r.angle_raw = WordAt(p, 1);
    for (size_t s = 0; s < kScannerSensors; ++s) {
      r.raw[s] = WordAt(p, 2 + s);
      if (r.raw[s] >= kRawValues) ++counters_.raw_out_of_range;
    }
    r.rectifier_mv = WordAt(p, 6);
    ++counters_.scanner;
    return RobotEvent(r);
  }
  ++counters_.unknown_type;
  return std::nullopt;
}

AsebaMessage EncodeOdometry(const RobotDescription& robot, const OdometryReading& r) {
  const std::array<uint16_t, kOdometryWords> words{r.seq,
                                                   Lo(r.left_ticks),
                                                   Hi(r.left_ticks),
                                                   Lo(r.right_ticks),
                                                   Hi(r.right_ticks),
                                                   static_cast<uint16_t>(r.gyro_raw)};
  return Message(robot.base.node, robot.base.event, words, r.t);
}

AsebaMessage EncodeScanner(const RobotDescription& robot, const ScannerReading& r) {
  const std::array<uint16_t, kScannerWords> words{r.seq,    r.angle_raw, r.raw[0],      r.raw[1],
                                                  r.raw[2], r.raw[3],    r.rectifier_mv};
  return Message(robot.scanner.node, robot.scanner.event, words, r.t);
}

}  // namespace slam::hw
