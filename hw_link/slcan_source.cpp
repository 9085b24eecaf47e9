// slcan (Lawicel ASCII) adapters on a tty or pseudo-terminal.
//
// Hang-up and reopening: when the device hangs up (POLLHUP, read() returning 0 or EIO) or fails,
// Read closes it and returns kError("... hung up"). While the device is closed, every Read
// returns kError: it first sleeps (at most its timeout) until the next reopen attempt is due
// (attempts are at least 200 ms apart), tries to reopen, and on success carries on
// reading within the same call. So a link keeps showing "source_error" until the device is
// back, and counts one error per Read meanwhile.

#include <fcntl.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <thread>
#include <utility>

#include "hw_link/fd_util.hpp"
#include "hw_link/slcan.hpp"
#include "hw_link/transports.hpp"

namespace slam::hw {
namespace {

constexpr int64_t kOpenWriteTimeoutNs = 200'000'000;  // for the open commands
constexpr size_t kReadChunk = 4096;
constexpr size_t kMaxBytesPerRead = 64 * 1024;  // then return what we have

// Opens the device in raw mode and sends the open commands; the descriptor or why not.
OpenedFd OpenDevice(const std::string& device) {
  UniqueFd fd(::open(device.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC));
  if (!fd.valid()) {
    const int err = errno;
    return Error("cannot open slcan device '" + device + "': " + ErrnoText(err));
  }
  if (::isatty(fd.get()) == 1) {
    // Raw mode: no echo, no line editing, and above all no '\r' -> '\n' translation.
    termios tio{};
    if (::tcgetattr(fd.get(), &tio) != 0) {
      const int err = errno;
      return Error("cannot read the terminal settings of '" + device + "': " + ErrnoText(err));
    }
    ::cfmakeraw(&tio);
    tio.c_cflag |= CLOCAL | CREAD;
    if (::tcsetattr(fd.get(), TCSANOW, &tio) != 0) {
      const int err = errno;
      return Error("cannot put '" + device + "' in raw mode: " + ErrnoText(err));
    }
  }
  const int err = WriteAll(fd.get(), SlcanOpenCommands(), SteadyNowNs() + kOpenWriteTimeoutNs);
  if (err != 0)
    return Error("cannot write the open commands to '" + device + "': " + ErrnoText(err));
  return fd;
}

SlcanCounters& operator+=(SlcanCounters& a, const SlcanCounters& b) {
  a.bytes += b.bytes;
  a.frames += b.frames;
  a.acks += b.acks;
  a.nacks += b.nacks;
  a.bad_lines += b.bad_lines;
  return a;
}

class SlcanSource final : public FrameSource {
 public:
  SlcanSource(std::string device, UniqueFd fd) : device_(std::move(device)), fd_(std::move(fd)) {}

  ReadOutcome Read(std::vector<TimedFrame>& out, std::chrono::milliseconds timeout) override {
    const int64_t deadline_ns = SteadyNowNs() + std::max<int64_t>(0, timeout.count()) * 1'000'000;
    if (!fd_.valid()) {
      std::string failure = TryReopen(deadline_ns);
      if (!failure.empty()) return {ReadStatus::kError, std::move(failure)};
    }
    const size_t before = out.size();
    size_t bytes_this_call = 0;
    while (true) {
      const int revents = PollReadable(fd_.get(), deadline_ns);
      if (revents < 0) return Fail("poll: " + ErrnoText(errno));
      if (revents == 0) return {};  // timeout
      if ((revents & POLLNVAL) != 0) return Fail("descriptor no longer valid");
      bool would_block = false;
      while (!would_block && bytes_this_call < kMaxBytesPerRead) {
        const ssize_t n = ::read(fd_.get(), buffer_.data(), buffer_.size());
        if (n > 0) {
          bytes_this_call += static_cast<size_t>(n);
          Deliver(std::string_view(buffer_.data(), static_cast<size_t>(n)), out);
        } else if (n == 0) {
          return Fail("device hung up");
        } else if (errno == EINTR) {
          continue;
        } else if (errno == EAGAIN || errno == EWOULDBLOCK) {
          would_block = true;
        } else if (errno == EIO) {
          return Fail("device hung up");
        } else {
          return Fail("read: " + ErrnoText(errno));
        }
      }
      if (would_block && (revents & (POLLHUP | POLLERR)) != 0 && (revents & POLLIN) == 0) {
        return Fail("device hung up");
      }
      if (out.size() > before || bytes_this_call >= kMaxBytesPerRead) return {};
      if (SteadyNowNs() >= deadline_ns) return {};
    }
  }

  std::string Describe() const override { return "slcan:" + device_; }

  SourceCounters Counters() const override {
    SlcanCounters total = previous_;
    total += parser_.counters();
    return {{"bytes", total.bytes},
            {"frames", total.frames},
            {"acks", total.acks},
            {"nacks", total.nacks},
            {"bad_lines", total.bad_lines},
            {"device_errors", device_errors_},
            {"reopen_attempts", reopener_.attempts()},
            {"reopens", reopener_.reopens()}};
  }

 private:
  // Parses received bytes and appends the frames they complete.
  void Deliver(std::string_view bytes, std::vector<TimedFrame>& out) {
    const int64_t now_ns = SteadyNowNs();
    parsed_.clear();
    parser_.Feed(bytes, parsed_);
    const size_t first = out.size();
    for (const SlcanFrame& parsed : parsed_) {
      TimedFrame frame;
      frame.frame = parsed.frame;
      frame.receive_ns = now_ns;
      if (parsed.timestamp_ms) frame.source_t = *parsed.timestamp_ms * 1e-3;
      frame.after_gap = parsed.after_bad_line || std::exchange(reopened_, false);
      out.push_back(frame);
    }
    clock_.Stamp(out, first, now_ns);
  }

  // Closes the device after a failure; a later Read reopens it.
  ReadOutcome Fail(const std::string& reason) {
    fd_.Reset();
    ++device_errors_;
    reopener_.Closed(reason);
    return {ReadStatus::kError, Describe() + ": " + reason};
  }

  // Waits (until `deadline_ns` at most) for the next attempt and reopens; empty on success,
  // otherwise the error to report.
  std::string TryReopen(int64_t deadline_ns) {
    OpenedFd opened =
        reopener_.TryReopen(deadline_ns, Describe(), [&] { return OpenDevice(device_); });
    if (!opened.ok()) return opened.Message();
    fd_ = std::move(opened).value();
    previous_ += parser_.counters();
    parser_ = SlcanParser{};  // a line cut by the hang-up must not glue onto the new stream
    reopened_ = true;         // nor a message cut by it: the next frame comes after a gap
    return {};
  }

  std::string device_;
  UniqueFd fd_;
  SlcanParser parser_;
  SlcanCounters previous_;  // counters of the parsers before the last reopen
  std::vector<SlcanFrame> parsed_;
  BatchClock clock_;
  bool reopened_ = false;  // the device was reopened since the last frame
  std::array<char, kReadChunk> buffer_{};
  Reopener reopener_;
  uint64_t device_errors_ = 0;
};

}  // namespace

OpenResult OpenSlcan(const std::string& device) {
  auto opened = OpenDevice(device);
  if (!opened.ok()) return opened.errors();
  return std::make_unique<SlcanSource>(device, std::move(opened).value());
}

}  // namespace slam::hw
