#pragma once
// The link thread: reads frames from a FrameSource, reassembles Aseba messages, decodes robot
// events, and pushes them into a bounded queue for the SLAM thread. The push never blocks the
// link thread: when the queue is full the event is dropped and counted. Memory is bounded by
// the queue's capacity.

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "engine/robot.hpp"
#include "engine/thread_safety.hpp"
#include "hw_link/aseba.hpp"
#include "hw_link/event_decoder.hpp"
#include "hw_link/frame_decoder.hpp"
#include "hw_link/frame_source.hpp"

namespace slam::hw {

/// A decoded event and when its last frame arrived.
struct LinkEvent {
  RobotEvent event;
  int64_t receive_ns = 0;  // steady clock
};

/// How long without a frame before a running link is reported silent (the marXbot sends tens of
/// frames a second; a live source that says nothing for this long has lost the robot).
inline constexpr double kLinkSilentAfterS = 1.0;

struct LinkOptions {
  size_t queue_capacity = 1024;                // events (about 9 s of robot traffic)
  std::chrono::milliseconds read_timeout{50};  // how often the thread checks for stop
  std::chrono::milliseconds error_retry{500};  // pause after a source error
};

enum class LinkState { kIdle, kRunning, kSourceError, kEnded, kStopped };

/// "idle", "running", "source_error", "ended", "stopped".
const char* ToString(LinkState state);

/// A consistent copy of everything the link counts.
struct LinkStatus {
  LinkState state = LinkState::kIdle;
  std::string source;      // the source's description
  std::string last_error;  // the latest source error, empty if none
  uint64_t source_errors = 0;
  uint64_t frames = 0;
  int64_t started_ns = 0;     // steady clock when the link started; 0: not started
  int64_t last_frame_ns = 0;  // steady clock when the latest frame was read; 0: none yet
  int64_t status_ns = 0;      // steady clock when this copy was taken
  ReassemblyCounters reassembly;
  DecoderCounters decoder;
  uint64_t events_queued = 0;  // pushed into the queue
  uint64_t queue_drops = 0;    // dropped because the queue was full
  uint64_t queue_size = 0;     // waiting now
  SourceCounters source_counters;

  /// Seconds without a frame as of this copy: since the latest frame, or since the start if
  /// none came; 0 before the start.
  double SecondsWithoutFrames() const {
    if (started_ns == 0) return 0.0;
    const int64_t since = last_frame_ns != 0 ? last_frame_ns : started_ns;
    return status_ns > since ? static_cast<double>(status_ns - since) * 1e-9 : 0.0;
  }
  /// Running, but nothing heard for kLinkSilentAfterS: the robot or its transport went quiet.
  bool Silent() const {
    return state == LinkState::kRunning && SecondsWithoutFrames() >= kLinkSilentAfterS;
  }
};

/// A bounded single-producer single-consumer queue of events; TryPush never blocks.
class EventQueue {
 public:
  explicit EventQueue(size_t capacity);

  /// Adds an event; false (and nothing added) when full.
  bool TryPush(const LinkEvent& event);
  /// Takes the oldest event, if any.
  bool TryPop(LinkEvent& event);
  /// Takes the oldest event, waiting up to `timeout` for one.
  bool PopWait(LinkEvent& event, std::chrono::milliseconds timeout);
  size_t size() const;
  size_t capacity() const { return slots_.size() - 1; }

 private:
  std::vector<LinkEvent> slots_;  // ring with one empty slot
  std::atomic<size_t> head_{0};   // next to pop (consumer)
  std::atomic<size_t> tail_{0};   // next to push (producer)
  Mutex wait_mutex_;              // only for the consumer's wait; the producer never takes it
  std::condition_variable wait_cv_;
};

class Link {
 public:
  Link(std::unique_ptr<FrameSource> source, const RobotDescription& robot,
       const LinkOptions& options = {});
  ~Link();  // stops the thread
  Link(const Link&) = delete;
  Link& operator=(const Link&) = delete;

  /// Starts the link thread (named "link"). Precondition: not started before.
  void Start();
  /// Asks the thread to stop and joins it; idempotent. Events already queued stay poppable.
  void Stop();

  /// The next event, if one is waiting (consumer side, one consumer thread).
  bool Pop(LinkEvent& event) { return queue_.TryPop(event); }
  /// The next event, waiting up to `timeout`.
  bool PopWait(LinkEvent& event, std::chrono::milliseconds timeout) {
    return queue_.PopWait(event, timeout);
  }

  /// True when the source has ended (kEnd) and every queued event has been popped.
  bool Drained() const;

  LinkStatus Status() const;

 private:
  void Run();

  std::unique_ptr<FrameSource> source_;
  LinkOptions options_;
  FrameDecoder decoder_;  // link thread only
  EventQueue queue_;
  std::atomic<bool> stop_{false};
  std::atomic<LinkState> state_{LinkState::kIdle};
  std::thread thread_;
  mutable Mutex status_mutex_;
  LinkStatus status_
      SLAM_GUARDED_BY(status_mutex_);  // refreshed by the link thread after each read
};

}  // namespace slam::hw
