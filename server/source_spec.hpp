#pragma once
// Opening a frame source from its command-line form (slamd --source, docs/design.md section 6):
//   sim:WORLD          the virtual marXbot in a built-in arena or a world.json file
//   candump:FILE       a candump -l log
//   slcan:DEVICE       an slcan adapter (tty or pseudo-terminal)
//   udp:PORT           cannelloni datagrams on PORT of loopback, or udp:ADDRESS:PORT, with
//                      ,from=SENDER to take datagrams from that sender only
//   socketcan:IFACE    a SocketCAN interface

#include <cstdint>
#include <string>

#include "engine/robot.hpp"
#include "hw_link/transports.hpp"
#include "sim/scenario.hpp"

namespace slam::server {

struct SourceSpecOptions {
  bool paced = true;  // sim and candump: in real time (times speed); false: as fast as read
  double speed = 1.0;
  uint64_t seed = 1;        // sim: the simulation's seed
  double duration_s = 0.0;  // sim: 0 = endless
  // sim: how the virtual marXbot's odometry errs (slam-sim's default: a tracked robot's)
  sim::OdometryProfile odometry = sim::OdometryProfile::kTracked;
};

/// The source `spec` names, or a one-line error (unknown kind, bad port, missing file, ...).
hw::OpenResult OpenSourceSpec(const std::string& spec, const RobotDescription& robot,
                              const SourceSpecOptions& options = {});

}  // namespace slam::server
