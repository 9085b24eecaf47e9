#pragma once
// The virtual marXbot: the simulated robot (Simulator) on the other side of the link,
// emitting exactly the real robot's frames (docs/design.md section 5) through the Aseba fragmenter
// and a model of the CAN bus, so that everything downstream is exercised.

#include <cstdint>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "engine/pose.hpp"
#include "engine/result.hpp"
#include "engine/robot.hpp"
#include "engine/thread_safety.hpp"
#include "hw_link/can_frame.hpp"
#include "hw_link/frame_source.hpp"
#include "sim/scenario.hpp"
#include "sim/world.hpp"

namespace slam::sim {

/// A classic CAN bus: each node sends its frames in order; when several nodes have a frame
/// ready, the lowest id wins arbitration; a frame is received when its transmission ends.
class CanBusModel {
 public:
  explicit CanBusModel(double bitrate_bps = 1e6) : bitrate_bps_(bitrate_bps) {}

  /// Queues one node's frames, ready to send from time t (seconds). Calls come with
  /// non-decreasing t, and t not before the last Deliver's `until`.
  void Send(const std::vector<hw::CanFrame>& frames, double t);

  /// Appends (reception time, frame), in bus order, for every transmission starting before
  /// `until`.
  void Deliver(double until, std::vector<std::pair<double, hw::CanFrame>>& out);

  /// Frames queued and not yet delivered.
  size_t pending() const;

  /// Time on the bus of one frame (bits including a typical amount of stuffing / bit rate).
  double FrameSeconds(const hw::CanFrame& frame) const;

 private:
  struct Queued {
    double ready_t;
    hw::CanFrame frame;
  };
  double bitrate_bps_;
  double bus_t_ = 0.0;                            // the bus is idle from this time
  std::map<uint32_t, std::deque<Queued>> nodes_;  // by source node (the id's low byte)
};

/// Every frame of a simulated run, in bus order, with reception times in seconds of simulated
/// time (the readings' times are when each node hands its event to the bus).
std::vector<std::pair<double, hw::CanFrame>> SimulatedFrames(const RobotDescription& robot,
                                                             const ScenarioOutput& output);

struct VirtualMarxbotOptions {
  bool paced = true;  // true: in real time (times speed); false: as fast as read
  double speed = 1.0;
  double duration_s = 0.0;  // 0: runs until stopped; otherwise kEnd after this
};

/// The virtual marXbot as a live FrameSource. Frame times are simulated seconds since its start
/// (t and source_t); receive_ns is when Read handed the frame over.
class VirtualMarxbotSource : public hw::FrameSource {
 public:
  VirtualMarxbotSource(const World& world, std::string world_name, const RobotDescription& robot,
                       const ScenarioConfig& config, const VirtualMarxbotOptions& options);

  hw::ReadOutcome Read(std::vector<hw::TimedFrame>& out,
                       std::chrono::milliseconds timeout) override;
  std::string Describe() const override;
  hw::SourceCounters Counters() const override;
  /// How its odometry errs: the ScenarioConfig's profile ("tracked", "gentle" or "custom").
  const std::string& odometry_profile() const { return odometry_profile_; }

  /// Ground-truth poses kept, the newest: the reader (slamd's service, once a scan) keeps its own
  /// copy. Keeping them all grew slamd by 55 KB a minute (30 poses a second) for nothing.
  static constexpr double kKeptTruthS = 60.0;

  /// The overhead tracker's poses of the last kKeptTruthS (thread-safe).
  std::vector<TimedPose> GroundTruth() const;
  /// Appends the tracker's poses from index `first` on (counting every pose made since the
  /// start) to `out`, as far as they are still kept; returns how many were made in all (so a
  /// reader copies only what is new).
  size_t GroundTruthSince(size_t first, std::vector<TimedPose>& out) const;

  /// Lifts the robot and sets it down at `target` or, when none is given, at the true pose it had
  /// half its run ago (to within the spacing of the poses it remembers: kRememberedPoseS at
  /// first, doubled whenever kRememberedPoses are kept), at the next simulation step
  /// (Simulator::Kidnap: its odometry does not see it, the ground truth does). Thread-safe: an
  /// HTTP thread may call it while another calls Read. The pose it will be set down at, or why it
  /// will not (the target is not free; nothing is then requested).
  Result<Pose2> Kidnap(std::optional<Pose2> target);
  /// The kidnappings done so far (thread-safe).
  uint64_t kidnaps() const;

  /// The true poses remembered for Kidnap's default target: one every kRememberedPoseS, and when
  /// kRememberedPoses are kept, every other one is forgotten and the spacing doubles.
  static constexpr double kRememberedPoseS = 1.0;
  static constexpr size_t kRememberedPoses = 1024;

 private:
  void Advance(double until_s);
  void RememberPose(double t, const Pose2& pose) SLAM_REQUIRES(kidnap_mutex_);

  std::string world_name_;
  std::string odometry_profile_;
  RobotDescription robot_;
  VirtualMarxbotOptions options_;
  Simulator simulator_;
  CanBusModel bus_;
  std::deque<std::pair<double, hw::CanFrame>> ready_;  // delivered by the bus, not yet read
  int64_t start_ns_ = 0;                               // steady time of the first Read
  bool started_ = false;
  uint64_t events_ = 0;
  uint64_t frames_ = 0;
  mutable Mutex truth_mutex_;
  std::deque<TimedPose> ground_truth_ SLAM_GUARDED_BY(truth_mutex_);  // the newest poses
  size_t truth_dropped_ SLAM_GUARDED_BY(truth_mutex_) = 0;            // older poses, no longer kept
  const World world_;                                                 // for Kidnap's check
  const double robot_radius_m_;
  double next_remembered_t_ = 0.0;  // simulated time of the next pose to remember (Read's thread)
  mutable Mutex kidnap_mutex_;
  std::optional<Pose2> requested_kidnap_ SLAM_GUARDED_BY(kidnap_mutex_);
  uint64_t kidnaps_ SLAM_GUARDED_BY(kidnap_mutex_) = 0;
  double simulated_s_ SLAM_GUARDED_BY(kidnap_mutex_) = 0.0;  // simulator time after Advance
  std::vector<TimedPose> remembered_ SLAM_GUARDED_BY(kidnap_mutex_);  // true poses, time-ordered
  double remembered_spacing_s_ SLAM_GUARDED_BY(kidnap_mutex_) = kRememberedPoseS;
};

}  // namespace slam::sim
