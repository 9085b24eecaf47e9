#include "hw_link/fd_util.hpp"

#include <poll.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <thread>

#include "hw_link/can_frame.hpp"

namespace slam::hw {
namespace {

constexpr int64_t kReopenIntervalNs = 200'000'000;

// strerror_r comes in two flavours (GNU returns the text, XSI fills the buffer); take either.
[[maybe_unused]] const char* StrerrorText(int /*result*/, const char* buffer) { return buffer; }
[[maybe_unused]] const char* StrerrorText(const char* result, const char* /*buffer*/) {
  return result;
}

// Milliseconds from now until `deadline_ns`, rounded up, clamped to [0, one hour].
int RemainingMs(int64_t deadline_ns) {
  const int64_t remaining_ns = deadline_ns - SteadyNowNs();
  if (remaining_ns <= 0) return 0;
  const int64_t ms = (remaining_ns + 999'999) / 1'000'000;
  return static_cast<int>(std::min<int64_t>(ms, 3'600'000));
}

// Waits for `events` on `fd` until the deadline; revents, 0 on timeout, -1 on poll failure.
int PollFor(int fd, short events, int64_t deadline_ns) {
  while (true) {
    pollfd entry{};
    entry.fd = fd;
    entry.events = events;
    const int ready = ::poll(&entry, 1, RemainingMs(deadline_ns));
    if (ready > 0) return entry.revents;
    if (ready == 0) return 0;
    if (errno != EINTR) return -1;
  }
}

}  // namespace

void UniqueFd::Reset(int fd) {
  if (fd_ >= 0 && fd_ != fd) ::close(fd_);
  fd_ = fd;
}

std::string ErrnoText(int err) {
  char buffer[256] = {};
  return StrerrorText(strerror_r(err, buffer, sizeof buffer), buffer);
}

int PollReadable(int fd, int64_t deadline_ns) { return PollFor(fd, POLLIN, deadline_ns); }

int WriteAll(int fd, const std::string& bytes, int64_t deadline_ns) {
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n > 0) {
      done += static_cast<size_t>(n);
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) return errno;
    const int revents = PollFor(fd, POLLOUT, deadline_ns);
    if (revents < 0) return errno;
    if (revents == 0) return ETIMEDOUT;
    if ((revents & POLLOUT) == 0) return (revents & POLLHUP) != 0 ? EIO : EPIPE;
  }
  return 0;
}

void Reopener::Closed(std::string reason) {
  reason_ = std::move(reason);
  next_attempt_ns_ = SteadyNowNs() + kReopenIntervalNs;
}

OpenedFd Reopener::TryReopen(int64_t deadline_ns, const std::string& who,
                             const std::function<OpenedFd()>& open) {
  int64_t now_ns = SteadyNowNs();
  if (now_ns < next_attempt_ns_) {
    std::this_thread::sleep_for(
        std::chrono::nanoseconds(std::min(next_attempt_ns_, deadline_ns) - now_ns));
    now_ns = SteadyNowNs();
    if (now_ns < next_attempt_ns_) {
      return Error(who + ": closed (" + reason_ + "), waiting to reopen");
    }
  }
  ++attempts_;
  next_attempt_ns_ = now_ns + kReopenIntervalNs;
  OpenedFd opened = open();
  if (!opened.ok())
    return Error(who + ": closed (" + reason_ + "); reopen failed: " + opened.Message());
  ++reopens_;
  return opened;
}

void BatchClock::Stamp(std::vector<TimedFrame>& frames, size_t first, int64_t now_ns) {
  if (first >= frames.size()) return;
  const auto n = static_cast<int64_t>(frames.size() - first);
  // Strictly after the previous batch's last frame, 1 ns a frame at the very least.
  const int64_t end = std::max(
      now_ns, previous_ns_ == std::numeric_limits<int64_t>::min() ? now_ns : previous_ns_ + n);
  const int64_t start =
      previous_ns_ == std::numeric_limits<int64_t>::min() || end - previous_ns_ > kMaxSpanNs
          ? end - kMaxSpanNs
          : previous_ns_;
  const int64_t span = end - start;
  for (int64_t i = 0; i < n; ++i) {
    const int64_t t_ns = start + span * (i + 1) / n;  // span <= kMaxSpanNs: no overflow
    frames[first + static_cast<size_t>(i)].t = static_cast<double>(t_ns) * 1e-9;
  }
  previous_ns_ = end;
}

}  // namespace slam::hw
