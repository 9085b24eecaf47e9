#include "engine/drift_tracker.hpp"

#include <algorithm>
#include <cmath>

namespace slam {
namespace {

// The heading drift estimate follows the heading corrections of informative matches averaged
// over this time (s): long enough to average out their jitter (about half a degree a scan on a
// perfect map, docs/accuracy.md), short enough to follow a MEMS gyro's bias as it wanders (over
// minutes).
constexpr double kHeadingDriftTimeS = 30.0;
// The estimate's bound: more than any gyro's bias after its start-up calibration.
constexpr double kMaxHeadingDriftDegS = 2.0;
// A heading from the encoders errs with the distance driven, not with time: wheels of unequal
// diameters turn the odometry by a constant angle per metre (Borenstein and Feng's systematic
// odometry errors; docs/laser.md), and a robot standing still does not drift. The estimate
// averages over this distance (about the 30 s above at the 0.2 to 0.3 m/s robots drive), and its
// bound allows a 5 % mismatch of the wheels on a 30 cm axle.
constexpr double kHeadingDriftDistanceM = 10.0;
constexpr double kMaxHeadingDriftDegM = 10.0;
// A range scanner's heading search follows the heading corrections its informative matches have
// been making (their root mean square over about kCorrectionAveragingScans scans): it spans
// kCorrectionSigmas of them, within the parameter set's minimum angle uncertainty (a robot whose
// odometry errs like a tracked one keeps the set's search) and never below kLeastSearchShare of
// it. A good odometry narrows it, so that a match on a few dozen rays cannot walk the heading
// away one plausible step after another (docs/laser.md, "A heading search that follows the
// corrections").
constexpr double kCorrectionSigmas = 3.0;
constexpr double kCorrectionAveragingScans = 30.0;
constexpr double kLeastSearchShare = 0.25;
// Scans that drove less than this tell a drift per metre little: their correction, weighted
// down, is mostly the match's jitter (the bound over 5 cm is half a degree).
constexpr double kMinHeadingDriftStepM = 0.05;
// A scan whose odometry moved less than kMinHeadingDriftStepM and turned less than this stood
// still: its heading correction is the match's jitter, not the odometry's error, and does not
// narrow the search (a robot parked for a minute would set off with the narrowest one).
constexpr double kStillTurnDeg = 1.0;

constexpr double Square(double x) { return x * x; }

}  // namespace

void DriftTracker::Reset() {
  unmatched_var_pos_ = 0.0;
  unmatched_var_angle_ = 0.0;
  correction_var_angle_.reset();
}

double DriftTracker::LeastSearchAngle(double set_least) const {
  if (!range_scanner_ || !correction_var_angle_) return set_least;
  return std::clamp(kCorrectionSigmas * std::sqrt(*correction_var_angle_),
                    kLeastSearchShare * set_least, set_least);
}

double DriftTracker::DriftAngle(const MotionNoise& noise) const {
  return std::sqrt(Square(noise.rot1) + Square(noise.rot2) + unmatched_var_angle_);
}

double DriftTracker::DriftPos(const MotionNoise& noise) const {
  return std::sqrt(Square(noise.trans) + unmatched_var_pos_);
}

double DriftTracker::DriftSpan(const Scan& scan, const MotionDelta& motion) const {
  return per_metre_ ? motion.trans : std::max(0.0, scan.t_end - scan.t_begin);
}

void DriftTracker::LearnFromMatch(const Scan& scan, double drift_span,
                                  std::span<const Pose2> chosen, std::span<const Pose2> nominal,
                                  double set_least, std::vector<Particle>& particles) {
  unmatched_var_pos_ = 0.0;
  unmatched_var_angle_ = 0.0;
  const double most = DegToRad(per_metre_ ? kMaxHeadingDriftDegM : kMaxHeadingDriftDegS);
  const double weight = drift_span / std::max(std::abs(drift_span), kMinHeadingDriftStepM);
  const Pose2 odometry = Between(scan.odom_begin, scan.odom_end);
  const bool still = std::hypot(odometry.x, odometry.y) < kMinHeadingDriftStepM &&
                     std::abs(odometry.theta) < DegToRad(kStillTurnDeg);
  if (range_scanner_ && !still) {
    double mean_sq = 0.0;
    for (size_t p = 0; p < particles.size(); ++p) {
      mean_sq += Square(NormalizeAngle(chosen[p].theta - nominal[p].theta));
    }
    mean_sq /= static_cast<double>(particles.size());
    // It starts where the set's own search stands.
    double& var = correction_var_angle_
                      ? *correction_var_angle_
                      : correction_var_angle_.emplace(Square(set_least / kCorrectionSigmas));
    var += (mean_sq - var) / kCorrectionAveragingScans;
  }
  for (size_t p = 0; p < particles.size(); ++p) {
    const double turn = NormalizeAngle(chosen[p].theta - nominal[p].theta);
    double& drift = particles[p].heading_drift;
    const double learnt =
        per_metre_ ? turn * weight / kHeadingDriftDistanceM : turn / kHeadingDriftTimeS;
    drift = std::clamp(drift - learnt, -most, most);
  }
}

void DriftTracker::AddUncorrected(const MotionNoise& noise, double trans) {
  unmatched_var_pos_ += Square(noise.trans) + Square(trans) * unmatched_var_angle_;
  unmatched_var_angle_ += Square(noise.rot1) + Square(noise.rot2);
}

}  // namespace slam
