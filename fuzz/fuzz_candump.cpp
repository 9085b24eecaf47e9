// Fuzzes ParseCandumpLine over every line of the input. Invariants: errors carry a one-line
// reason, parsed frames are valid, and Format -> Parse gives back the same line exactly.

#include <cstddef>
#include <cstdint>
#include <string_view>

#include "fuzz/fuzz_check.hpp"
#include "hw_link/candump.hpp"

namespace {

using slam::fuzz::Check;
using namespace slam::hw;

bool IsValidFdLength(int n) {
  return n <= 8 || n == 12 || n == 16 || n == 20 || n == 24 || n == 32 || n == 48 || n == 64;
}

void CheckLine(std::string_view text) {
  const CandumpLine line = ParseCandumpLine(text);
  if (line.kind == CandumpLineKind::kIgnored) {
    Check(line.error.empty(), "ignored line with an error");
    return;
  }
  if (line.kind == CandumpLineKind::kError) {
    Check(!line.error.empty(), "error without a reason");
    Check(line.error.find('\n') == std::string::npos, "reason spans lines");
    return;
  }
  const CanFrame& f = line.frame;
  Check(line.time_us >= 0, "negative time");
  Check(!line.interface.empty(), "empty interface");
  Check(f.id <= (f.extended ? kCanExtendedIdMax : kCanStandardIdMax), "id out of range");
  Check(!(f.remote && f.fd), "remote FD frame");
  Check(f.fd ? IsValidFdLength(f.len) : f.len <= kCanMaxData, "length out of range");

  const std::string formatted = FormatCandumpLine(line.time_us, line.interface, f);
  const CandumpLine again = ParseCandumpLine(formatted);
  Check(again.kind == CandumpLineKind::kFrame, "formatted line does not parse");
  Check(again.time_us == line.time_us, "time does not round-trip");
  Check(again.interface == line.interface, "interface does not round-trip");
  Check(again.frame == f, "frame does not round-trip");
  Check(FormatCandumpLine(again.time_us, again.interface, again.frame) == formatted,
        "format is not a fixed point");
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  size_t begin = 0;
  while (true) {
    const size_t end = input.find('\n', begin);
    CheckLine(input.substr(begin, end == std::string_view::npos ? end : end - begin));
    if (end == std::string_view::npos) break;
    begin = end + 1;
  }
  return 0;
}
