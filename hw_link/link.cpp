#include "hw_link/link.hpp"

#include <pthread.h>

#include <algorithm>
#include <exception>
#include <utility>

#include "engine/thread_safety.hpp"

namespace slam::hw {
namespace {

// The longest a PopWait sleeps before looking at the queue again (see EventQueue::PopWait).
constexpr std::chrono::milliseconds kWaitSlice{10};
// The longest the link thread sleeps between looks at stop_ while pausing after an error.
constexpr std::chrono::milliseconds kStopCheckSlice{10};
constexpr size_t kFramesReserve = 512;

// Gives the calling thread a name that top, gdb and perf show.
void NameThisThread(const char* name) {
#if defined(__linux__)
  pthread_setname_np(pthread_self(), name);
#else
  (void)name;
#endif
}

}  // namespace

const char* ToString(LinkState state) {
  switch (state) {
    case LinkState::kIdle:
      return "idle";
    case LinkState::kRunning:
      return "running";
    case LinkState::kSourceError:
      return "source_error";
    case LinkState::kEnded:
      return "ended";
    case LinkState::kStopped:
      return "stopped";
  }
  return "unknown";
}

// ---------------------------------------------------------------------------------------------
// EventQueue: a ring of capacity + 1 preallocated slots. The producer owns tail_, the consumer
// owns head_; each publishes its index with a release store and reads the other's with an
// acquire load, so a slot's contents are visible before its index moves past it. A capacity of
// 0 is taken as 1.

EventQueue::EventQueue(size_t capacity) : slots_(std::max<size_t>(capacity, 1) + 1) {}

bool EventQueue::TryPush(const LinkEvent& event) {
  const size_t tail = tail_.load(std::memory_order_relaxed);
  const size_t next = tail + 1 == slots_.size() ? 0 : tail + 1;
  if (next == head_.load(std::memory_order_acquire)) return false;  // full
  slots_[tail] = event;  // trivially copyable readings: no allocation
  tail_.store(next, std::memory_order_release);
  // Without taking wait_mutex_: the producer must never block. The price is a wake-up that can
  // be missed (see PopWait).
  wait_cv_.notify_one();
  return true;
}

bool EventQueue::TryPop(LinkEvent& event) {
  const size_t head = head_.load(std::memory_order_relaxed);
  if (head == tail_.load(std::memory_order_acquire)) return false;  // empty
  event = slots_[head];
  head_.store(head + 1 == slots_.size() ? 0 : head + 1, std::memory_order_release);
  return true;
}

// The producer notifies without holding wait_mutex_, so a push landing between the predicate
// check and the start of the wait is not seen as a wake-up. The consumer therefore waits in
// slices of at most kWaitSlice and checks the queue again after each: a missed wake-up costs at
// most one slice, never the whole timeout. Callers should still pass short timeouts (tens of
// milliseconds) so that they can notice their own stop requests.
bool EventQueue::PopWait(LinkEvent& event, std::chrono::milliseconds timeout) {
  if (TryPop(event)) return true;
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  {
    MutexLock lock(wait_mutex_);
    const auto not_empty = [this] {
      return head_.load(std::memory_order_acquire) != tail_.load(std::memory_order_acquire);
    };
    while (!not_empty()) {
      const auto now = std::chrono::steady_clock::now();
      if (now >= deadline) break;
      const auto slice = std::min<std::chrono::steady_clock::duration>(deadline - now, kWaitSlice);
      lock.WaitUntil(wait_cv_, now + slice);
    }
  }
  return TryPop(event);
}

size_t EventQueue::size() const {
  const size_t head = head_.load(std::memory_order_acquire);
  const size_t tail = tail_.load(std::memory_order_acquire);
  return tail >= head ? tail - head : tail + slots_.size() - head;
}

// ---------------------------------------------------------------------------------------------
// Link

Link::Link(std::unique_ptr<FrameSource> source, const RobotDescription& robot,
           const LinkOptions& options)
    : source_(std::move(source)),
      options_(options),
      decoder_(robot),
      queue_(options.queue_capacity) {
  status_.source = source_ ? source_->Describe() : "(no source)";
}

Link::~Link() { Stop(); }

void Link::Start() {
  if (thread_.joinable()) return;
  MutexLock lock(status_mutex_);
  if (!source_) {
    status_.last_error = "no frame source";
    state_.store(LinkState::kEnded);
    return;
  }
  state_.store(LinkState::kRunning);
  status_.started_ns = SteadyNowNs();
  thread_ = std::thread(&Link::Run, this);
}

void Link::Stop() {
  stop_.store(true, std::memory_order_release);
  if (!thread_.joinable()) return;
  thread_.join();
  MutexLock lock(status_mutex_);
  if (state_.load() != LinkState::kEnded) state_.store(LinkState::kStopped);
}

bool Link::Drained() const { return state_.load() == LinkState::kEnded && queue_.size() == 0; }

LinkStatus Link::Status() const {
  MutexLock lock(status_mutex_);
  LinkStatus status = status_;
  status.state = state_.load();
  status.queue_size = queue_.size();
  status.status_ns = SteadyNowNs();
  return status;
}

void Link::Run() {
  NameThisThread("link");
  std::vector<TimedFrame> frames;
  frames.reserve(kFramesReserve);
  uint64_t frame_count = 0;
  uint64_t queued = 0;
  uint64_t drops = 0;
  while (!stop_.load(std::memory_order_acquire)) {
    ReadOutcome outcome;
    try {
      frames.clear();
      outcome = source_->Read(frames, options_.read_timeout);
      for (const TimedFrame& frame : frames) {
        ++frame_count;
        const std::optional<RobotEvent> event = decoder_.Push(frame);
        if (!event) continue;
        if (queue_.TryPush(LinkEvent{*event, frame.receive_ns})) {
          ++queued;
        } else {
          ++drops;
        }
      }
    } catch (const std::exception& e) {  // e.g. std::bad_alloc: report it like a source error
      outcome = {ReadStatus::kError, std::string("link: ") + e.what()};
    }
    // A burst (a flood of datagrams, say) must not keep its memory for the rest of the run.
    if (frames.capacity() > 16 * kFramesReserve) {
      frames = std::vector<TimedFrame>();
      frames.reserve(kFramesReserve);
    }

    LinkState next = LinkState::kRunning;
    if (outcome.status == ReadStatus::kEnd) next = LinkState::kEnded;
    if (outcome.status == ReadStatus::kError) next = LinkState::kSourceError;
    {
      MutexLock lock(status_mutex_);
      if (!frames.empty()) status_.last_frame_ns = SteadyNowNs();
      status_.frames = frame_count;
      status_.reassembly = decoder_.reassembly();
      status_.decoder = decoder_.decoder();
      status_.events_queued = queued;
      status_.queue_drops = drops;
      try {
        status_.source = source_->Describe();
        status_.source_counters = source_->Counters();
      } catch (const std::exception&) {
        // Keep the previous description and counters.
      }
      if (next == LinkState::kSourceError) {
        ++status_.source_errors;
        status_.last_error = outcome.message.empty() ? "source error" : outcome.message;
      }
      state_.store(next);
    }
    if (next == LinkState::kEnded) return;
    if (next == LinkState::kSourceError) {
      // Pause before retrying (sources reopen themselves), looking at stop_ every slice.
      const auto resume = std::chrono::steady_clock::now() + options_.error_retry;
      while (!stop_.load(std::memory_order_acquire)) {
        const auto now = std::chrono::steady_clock::now();
        if (now >= resume) break;
        std::this_thread::sleep_for(
            std::min<std::chrono::steady_clock::duration>(resume - now, kStopCheckSlice));
      }
    }
  }
}

}  // namespace slam::hw
