#pragma once
// Where CAN frames come from: one interface for every transport (candump replay, slcan, UDP,
// SocketCAN, the virtual marXbot). A source is used by one thread (the link thread).

#include <chrono>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "hw_link/can_frame.hpp"

namespace slam::hw {

enum class ReadStatus {
  kOk,     // zero or more frames appended (zero when the timeout passed with nothing)
  kEnd,    // the source is exhausted for good (end of a log or a finite simulation)
  kError,  // the source failed (device gone, ...): `message` says why; a later Read retries
};

struct ReadOutcome {
  ReadStatus status = ReadStatus::kOk;
  std::string message;
};

/// Named transport-level counters (bytes, bad lines, lost datagrams, reopens, ...).
using SourceCounters = std::vector<std::pair<std::string, uint64_t>>;

class FrameSource {
 public:
  virtual ~FrameSource() = default;

  /// Appends the frames available now to `out`, waiting at most `timeout` for the first one.
  /// Never blocks longer than `timeout` (plus a few milliseconds).
  virtual ReadOutcome Read(std::vector<TimedFrame>& out, std::chrono::milliseconds timeout) = 0;

  /// A short description for logs and the status page, e.g. "slcan:/dev/ttyACM0".
  virtual std::string Describe() const = 0;

  /// The transport's own counters, read on the thread that calls Read.
  virtual SourceCounters Counters() const { return {}; }
};

}  // namespace slam::hw
