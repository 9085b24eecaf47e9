#include "hw_link/frame_decoder.hpp"

#include <vector>

namespace slam::hw {

Result<void> DecodeToEnd(FrameSource& source, FrameDecoder& decoder,
                         const std::function<void(const RobotEvent&)>& on_event,
                         const std::function<void(const TimedFrame&)>& on_frame) {
  std::vector<TimedFrame> frames;
  for (;;) {
    frames.clear();
    const ReadOutcome outcome = source.Read(frames, std::chrono::milliseconds(100));
    for (const TimedFrame& frame : frames) {
      if (on_frame) on_frame(frame);
      if (auto event = decoder.Push(frame)) on_event(*event);
    }
    if (outcome.status == ReadStatus::kEnd) return {};
    if (outcome.status == ReadStatus::kError) return Error(outcome.message);
  }
}

}  // namespace slam::hw
