#pragma once
// Small POSIX helpers shared by the live transports (slcan, UDP, SocketCAN) and their tests:
// an owning file descriptor, errno text, and poll() with a deadline.

#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "engine/result.hpp"
#include "hw_link/can_frame.hpp"

namespace slam::hw {

/// Owns a file descriptor and closes it exactly once.
class UniqueFd {
 public:
  UniqueFd() = default;
  explicit UniqueFd(int fd) : fd_(fd) {}
  ~UniqueFd() { Reset(); }
  UniqueFd(UniqueFd&& other) noexcept : fd_(std::exchange(other.fd_, -1)) {}
  UniqueFd& operator=(UniqueFd&& other) noexcept {
    if (this != &other) Reset(std::exchange(other.fd_, -1));
    return *this;
  }
  UniqueFd(const UniqueFd&) = delete;
  UniqueFd& operator=(const UniqueFd&) = delete;

  /// The descriptor, or -1.
  int get() const { return fd_; }
  /// True when a descriptor is held.
  bool valid() const { return fd_ >= 0; }
  /// Closes the held descriptor (if any) and takes `fd` instead.
  void Reset(int fd = -1);

 private:
  int fd_ = -1;
};

/// The text of an errno value, e.g. "No such file or directory" (thread-safe).
std::string ErrnoText(int err);

/// Waits until `fd` is readable, hung up or in error, or until the steady clock reaches
/// `deadline_ns` (SteadyNowNs() time). Returns poll()'s revents (0 on timeout), or -1 with errno
/// set when poll() itself fails; EINTR is retried with the remaining time.
int PollReadable(int fd, int64_t deadline_ns);

/// Writes all of `bytes` to a (possibly non-blocking) descriptor, waiting for it to accept
/// them until `deadline_ns`. Returns 0, or the errno value of the failure (ETIMEDOUT when the
/// deadline passed).
int WriteAll(int fd, const std::string& bytes, int64_t deadline_ns);

/// A descriptor, or why it could not be opened.
using OpenedFd = Result<UniqueFd>;

/// The reopen policy of the live transports after their device fails: remember why it closed,
/// and make an attempt at most every 200 ms, the first one 200 ms after the failure.
class Reopener {
 public:
  /// Records that the device closed now, for `reason`.
  void Closed(std::string reason);

  /// Waits (until `deadline_ns` at most) for the next attempt and makes it with `open`: the new
  /// descriptor, or the error to report, prefixed with `who`.
  OpenedFd TryReopen(int64_t deadline_ns, const std::string& who,
                     const std::function<OpenedFd()>& open);

  uint64_t attempts() const { return attempts_; }
  uint64_t reopens() const { return reopens_; }

 private:
  std::string reason_;
  int64_t next_attempt_ns_ = 0;
  uint64_t attempts_ = 0;
  uint64_t reopens_ = 0;
};

/// Times for frames that arrive together (one UDP datagram, one read from a serial line): they
/// were received at once but sent over the time since the previous batch. With the receive time
/// for all, readings of one kind in a batch shared a time and the scan assembler dropped all but
/// the first as out of order (a cannelloni sender batching 100 ms of frames lost five scanner
/// samples of six). The frames of a batch are spread evenly over the time since the previous
/// batch, at most kMaxSpanNs, the last one at the receive time; receive_ns stays the receive time.
class BatchClock {
 public:
  static constexpr int64_t kMaxSpanNs = 200'000'000;

  /// Sets `t` of frames[first..] (the batch received at `now_ns`, SteadyNowNs() time).
  void Stamp(std::vector<TimedFrame>& frames, size_t first, int64_t now_ns);

 private:
  int64_t previous_ns_ = std::numeric_limits<int64_t>::min();
};

}  // namespace slam::hw
