// SocketCAN raw sockets (Linux). Kernels without AF_CAN (such as the build machines') make
// OpenSocketCan fail with a message saying so.
//
// Errors: ENETDOWN (interface down) is reported as kError and the socket is kept (it receives
// again once the interface is up); any other read error closes the socket, reports kError, and
// later Reads reopen it (attempts at least 200 ms apart; kError while closed).

#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <thread>

#include "hw_link/fd_util.hpp"
#include "hw_link/transports.hpp"

namespace slam::hw {
namespace {

constexpr size_t kMaxFramesPerRead = 256;

// A raw CAN socket bound to `interface` (CAN FD frames enabled when possible), or why not.
OpenedFd OpenSocket(const std::string& interface) {
  UniqueFd fd(::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW));
  if (!fd.valid()) {
    const int err = errno;
    if (err == EAFNOSUPPORT) {
      return Error("SocketCAN is not available: this kernel has no AF_CAN support (socket: " +
                   ErrnoText(err) + ")");
    }
    return Error("cannot create a SocketCAN socket for '" + interface + "': " + ErrnoText(err));
  }
  if (interface.empty() || interface.size() >= IFNAMSIZ) {
    return Error("invalid CAN interface name '" + interface + "'");
  }
  const unsigned int index = ::if_nametoindex(interface.c_str());
  if (index == 0) {
    const int err = errno;
    return Error("no CAN interface '" + interface + "': " + ErrnoText(err));
  }
  const int on = 1;  // best effort: older kernels deliver classic frames only
  ::setsockopt(fd.get(), SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on);
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(index);
  if (::bind(fd.get(), reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    const int err = errno;
    return Error("cannot bind to CAN interface '" + interface + "': " + ErrnoText(err));
  }
  return fd;
}

class SocketCanSource final : public FrameSource {
 public:
  SocketCanSource(std::string interface, UniqueFd fd)
      : interface_(std::move(interface)), fd_(std::move(fd)) {}

  ReadOutcome Read(std::vector<TimedFrame>& out, std::chrono::milliseconds timeout) override {
    const int64_t deadline_ns = SteadyNowNs() + std::max<int64_t>(0, timeout.count()) * 1'000'000;
    if (!fd_.valid()) {
      std::string failure = TryReopen(deadline_ns);
      if (!failure.empty()) return {ReadStatus::kError, std::move(failure)};
    }
    const size_t before = out.size();
    while (true) {
      const int revents = PollReadable(fd_.get(), deadline_ns);
      if (revents < 0) return Fail("poll: " + ErrnoText(errno));
      if (revents == 0) return {};
      for (size_t count = 0; count < kMaxFramesPerRead; ++count) {
        canfd_frame raw{};
        const ssize_t n = ::read(fd_.get(), &raw, sizeof raw);
        if (n < 0) {
          if (errno == EINTR) continue;
          if (errno == EAGAIN || errno == EWOULDBLOCK) break;
          if (errno == ENETDOWN) {
            return {ReadStatus::kError, Describe() + ": interface is down"};
          }
          return Fail("read: " + ErrnoText(errno));
        }
        Deliver(raw, static_cast<size_t>(n), out);
      }
      if (out.size() > before || SteadyNowNs() >= deadline_ns) return {};
    }
  }

  std::string Describe() const override { return "socketcan:" + interface_; }

  SourceCounters Counters() const override {
    return {{"frames", frames_},
            {"fd_frames", fd_frames_},
            {"error_frames", error_frames_},
            {"short_reads", short_reads_},
            {"reopen_attempts", reopener_.attempts()},
            {"reopens", reopener_.reopens()}};
  }

 private:
  // Converts one kernel frame (CAN_MTU or CANFD_MTU bytes) and appends it.
  void Deliver(const canfd_frame& raw, size_t bytes, std::vector<TimedFrame>& out) {
    const bool fd = bytes == CANFD_MTU;
    if (!fd && bytes != CAN_MTU) {
      ++short_reads_;
      return;
    }
    if ((raw.can_id & CAN_ERR_FLAG) != 0) {
      ++error_frames_;
      return;
    }
    TimedFrame frame;
    frame.frame.extended = (raw.can_id & CAN_EFF_FLAG) != 0;
    frame.frame.remote = (raw.can_id & CAN_RTR_FLAG) != 0;
    frame.frame.fd = fd;
    frame.frame.id = raw.can_id & (frame.frame.extended ? CAN_EFF_MASK : CAN_SFF_MASK);
    const size_t max_len = fd ? static_cast<size_t>(kCanFdMaxData) : kCanMaxData;
    const size_t len = std::min<size_t>(raw.len, max_len);
    frame.frame.len = static_cast<uint8_t>(len);
    if (!frame.frame.remote) std::memcpy(frame.frame.data.data(), raw.data, len);
    frame.receive_ns = SteadyNowNs();
    frame.t = static_cast<double>(frame.receive_ns) * 1e-9;
    out.push_back(frame);
    ++frames_;
    if (fd) ++fd_frames_;
  }

  // Closes the socket after a failure; a later Read reopens it.
  ReadOutcome Fail(const std::string& reason) {
    fd_.Reset();
    reopener_.Closed(reason);
    return {ReadStatus::kError, Describe() + ": " + reason};
  }

  // Waits (until `deadline_ns` at most) for the next attempt and reopens; empty on success,
  // otherwise the error to report.
  std::string TryReopen(int64_t deadline_ns) {
    OpenedFd opened =
        reopener_.TryReopen(deadline_ns, Describe(), [&] { return OpenSocket(interface_); });
    if (!opened.ok()) return opened.Message();
    fd_ = std::move(opened).value();
    return {};
  }

  std::string interface_;
  UniqueFd fd_;
  Reopener reopener_;
  uint64_t frames_ = 0;
  uint64_t fd_frames_ = 0;
  uint64_t error_frames_ = 0;
  uint64_t short_reads_ = 0;
};

}  // namespace

OpenResult OpenSocketCan(const std::string& interface) {
  auto opened = OpenSocket(interface);
  if (!opened.ok()) return opened.errors();
  return std::make_unique<SocketCanSource>(interface, std::move(opened).value());
}

bool SocketCanAvailable() {
  const UniqueFd fd(::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW));
  return fd.valid();
}

}  // namespace slam::hw
