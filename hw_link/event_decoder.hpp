#pragma once
// Aseba messages <-> robot events, as robot.json configures them (docs/design.md section 5):
//   base (node, event):    seq, left ticks lo, hi, right ticks lo, hi, gyro z   (6 words)
//   scanner (node, event): seq, platform angle, s0, s1, s2, s3, rectifier mV    (7 words)

#include <cstdint>
#include <optional>

#include "engine/robot.hpp"
#include "hw_link/aseba.hpp"

namespace slam::hw {

inline constexpr int kOdometryWords = 6;
inline constexpr int kScannerWords = 7;

struct DecoderCounters {
  uint64_t messages = 0;  // messages offered
  uint64_t odometry = 0;  // events decoded, per type
  uint64_t scanner = 0;
  uint64_t unknown_node = 0;  // from a node that is neither the base nor the scanner
  uint64_t unknown_type = 0;  // from a known node, of a type robot.json does not name
  uint64_t bad_size = 0;      // a known event with the wrong number of bytes
  /// Scanner readings above the 10-bit ADC's 1023 (the sample is kept; those sensors' values
  /// are unusable and the engine skips them): a corrupt event, or a scanner of another kind.
  uint64_t raw_out_of_range = 0;

  uint64_t Rejected() const { return unknown_node + unknown_type + bad_size; }
};

class EventDecoder {
 public:
  explicit EventDecoder(const RobotDescription& robot);

  /// The robot event carried by `message` (its time is the message's), or nothing when the
  /// message is not one (counted).
  std::optional<RobotEvent> Decode(const AsebaMessage& message);

  const DecoderCounters& counters() const { return counters_; }

 private:
  int base_node_;
  int base_event_;
  int scanner_node_;
  int scanner_event_;
  DecoderCounters counters_;
};

/// The message the base sends for `reading` (t copied).
AsebaMessage EncodeOdometry(const RobotDescription& robot, const OdometryReading& reading);

/// The message the scanner sends for `reading` (t copied).
AsebaMessage EncodeScanner(const RobotDescription& robot, const ScannerReading& reading);

}  // namespace slam::hw
