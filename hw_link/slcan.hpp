#pragma once
// slcan (Lawicel ASCII) as spoken by cheap USB-CAN adapters, parsed incrementally: the byte
// stream may be split anywhere.
//   tIIILDD..\r   standard frame       TIIIIIIIILDD..\r   extended frame
//   rIIIL\r       standard remote      RIIIIIIIIL\r       extended remote
// A frame line may end with 4 hex digits of adapter time in milliseconds (modulo 60000) when
// time stamps are on (`Z1`). Replies: "\r" ok, "\a" error, "z\r"/"Z\r" sent. '\n' is tolerated
// as a line end (a tty not in raw mode turns '\r' into '\n'). Malformed lines and lines longer
// than any valid one are counted and skipped; the parser resynchronises at the next line end.

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "hw_link/can_frame.hpp"

namespace slam::hw {

struct SlcanFrame {
  CanFrame frame;
  std::optional<uint16_t> timestamp_ms;  // adapter time (0..59999) when time stamps are on
  bool after_bad_line = false;  // a line the parser could not read came before it (a lost frame?)

  friend bool operator==(const SlcanFrame&, const SlcanFrame&) = default;
};

struct SlcanCounters {
  uint64_t bytes = 0;
  uint64_t frames = 0;
  uint64_t acks = 0;       // "\r", "z\r", "Z\r"
  uint64_t nacks = 0;      // "\a"
  uint64_t bad_lines = 0;  // malformed or too long: skipped

  friend bool operator==(const SlcanCounters&, const SlcanCounters&) = default;
};

class SlcanParser {
 public:
  /// Parses `bytes`, appending every frame completed by them to `out`.
  void Feed(std::string_view bytes, std::vector<SlcanFrame>& out);

  const SlcanCounters& counters() const { return counters_; }

 private:
  std::string line_;
  bool overlong_ = false;
  bool bad_since_frame_ = false;  // a bad line since the last frame
  bool after_cr_ = false;         // the last byte was '\r': a '\n' right after it ends nothing
  SlcanCounters counters_;
};

/// The line an adapter sends (and accepts) for this frame, '\r' included. Preconditions: a
/// classic frame (not fd), len <= 8, id within its range.
std::string FormatSlcanFrame(const CanFrame& frame,
                             std::optional<uint16_t> timestamp_ms = std::nullopt);

/// Commands sent on open: "C\r" (close, in case it was open), "S8\r" (1 Mbit/s), "O\r" (open).
std::string SlcanOpenCommands();

}  // namespace slam::hw
