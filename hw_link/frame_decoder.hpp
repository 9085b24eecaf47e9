#pragma once
// The link's decoding pipeline without a thread: frames -> Aseba messages -> robot events. The
// link thread runs it on live data; replays and tools run it directly on recorded data, so
// that nothing is dropped and results do not depend on thread timing.

#include <cstdint>
#include <functional>
#include <optional>
#include <string>

#include "engine/result.hpp"
#include "engine/robot.hpp"
#include "hw_link/aseba.hpp"
#include "hw_link/event_decoder.hpp"
#include "hw_link/frame_source.hpp"

namespace slam::hw {

class FrameDecoder {
 public:
  explicit FrameDecoder(const RobotDescription& robot) : decoder_(robot) {}

  /// The robot event this frame completes, if any (timed by the frame's t).
  std::optional<RobotEvent> Push(const TimedFrame& frame) {
    if (frames_++ == 0) first_time_ = frame.t;
    last_time_ = frame.t;
    if (frame.after_gap) reassembler_.Gap();
    const auto message = reassembler_.Push(frame.frame, frame.t);
    if (!message) return std::nullopt;
    return decoder_.Decode(*message);
  }

  uint64_t frames() const { return frames_; }
  /// Times of the first and last frame pushed (0 before any).
  double first_time() const { return first_time_; }
  double last_time() const { return last_time_; }
  const ReassemblyCounters& reassembly() const { return reassembler_.counters(); }
  const DecoderCounters& decoder() const { return decoder_.counters(); }

 private:
  uint64_t frames_ = 0;
  double first_time_ = 0.0;
  double last_time_ = 0.0;
  AsebaReassembler reassembler_;
  EventDecoder decoder_;
};

/// Reads `source` to its end, handing every decoded event to `on_event` in order, with nothing
/// dropped, and every frame read to `on_frame` (when given) before it is decoded. Returns the
/// source's error if it fails before its end (kError).
Result<void> DecodeToEnd(FrameSource& source, FrameDecoder& decoder,
                         const std::function<void(const RobotEvent&)>& on_event,
                         const std::function<void(const TimedFrame&)>& on_frame = {});

}  // namespace slam::hw
