// Fuzzes AsebaReassembler with frames built from the input. Each frame takes a header of three
// bytes: [fragment type (bits 1..0) and flags (bits 7..2)] [source] [length], then its data
// bytes (zeros when the input runs out). Invariants: counters().frames counts every push,
// counters().messages every emitted message, and no message exceeds kAsebaMaxMessageBytes.

#include <algorithm>
#include <cstddef>
#include <cstdint>

#include "fuzz/fuzz_check.hpp"
#include "hw_link/aseba.hpp"

namespace {

constexpr int kFdLengths[] = {0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64};

}  // namespace

using slam::fuzz::Check;
using namespace slam::hw;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  AsebaReassembler reassembler;
  uint64_t pushed = 0;
  uint64_t emitted = 0;
  size_t pos = 0;
  while (size - pos >= 3) {
    const uint8_t head = data[pos];
    const uint8_t source = data[pos + 1];
    const uint8_t len_byte = data[pos + 2];
    pos += 3;
    CanFrame frame;
    const int flags = head >> 2;
    // Non-Aseba frames are rare (1 in 16 each), so most inputs exercise reassembly.
    frame.extended = (flags & 0x0F) == 0x0F;
    frame.remote = (flags & 0x3C) == 0x3C;
    frame.fd = (flags & 0x33) == 0x33;
    frame.id = (static_cast<uint32_t>(head & 0x3) << 8) | source;
    if (frame.extended) frame.id |= static_cast<uint32_t>(len_byte) << 11;
    // Classic lengths 0..8, or 0..15 (bad DLCs the reassembler must drop) when bit 4 is set.
    const int len = frame.fd ? kFdLengths[len_byte % 16]
                             : ((len_byte & 0x10) != 0 ? len_byte % 16 : len_byte % 9);
    frame.len = static_cast<uint8_t>(len);
    const size_t n = std::min<size_t>(std::min<size_t>(frame.len, kCanFdMaxData), size - pos);
    std::copy(data + pos, data + pos + n, frame.data.begin());
    pos += n;

    const auto message = reassembler.Push(frame, static_cast<double>(pushed));
    ++pushed;
    if (message) {
      ++emitted;
      Check(2 + message->payload.size() <= static_cast<size_t>(kAsebaMaxMessageBytes),
            "message longer than kAsebaMaxMessageBytes");
      Check(message->source == (frame.id & 0xFF), "message from another source");
      Check(message->t == static_cast<double>(pushed - 1), "message time is not its last frame's");
    }
    const ReassemblyCounters& c = reassembler.counters();
    Check(c.frames == pushed, "counters().frames differs from the frames pushed");
    Check(c.messages == emitted, "counters().messages differs from the messages emitted");
  }
  return 0;
}
