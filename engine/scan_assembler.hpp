#pragma once
// Robot events -> scans (docs/design.md section 2): scanner samples grouped into half turns of the
// platform (one scan each), every sample posed by dead reckoning from the odometry and gyro
// around it. Works incrementally on events in arrival order, as the link delivers them; the
// recorded-experiment replay and the live server use the same code.
//
// What it tolerates, and counts:
// - wrap-around of the platform angle (16 bits) and of the encoder counters (32 bits);
// - lost readings (gaps in the sequence numbers): a few lost samples make a sparser scan;
// - silences longer than the configured gaps (scanner or odometry): the scan in progress is
//   discarded, and grouping restarts at the next sample;
// - events whose time is not after the previous one of their kind: dropped;
// - odometry that moves a treel further than the robot can (OdometryIntegrator::Plausible: a
//   spoofed or corrupted message, counters that restarted): refused as motion, taken as the new
//   reference; like a silence, the scan in progress is discarded;
// - samples that no odometry brackets (before the first reading, or odometry stalled): dropped.

#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "engine/odometry.hpp"
#include "engine/robot.hpp"
#include "engine/scan.hpp"

namespace slam {

struct ScanAssemblerConfig {
  /// A scanner silence longer than this discards the scan in progress (60 Hz: 15 samples).
  double max_sample_gap_s = 0.25;
  /// Samples are posed only between odometry readings at most this far apart.
  double max_odometry_gap_s = 0.25;
  /// Samples waiting longer than this for the odometry to catch up are dropped.
  double max_odometry_wait_s = 0.5;
  /// A half turn longer than this many samples (68 s at 60 Hz) is abandoned: the platform has
  /// stopped turning (its samples would pile up without bound).
  int64_t max_scan_samples = 4096;

  /// Problems as "/key: detail" lines; empty when valid.
  std::vector<std::string> Validate() const;
};

struct ScanAssemblerCounters {
  uint64_t odometry = 0;          // odometry events accepted
  uint64_t samples = 0;           // scanner samples accepted
  uint64_t samples_in_scans = 0;  // samples delivered inside scans
  uint64_t scans = 0;             // scans delivered
  uint64_t out_of_order = 0;      // events not after the previous of their kind: dropped
  uint64_t odometry_lost = 0;     // readings missing from the sequence numbers
  uint64_t samples_lost = 0;
  uint64_t odometry_gaps = 0;    // silences longer than max_odometry_gap_s
  uint64_t odometry_jumps = 0;   // readings moving further than the robot can: refused
  uint64_t sample_gaps = 0;      // silences longer than max_sample_gap_s
  uint64_t samples_unposed = 0;  // samples no odometry brackets: dropped
  uint64_t scans_discarded = 0;  // scans in progress abandoned at a gap (or too long)
  uint64_t scans_too_long = 0;   // of those, abandoned at max_scan_samples: platform stalled
};

class ScanAssembler {
 public:
  explicit ScanAssembler(const RobotDescription& robot, const ScanAssemblerConfig& config = {});

  /// Feeds one event; appends to `out` every scan it completes. A scan completes when the first
  /// sample of the next half turn has been posed. Scans follow one another: each begins where
  /// the previous one delivered ended (t_begin, odom_begin), also after a scan was abandoned at
  /// a gap, so that the motion in the gap reaches the SLAM.
  void Add(const RobotEvent& event, std::vector<Scan>& out);

  /// The dead-reckoned pose at the last odometry reading, and its time (nothing before any).
  std::optional<TimedPose> LastOdometry() const;

  const ScanAssemblerCounters& counters() const { return counters_; }

 private:
  struct Pending {
    ScannerReading reading;
    bool break_before = false;  // a silence precedes it: the scan in progress ends unfinished
  };

  void AddOdometry(const OdometryReading& reading, std::vector<Scan>& out);
  void AddSample(const ScannerReading& reading, std::vector<Scan>& out);
  void PosePending(std::vector<Scan>& out);
  void Group(const Pending& sample, const Pose2& odom, std::vector<Scan>& out);
  void DropPending(bool scan_in_progress_broken);
  void DiscardScan();

  ScanAssemblerConfig config_;
  OdometryIntegrator integrator_;
  std::deque<TimedPose> odometry_;  // recent dead-reckoned poses, time-ordered
  std::deque<Pending> pending_;     // samples waiting for odometry after them
  std::optional<OdometryReading> last_odometry_;
  std::optional<ScannerReading> last_sample_;

  // Grouping of posed samples into half turns.
  std::optional<Scan> current_;
  std::optional<TimedPose> last_end_;  // where the last scan delivered ended
  std::optional<uint16_t> previous_angle_;
  int64_t progress_ = 0;  // platform rotation since the reference sample, raw units
  int64_t half_turn_ = 0;
  bool break_next_ = false;  // a sample was dropped: the scan in progress has a hole
  ScanAssemblerCounters counters_;
};

}  // namespace slam
