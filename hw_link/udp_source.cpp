// CAN frames in cannelloni datagrams on a UDP port.

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <optional>
#include <span>

#include "hw_link/cannelloni.hpp"
#include "hw_link/fd_util.hpp"
#include "hw_link/transports.hpp"

namespace slam::hw {
namespace {

constexpr size_t kMaxDatagram = 65536;        // larger than any UDP payload
constexpr int kReceiveBufferBytes = 1 << 20;  // absorbs bursts while the link is busy
constexpr size_t kMaxDatagramsPerRead = 256;
// A datagram of 64 KiB holds up to 13 000 frames without data: a read stops taking datagrams
// beyond this many frames, so that what one read holds stays a few megabytes.
constexpr size_t kMaxFramesPerRead = 16384;

class UdpSource final : public FrameSource {
 public:
  UdpSource(UniqueFd fd, std::string address, uint16_t port, std::optional<in_addr> sender,
            std::string sender_text)
      : fd_(std::move(fd)),
        address_(std::move(address)),
        port_(port),
        sender_(sender),
        sender_text_(std::move(sender_text)) {}

  ReadOutcome Read(std::vector<TimedFrame>& out, std::chrono::milliseconds timeout) override {
    const int64_t deadline_ns = SteadyNowNs() + std::max<int64_t>(0, timeout.count()) * 1'000'000;
    const size_t before = out.size();
    while (true) {
      const int revents = PollReadable(fd_.get(), deadline_ns);
      if (revents < 0) return {ReadStatus::kError, Describe() + ": poll: " + ErrnoText(errno)};
      if (revents == 0) return {};
      for (size_t count = 0;
           count < kMaxDatagramsPerRead && out.size() - before < kMaxFramesPerRead; ++count) {
        sockaddr_in from{};
        socklen_t from_size = sizeof from;
        const ssize_t n = ::recvfrom(fd_.get(), buffer_.data(), buffer_.size(), MSG_DONTWAIT,
                                     reinterpret_cast<sockaddr*>(&from), &from_size);
        if (n < 0) {
          if (errno == EINTR) continue;
          if (errno == EAGAIN || errno == EWOULDBLOCK) break;
          return {ReadStatus::kError, Describe() + ": recv: " + ErrnoText(errno)};
        }
        if (sender_ && (from.sin_family != AF_INET || from.sin_addr.s_addr != sender_->s_addr)) {
          ++foreign_datagrams_;
          continue;
        }
        Deliver(std::span<const uint8_t>(buffer_.data(), static_cast<size_t>(n)), out);
      }
      if (out.size() > before || SteadyNowNs() >= deadline_ns) return {};
    }
  }

  std::string Describe() const override {
    std::string text = "udp:" + address_ + ":" + std::to_string(port_);
    if (sender_) text += ",from=" + sender_text_;
    return text;
  }

  SourceCounters Counters() const override {
    return {{"datagrams", datagrams_},
            {"bad_datagrams", bad_datagrams_},
            {"foreign_datagrams", foreign_datagrams_},
            {"frames", frames_},
            {"lost", sequence_.counters().lost},
            {"reordered", sequence_.counters().reordered}};
  }

  uint16_t port() const { return port_; }

 private:
  // Decodes one datagram and appends its frames.
  void Deliver(std::span<const uint8_t> bytes, std::vector<TimedFrame>& out) {
    const int64_t now_ns = SteadyNowNs();
    ++datagrams_;
    const Result<CannelloniDatagram> decoded = DecodeCannelloni(bytes);
    if (!decoded.ok()) {
      ++bad_datagrams_;
      return;
    }
    const CannelloniDatagram* datagram = &decoded.value();
    const bool in_sequence = sequence_.Observe(datagram->sequence);
    const size_t first = out.size();
    for (const CanFrame& can_frame : datagram->frames) {
      TimedFrame frame;
      frame.frame = can_frame;
      frame.receive_ns = now_ns;
      out.push_back(frame);
      ++frames_;
    }
    clock_.Stamp(out, first, now_ns);
    if (!in_sequence && out.size() > first) out[first].after_gap = true;
  }

  UniqueFd fd_;
  std::string address_;
  uint16_t port_;
  std::optional<in_addr> sender_;  // the only address datagrams are taken from, if any
  std::string sender_text_;
  std::array<uint8_t, kMaxDatagram> buffer_{};
  SequenceTracker sequence_;
  BatchClock clock_;
  uint64_t datagrams_ = 0;
  uint64_t bad_datagrams_ = 0;
  uint64_t foreign_datagrams_ = 0;
  uint64_t frames_ = 0;
};

}  // namespace

OpenResult OpenUdp(uint16_t port, const std::string& address, const std::string& sender) {
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(port);
  if (::inet_pton(AF_INET, address.c_str(), &addr.sin_addr) != 1) {
    return Error("invalid IPv4 address '" + address + "' for the UDP source");
  }
  std::optional<in_addr> sender_addr;
  if (!sender.empty()) {
    in_addr parsed{};
    if (::inet_pton(AF_INET, sender.c_str(), &parsed) != 1) {
      return Error("invalid IPv4 sender address '" + sender + "' for the UDP source");
    }
    sender_addr = parsed;
  }
  const std::string where = address + ":" + std::to_string(port);
  UniqueFd fd(::socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0));
  if (!fd.valid()) {
    const int err = errno;
    return Error("cannot create a UDP socket for " + where + ": " + ErrnoText(err));
  }
  const int size = kReceiveBufferBytes;
  ::setsockopt(fd.get(), SOL_SOCKET, SO_RCVBUF, &size, sizeof size);  // best effort
  if (::bind(fd.get(), reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    const int err = errno;
    return Error("cannot bind UDP " + where + ": " + ErrnoText(err));
  }
  sockaddr_in bound{};
  socklen_t bound_size = sizeof bound;
  if (::getsockname(fd.get(), reinterpret_cast<sockaddr*>(&bound), &bound_size) != 0) {
    const int err = errno;
    return Error("cannot read the address of UDP " + where + ": " + ErrnoText(err));
  }
  return std::make_unique<UdpSource>(std::move(fd), address, ntohs(bound.sin_port), sender_addr,
                                     sender);
}

uint16_t BoundUdpPort(const FrameSource& source) {
  const auto* udp = dynamic_cast<const UdpSource*>(&source);
  return udp != nullptr ? udp->port() : 0;
}

}  // namespace slam::hw
