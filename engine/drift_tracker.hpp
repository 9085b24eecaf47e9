#pragma once
// What the odometry drifts by and the map has not yet corrected: the variance accumulated since
// the last informative match (it widens phase B's search when readings return), the heading
// corrections a range scanner's matches have been making (they narrow its heading search), and
// each particle's estimate of the odometry's heading drift (its prediction takes it out).

#include <cstddef>
#include <optional>
#include <span>
#include <vector>

#include "engine/motion_model.hpp"
#include "engine/particle_set.hpp"
#include "engine/pose.hpp"
#include "engine/scan.hpp"

namespace slam {

class DriftTracker {
 public:
  /// A scan matched on at least this many readings corrects the drift (a few readings along one
  /// wall do not).
  static constexpr size_t kInformativeMatches = 12;

  /// `heading_from_gyro`: the heading drifts with time (a gyro's bias), else with the distance
  /// driven (the wheels'). `range_scanner`: the heading search follows the matches' corrections.
  DriftTracker(bool heading_from_gyro, bool range_scanner)
      : per_metre_(!heading_from_gyro), range_scanner_(range_scanner) {}

  /// Forgets everything (a restored map and pose are where the robot is).
  void Reset();

  /// Phase B's least heading search (rad), for a parameter set whose least is `set_least`: for a
  /// range scanner, kCorrectionSigmas times the root mean square of the heading corrections of
  /// its recent informative matches, within [kLeastSearchShare, 1] of the set's.
  double LeastSearchAngle(double set_least) const;
  /// Deviation of the heading's drift over a scan with this motion noise (rad): its two
  /// rotations' plus what is left uncorrected since the last informative match.
  double DriftAngle(const MotionNoise& noise) const;
  /// The same for the position (m).
  double DriftPos(const MotionNoise& noise) const;
  /// What a particle's heading drift is multiplied by over a scan: its time (s) where the
  /// heading comes from a gyro, its signed distance (m) where it comes from the encoders.
  double DriftSpan(const Scan& scan, const MotionDelta& motion) const;

  /// After an informative match: nothing is left uncorrected; the heading each particle's match
  /// corrected beyond its `nominal` end pose (its drift already taken out) is drift still there,
  /// learnt into its heading_drift (per second, a scan's worth over kHeadingDriftTimeS; per
  /// metre, weighted by the distance driven); a range scanner's correction average follows,
  /// unless the robot stood still. `set_least` as LeastSearchAngle's.
  void LearnFromMatch(const Scan& scan, double drift_span, std::span<const Pose2> chosen,
                      std::span<const Pose2> nominal, double set_least,
                      std::vector<Particle>& particles);
  /// After a scan refined without an informative match: its motion's noise (and its
  /// translation `trans`, turned by the heading's uncorrected drift) adds to what is uncorrected.
  void AddUncorrected(const MotionNoise& noise, double trans);

 private:
  bool per_metre_;
  bool range_scanner_;
  // Variance of the drift the map has not corrected since the last informative match (position
  // m^2, heading rad^2).
  double unmatched_var_pos_ = 0.0;
  double unmatched_var_angle_ = 0.0;
  // Mean square of the heading corrections of a range scanner's informative matches (rad^2),
  // averaged over the last scans; none before the first.
  std::optional<double> correction_var_angle_;
};

}  // namespace slam
