// Fuzzes SlcanParser. Invariants: feeding the input in two chunks (cut where the first byte
// says) or byte by byte gives the same frames and counters as feeding it whole; the counters
// add up; every frame is valid and FormatSlcanFrame -> parse gives it back.

#include <cstddef>
#include <cstdint>
#include <string_view>
#include <vector>

#include "fuzz/fuzz_check.hpp"
#include "hw_link/slcan.hpp"

namespace {

using slam::fuzz::Check;
using namespace slam::hw;

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const std::string_view input(reinterpret_cast<const char*>(data) + 1, size - 1);
  const size_t cut = data[0] % (input.size() + 1);

  SlcanParser whole;
  std::vector<SlcanFrame> whole_frames;
  whole.Feed(input, whole_frames);
  const SlcanCounters& c = whole.counters();
  Check(c.bytes == input.size(), "byte count");
  Check(c.frames == whole_frames.size(), "frame count");
  Check(c.frames + c.acks + c.nacks + c.bad_lines <= input.size(), "more events than bytes");

  SlcanParser split;
  std::vector<SlcanFrame> split_frames;
  split.Feed(input.substr(0, cut), split_frames);
  split.Feed(input.substr(cut), split_frames);
  Check(whole_frames == split_frames, "split feed: different frames");
  Check(c == split.counters(), "split feed: different counters");

  SlcanParser bytewise;
  std::vector<SlcanFrame> bytewise_frames;
  for (size_t i = 0; i < input.size(); ++i) bytewise.Feed(input.substr(i, 1), bytewise_frames);
  Check(whole_frames == bytewise_frames, "bytewise feed: different frames");
  Check(c == bytewise.counters(), "bytewise feed: different counters");

  for (const SlcanFrame& f : whole_frames) {
    Check(!f.frame.fd && f.frame.len <= kCanMaxData, "bad length");
    Check(f.frame.id <= (f.frame.extended ? kCanExtendedIdMax : kCanStandardIdMax), "bad id");
    Check(!f.timestamp_ms || *f.timestamp_ms < 60000, "bad time stamp");
    SlcanParser again;
    std::vector<SlcanFrame> out;
    again.Feed(FormatSlcanFrame(f.frame, f.timestamp_ms), out);
    Check(out.size() == 1 && again.counters().bad_lines == 0, "formatted frame does not parse");
    Check(!f.after_bad_line || c.bad_lines > 0, "after a bad line without bad lines");
    SlcanFrame alone = f;  // parsed on its own, no bad line comes before it
    alone.after_bad_line = false;
    Check(out == std::vector<SlcanFrame>{alone}, "frame does not round-trip");
  }
  return 0;
}
