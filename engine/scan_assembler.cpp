#include "engine/scan_assembler.hpp"

#include <cmath>
#include <cstdlib>

namespace slam {
namespace {

constexpr int64_t kFullTurnRaw = 65536;
constexpr int64_t kHalfTurnRaw = 32768;
constexpr double kOdometryHistoryS = 2.0;  // poses kept for interpolation

/// Readings missing between two sequence numbers (16-bit, wrapping); 0 for a step back.
uint64_t Missing(uint16_t previous, uint16_t current) {
  const auto skipped = static_cast<uint16_t>(current - previous - 1U);
  return skipped < 0x8000U ? skipped : 0U;
}

}  // namespace

std::vector<std::string> ScanAssemblerConfig::Validate() const {
  std::vector<std::string> errors;
  const auto positive = [&](double v, const char* key) {
    if (!(v > 0.0) || !std::isfinite(v)) errors.push_back(std::string("/") + key + ": must be > 0");
  };
  positive(max_sample_gap_s, "max_sample_gap_s");
  positive(max_odometry_gap_s, "max_odometry_gap_s");
  positive(max_odometry_wait_s, "max_odometry_wait_s");
  if (max_scan_samples < 2) errors.push_back("/max_scan_samples: must be >= 2");
  return errors;
}

ScanAssembler::ScanAssembler(const RobotDescription& robot, const ScanAssemblerConfig& config)
    : config_(config), integrator_(robot.base) {}

void ScanAssembler::Add(const RobotEvent& event, std::vector<Scan>& out) {
  if (const auto* odometry = std::get_if<OdometryReading>(&event)) {
    AddOdometry(*odometry, out);
  } else {
    AddSample(std::get<ScannerReading>(event), out);
  }
}

std::optional<TimedPose> ScanAssembler::LastOdometry() const {
  if (odometry_.empty()) return std::nullopt;
  return odometry_.back();
}

void ScanAssembler::AddOdometry(const OdometryReading& reading, std::vector<Scan>& out) {
  if (last_odometry_) {
    if (!(reading.t > last_odometry_->t)) {
      ++counters_.out_of_order;
      return;
    }
    counters_.odometry_lost += Missing(last_odometry_->seq, reading.seq);
    if (!integrator_.Plausible(reading)) {
      // Nothing is known of the motion up to it: samples waiting for it are lost, the pose
      // holds, and the reading is the reference for the next.
      ++counters_.odometry_jumps;
      while (!pending_.empty() && pending_.front().reading.t < reading.t) DropPending(true);
      odometry_.clear();
      integrator_.Rebase(reading);
      last_odometry_ = reading;
      odometry_.push_back({reading.t, integrator_.pose()});
      PosePending(out);
      return;
    }
    if (reading.t - last_odometry_->t > config_.max_odometry_gap_s) {
      // Nothing can be posed inside the silence: samples waiting in it are lost.
      ++counters_.odometry_gaps;
      while (!pending_.empty() && pending_.front().reading.t < reading.t) DropPending(true);
      odometry_.clear();
    }
  }
  ++counters_.odometry;
  last_odometry_ = reading;
  odometry_.push_back({reading.t, integrator_.Add(reading)});
  while (odometry_.size() > 2 && odometry_[1].t < reading.t - kOdometryHistoryS) {
    odometry_.pop_front();
  }
  PosePending(out);
}

void ScanAssembler::AddSample(const ScannerReading& reading, std::vector<Scan>& out) {
  Pending sample{reading, false};
  if (last_sample_) {
    if (!(reading.t > last_sample_->t)) {
      ++counters_.out_of_order;
      return;
    }
    counters_.samples_lost += Missing(last_sample_->seq, reading.seq);
    if (reading.t - last_sample_->t > config_.max_sample_gap_s) {
      ++counters_.sample_gaps;
      sample.break_before = true;
    }
  }
  ++counters_.samples;
  last_sample_ = reading;
  pending_.push_back(sample);
  PosePending(out);
  // Odometry stalled: give up on samples that waited too long.
  while (!pending_.empty() &&
         pending_.front().reading.t < reading.t - config_.max_odometry_wait_s) {
    DropPending(true);
  }
}

void ScanAssembler::DropPending(bool scan_in_progress_broken) {
  ++counters_.samples_unposed;
  if (pending_.front().break_before) break_next_ = true;
  if (scan_in_progress_broken) break_next_ = true;
  pending_.pop_front();
}

void ScanAssembler::PosePending(std::vector<Scan>& out) {
  while (!pending_.empty()) {
    const double t = pending_.front().reading.t;
    if (odometry_.empty() || t > odometry_.back().t) return;  // wait for odometry after it
    if (t < odometry_.front().t) {
      DropPending(true);  // before the odometry we have
      continue;
    }
    size_t i = 1;
    while (i < odometry_.size() && odometry_[i].t < t) ++i;
    Pose2 odom = odometry_.front().pose;
    if (i < odometry_.size()) {
      const TimedPose& a = odometry_[i - 1];
      const TimedPose& b = odometry_[i];
      odom = Interpolate(a.pose, b.pose, (t - a.t) / (b.t - a.t));
    }
    Group(pending_.front(), odom, out);
    pending_.pop_front();
  }
}

void ScanAssembler::DiscardScan() {
  if (current_ && !current_->samples.empty()) ++counters_.scans_discarded;
  current_.reset();
  previous_angle_.reset();
  progress_ = 0;
  half_turn_ = 0;
}

void ScanAssembler::Group(const Pending& sample, const Pose2& odom, std::vector<Scan>& out) {
  const ScannerReading& r = sample.reading;
  if (sample.break_before || break_next_) DiscardScan();
  break_next_ = false;
  if (current_ && static_cast<int64_t>(current_->samples.size()) >= config_.max_scan_samples) {
    ++counters_.scans_too_long;
    DiscardScan();
  }
  if (previous_angle_) {
    int64_t delta = (int64_t{r.angle_raw} - *previous_angle_) & (kFullTurnRaw - 1);
    if (delta >= kHalfTurnRaw) delta -= kFullTurnRaw;
    progress_ += delta;
  }
  previous_angle_ = r.angle_raw;
  const int64_t h = std::abs(progress_) / kHalfTurnRaw;
  if (current_ && h != half_turn_) {
    Scan next;
    next.t_begin = current_->t_end;
    next.odom_begin = current_->odom_end;
    current_->index = static_cast<int64_t>(counters_.scans);
    ++counters_.scans;
    counters_.samples_in_scans += current_->samples.size();
    last_end_ = TimedPose{current_->t_end, current_->odom_end};
    out.push_back(std::move(*current_));
    current_ = std::move(next);
  }
  if (!current_) {
    // The first scan starts at its first sample; a scan after an abandoned one where the last
    // delivered scan ended: the motion in between (the gap, the abandoned part) is the SLAM's.
    current_.emplace();
    current_->t_begin = last_end_ ? last_end_->t : r.t;
    current_->odom_begin = last_end_ ? last_end_->pose : odom;
  }
  half_turn_ = h;
  ScanSample s;
  s.t = r.t;
  s.odom = odom;
  s.platform_angle_rad = static_cast<double>(r.angle_raw) * 2.0 * kPi / kFullTurnRaw;
  s.raw = r.raw;
  current_->samples.push_back(s);
  current_->t_end = r.t;
  current_->odom_end = odom;
}

}  // namespace slam
