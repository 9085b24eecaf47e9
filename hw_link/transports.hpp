#pragma once
// The real transports. Each fails to open with a clear one-line message (never throws through
// the link); live transports reopen by themselves after the device goes away.

#include <memory>
#include <string>

#include "engine/result.hpp"
#include "hw_link/frame_source.hpp"

namespace slam::hw {

/// A source, or the reason it could not be opened.
using OpenResult = Result<std::unique_ptr<FrameSource>>;

struct CandumpReplayOptions {
  /// false: as fast as the reader takes frames; true: paced by the log's timestamps.
  bool paced = false;
  double speed = 1.0;  // with paced: 2.0 plays twice as fast as recorded
};

/// Replays a candump -l log. Frame times are the log's, with wall-clock jumps (a step back, or more
/// than 5 s of silence) taken out and counted ("clock_jumps"). Garbage lines are counted and
/// skipped
/// ("bad_lines"), comments counted ("ignored_lines"); the end of the file is kEnd.
OpenResult OpenCandumpReplay(const std::string& path, const CandumpReplayOptions& options = {});

/// slcan adapter on a tty or pseudo-terminal: raw mode, sends "C", "S8", "O" on open; frame times
/// are the monotonic receive time, the frames of one read spread over the time since the previous
/// one (BatchClock; the adapter's time stamp, if any, goes to source_t). On hang-up or read error
/// it reports kError and reopens the device on later reads.
OpenResult OpenSlcan(const std::string& device);

/// CAN frames in cannelloni datagrams on a UDP port, bound on `address` (loopback unless the
/// robot's bridge is elsewhere; "0.0.0.0" = every address). With `sender` (an IPv4 address),
/// datagrams from any other address are dropped before they are read, and counted
/// (foreign_datagrams): anyone who can reach the port could otherwise drive the robot's pose.
/// Lost and reordered datagrams are counted by sequence number. Frame times are the monotonic
/// receive time, the frames of a datagram spread over the time since the previous one
/// (BatchClock).
OpenResult OpenUdp(uint16_t port, const std::string& address = "127.0.0.1",
                   const std::string& sender = "");

/// The port the UDP source is bound to (useful with port 0), or 0 for other sources.
uint16_t BoundUdpPort(const FrameSource& source);

/// SocketCAN raw socket on `interface`. On kernels without AF_CAN it fails with a message saying
/// so.
OpenResult OpenSocketCan(const std::string& interface);

/// True when this kernel can open a CAN_RAW socket (tests skip SocketCAN otherwise).
bool SocketCanAvailable();

}  // namespace slam::hw
