// Fuzzes DecodeCannelloni (and SequenceTracker). Invariants: a decoded datagram encodes and
// decodes back to itself, and re-encodes to the input bytes exactly when it has no FD frames
// (their flags byte is dropped); errors carry a one-line reason.

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <variant>
#include <vector>

#include "fuzz/fuzz_check.hpp"
#include "hw_link/cannelloni.hpp"

using slam::fuzz::Check;
using namespace slam::hw;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::span<const uint8_t> input(data, size);
  const auto decoded = DecodeCannelloni(input);
  if (!decoded.ok()) {
    const std::string error = decoded.Message();
    Check(!error.empty(), "error without a reason");
    Check(error.find('\n') == std::string::npos, "reason spans lines");
  } else {
    const CannelloniDatagram& datagram = decoded.value();
    const std::vector<uint8_t> encoded = EncodeCannelloni(datagram.sequence, datagram.frames);
    const auto again = DecodeCannelloni(encoded);
    Check(again.ok(), "encoded datagram does not decode");
    const CannelloniDatagram* datagram2 = &again.value();
    Check(datagram2->sequence == datagram.sequence, "sequence does not round-trip");
    Check(datagram2->frames == datagram.frames, "frames do not round-trip");
    bool any_fd = false;
    for (const CanFrame& f : datagram.frames) any_fd = any_fd || f.fd;
    if (!any_fd) {
      Check(std::equal(encoded.begin(), encoded.end(), input.begin(), input.end()),
            "re-encoding differs from the input");
    }
  }

  SequenceTracker tracker;
  for (const uint8_t s : input) tracker.Observe(s);
  const SequenceCounters& c = tracker.counters();
  Check(c.datagrams == size, "datagram count");
  Check(c.reordered < size || size == 0, "reordered count");
  Check(c.lost <= 126 * size, "lost count");
  return 0;
}
