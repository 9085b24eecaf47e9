#pragma once
// candump log lines (can-utils `candump -l`, replayed by `canplayer`):
//   "(1436509052.249713) can0 123#DEADBEEF"
// 3 hex digits of id = standard frame, 8 = extended; "#R" (optionally followed by a length
// digit) = remote frame; "##" + one flags digit + data = CAN FD frame.
//
// How lines are handled (the contract the replay and the tests rely on):
// - empty lines, and lines whose first non-blank character is not '(' (comments, canplayer's
//   rule), are kIgnored;
// - well-formed standard, extended, remote and FD lines are kFrame, with the frame's flags set
//   (whether Aseba can use the frame is the reassembler's business, which counts it);
// - anything else (bad timestamp, missing interface, bad id, odd or non-hex data, too many data
//   bytes, trailing garbage) is kError with a one-line reason.
// Blanks (spaces or tabs, any number) separate the three fields; a trailing '\r' is ignored.

#include <cstdint>
#include <string>
#include <string_view>

#include "hw_link/can_frame.hpp"

namespace slam::hw {

enum class CandumpLineKind { kFrame, kIgnored, kError };

struct CandumpLine {
  CandumpLineKind kind = CandumpLineKind::kIgnored;
  int64_t time_us = 0;  // the timestamp, microseconds since the epoch (kFrame only)
  std::string interface;
  CanFrame frame;
  std::string error;  // kError only
};

/// Parses one line (without its '\n').
CandumpLine ParseCandumpLine(std::string_view line);

/// Formats a frame as a candump -l line without the newline, e.g.
/// "(1700000000.000123) can0 102#2000010000402C01". Precondition: time_us >= 0 (times past
/// 2^40 s do not parse back).
std::string FormatCandumpLine(int64_t time_us, std::string_view interface, const CanFrame& frame);

}  // namespace slam::hw
