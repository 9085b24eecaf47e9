#pragma once
// A CAN frame as every transport delivers it, and the times attached to it on reception.

#include <array>
#include <cstdint>
#include <optional>
#include <string>

namespace slam::hw {

/// Largest payload of any frame we may meet (CAN FD); Aseba itself uses classic 8-byte frames.
inline constexpr int kCanFdMaxData = 64;
inline constexpr int kCanMaxData = 8;
inline constexpr uint32_t kCanStandardIdMax = 0x7FF;
inline constexpr uint32_t kCanExtendedIdMax = 0x1FFFFFFF;

/// One frame. Transports keep frames that Aseba does not use (extended, remote, FD) so that the
/// reassembler can count them.
struct CanFrame {
  uint32_t id = 0;  // 11 bits, or 29 bits when `extended`
  uint8_t len = 0;  // data bytes: 0..8, or 0..64 when `fd`; a remote frame's requested length
  bool extended = false;
  bool remote = false;
  bool fd = false;
  std::array<uint8_t, kCanFdMaxData> data{};

  /// Equal ids, flags, lengths and the first `len` data bytes (remote frames carry no data).
  friend bool operator==(const CanFrame& a, const CanFrame& b);
};

/// A received frame with its times.
struct TimedFrame {
  CanFrame frame;
  /// The time downstream uses, in seconds: the recording's own time for logs and the virtual
  /// marXbot, the monotonic receive time (steady clock) for live transports.
  double t = 0.0;
  /// Monotonic receive time (std::chrono::steady_clock), nanoseconds.
  int64_t receive_ns = 0;
  /// The log's or the device's own timestamp, when the transport has one (seconds).
  std::optional<double> source_t;
  /// The transport knows frames were lost just before this one (a datagram missing from the
  /// sequence, a device reopened, a garbled log line): messages in progress cannot be finished.
  bool after_gap = false;
};

/// The frame in candump's compact form, e.g. "102#2000010000402C01", "1F334455#R", "123##1AB".
std::string FormatCompact(const CanFrame& frame);

/// The steady clock now, in nanoseconds (what TimedFrame::receive_ns holds).
int64_t SteadyNowNs();

}  // namespace slam::hw
