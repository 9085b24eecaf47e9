#include "engine/slam.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <numeric>
#include <optional>
#include <span>
#include <utility>

#include "engine/cell_encoding.hpp"
#include "engine/for_each.hpp"
#include "engine/match_window.hpp"
#include "engine/motion_model.hpp"
#include "engine/random.hpp"
#include "engine/update_ray.hpp"

namespace slam {

namespace {

// Random stream kinds, so that motion, candidates (2 and up, the scan matcher's) and resampling
// never share draws.
constexpr uint64_t kStreamMotion = 0;
constexpr uint64_t kStreamResampling = 1;

// Phase B's search spread, widened by drift left uncorrected, stays within these: beyond, the
// candidates a budget affords are too sparse to find the pose, and a wrong match costs more
// than none.
constexpr double kMaxSearchPosM = 0.25;
constexpr double kMaxSearchAngleDeg = 20.0;

// Picks `cap` of `n` items spread evenly (all of them when n <= cap).
std::vector<size_t> SpreadEvenly(size_t n, size_t cap) {
  std::vector<size_t> picked;
  if (n <= cap) {
    picked.resize(n);
    std::iota(picked.begin(), picked.end(), size_t{0});
    return picked;
  }
  picked.reserve(cap);
  for (size_t i = 0; i < cap; ++i) picked.push_back(i * n / cap);
  return picked;
}

/// `pose` with its position moved inside the map's bound where it is not (half a cell inside).
Pose2 ClampToMapBound(const Pose2& pose, const GridGeometry& geometry) {
  if (geometry.InMapBound(pose.translation())) return pose;
  const double limit = (kMapCellBound - 0.5) * geometry.resolution();
  return {std::clamp(pose.x, -limit, limit), std::clamp(pose.y, -limit, limit), pose.theta};
}

}  // namespace

ConfigErrors SlamConfig::Validate() const {
  ConfigErrors errors;
  auto check = [&](bool ok, const char* pointer, const char* detail) {
    if (!ok) errors.push_back({pointer, detail});
  };
  check(std::isfinite(resolution_m) && resolution_m >= 0.001 && resolution_m <= 0.5,
        "/resolution_m", "must be between 0.001 and 0.5 m");
  check(std::isfinite(logodds_limit) && logodds_limit > 0.1 &&
            logodds_limit * kLogOddsScale <= kLogOddsLimit,
        "/logodds_limit", "must be above 0.1 and at most 16");
  check(std::isfinite(occupied_above_logodds) && std::abs(occupied_above_logodds) < logodds_limit,
        "/occupied_above_logodds", "must lie inside the clamp limits");
  check(std::isfinite(update.free_logodds) && update.free_logodds <= 0, "/update/free_logodds",
        "must be <= 0");
  check(std::isfinite(update.occupied_logodds) && update.occupied_logodds > 0,
        "/update/occupied_logodds", "must be > 0");
  check(std::isfinite(update.occupied_sigma_factor) && update.occupied_sigma_factor >= 0,
        "/update/occupied_sigma_factor", "must be >= 0");
  check(std::isfinite(update.occupied_depth_cells) && update.occupied_depth_cells >= 0.5 &&
            update.occupied_depth_cells <= 10,
        "/update/occupied_depth_cells", "must be in [0.5, 10]");
  check(std::isfinite(match_floor) && match_floor > 0 && match_floor < 1, "/match_floor",
        "must be in (0, 1)");
  check(std::isfinite(match_range_sigmas) && match_range_sigmas >= 1 && match_range_sigmas <= 10,
        "/match_range_sigmas", "must be in [1, 10]");
  check(std::isfinite(range_sigma_min_cells) && range_sigma_min_cells >= 0 &&
            range_sigma_min_cells <= 10,
        "/range_sigma_min_cells", "must be in [0, 10]");
  check(std::isfinite(heading_sweep_turn_deg) && heading_sweep_turn_deg >= 0 &&
            heading_sweep_turn_deg <= 360,
        "/heading_sweep_turn_deg", "must be in [0, 360]");
  check(std::isfinite(heading_sweep_share) && heading_sweep_share > 0 && heading_sweep_share <= 1,
        "/heading_sweep_share", "must be in (0, 1]");
  check(std::isfinite(heading_sweep_step_deg) && heading_sweep_step_deg >= 0.1 &&
            heading_sweep_step_deg <= 30,
        "/heading_sweep_step_deg", "must be in [0.1, 30]");
  return errors;
}

namespace {

MatcherConfig MatcherConfigOf(const SlamConfig& config) {
  MatcherConfig matcher;
  matcher.occupied_above = EncodeLogOdds(config.occupied_above_logodds);
  matcher.match_floor = config.match_floor;
  matcher.fit_peak = config.fit_peak;
  matcher.sweep_step_rad = DegToRad(config.heading_sweep_step_deg);
  matcher.seed = config.seed;
  matcher.parallel = config.parallel;
  return matcher;
}

}  // namespace

Slam::Slam(const RobotDescription& robot, const SlamParams& params, const SlamConfig& config)
    : robot_(robot),
      params_(params),
      config_(config),
      geometry_(config.resolution_m),
      matcher_(MatcherConfigOf(config)),
      drift_(robot.base.heading_from_gyro, HasRangeScanner(robot)) {
  for (const ScannerSensor& sensor : robot_.scanner.sensors) {
    sensor_models_.emplace_back(robot_.sensor_types.at(sensor.type), config_.update,
                                config_.resolution_m);
  }
  const auto clock = std::make_shared<VersionClock>(0);
  const OccupancyGrid empty(geometry_, EncodeLogOdds(config_.logodds_limit), clock);
  particles_.assign(static_cast<size_t>(std::max(1, params_.particles)),
                    Particle{{}, 0.0, empty, nullptr});
}

bool Slam::AcceptsPose(const Pose2& pose) const {
  return std::isfinite(pose.theta) && geometry_.InMapBound(pose.translation());
}

bool Slam::Restore(const OccupancyGrid& map, const Pose2& pose) {
  if (!AcceptsPose(pose)) return false;
  drift_.Reset();
  for (Particle& p : particles_) {
    p.map = map;
    p.map.RefreshSummaries();
    p.pose = pose;
    p.log_weight = 0.0;
    p.history = nullptr;
    p.heading_drift = 0.0;
  }
  return true;
}

bool Slam::Relocate(const Pose2& pose) {
  if (!AcceptsPose(pose)) return false;
  const Particle best = Best();  // a copy: its map's tiles and history are shared, not copied
  for (Particle& p : particles_) {
    p = best;
    p.pose = pose;
    p.log_weight = 0.0;
  }
  return true;
}

void Slam::ReplaceMap(const OccupancyGrid& map) {
  for (Particle& p : particles_) {
    p.map = map;
    p.map.RefreshSummaries();
  }
}

std::vector<Measurement> Slam::CollectMeasurements(const Scan& scan) const {
  std::vector<Measurement> measurements;
  const double radius = robot_.scanner.mount_radius_m;
  const Vec2 offset(robot_.scanner.offset_x_m, robot_.scanner.offset_y_m);
  for (size_t i = 0; i < scan.samples.size(); ++i) {
    const ScanSample& sample = scan.samples[i];
    for (int k = 0; k < static_cast<int>(sensor_models_.size()); ++k) {
      const SensorModel& model = sensor_models_[static_cast<size_t>(k)];
      const uint16_t raw = sample.raw[static_cast<size_t>(k)];
      const std::optional<double> d = model.Distance(raw);
      if (!d) continue;
      Measurement m;
      m.sample = i;
      m.sensor = k;
      m.raw = raw;
      m.distance_m = *d;
      // Reading noise plus the grid's quantisation of where a surface lies (uniform in a cell).
      m.sigma_m = std::sqrt(model.Sigma(*d) * model.Sigma(*d) +
                            config_.resolution_m * config_.resolution_m / 12.0);
      if (model.description().kind == SensorKind::kRange) {
        m.sigma_m = std::max(m.sigma_m, config_.range_sigma_min_cells * config_.resolution_m);
      }
      m.local_angle = sample.platform_angle_rad +
                      DegToRad(robot_.scanner.sensors[static_cast<size_t>(k)].angle_deg);
      m.local_direction = Vec2(std::cos(m.local_angle), std::sin(m.local_angle));
      m.local_origin = offset + radius * m.local_direction;
      m.match_range_m = m.distance_m + config_.match_range_sigmas * m.sigma_m;
      measurements.push_back(m);
    }
  }
  return measurements;
}

PreparedScan Slam::Prepare(const Scan& scan) const {
  PreparedScan prepared;
  prepared.scan = &scan;
  prepared.usable = CollectMeasurements(scan);
  prepared.thinned = ThinByAngle(scan, prepared.usable, ThinningStep());
  const double narrowed = NarrowedThinningStep(scan);
  if (narrowed < ThinningStep()) prepared.narrowed = ThinByAngle(scan, prepared.usable, narrowed);
  prepared.summary.usable_measurements = static_cast<int>(prepared.usable.size());
  prepared.summary.matching_measurements = static_cast<int>(prepared.thinned.size());
  prepared.summary.matching_available = static_cast<int>(
      narrowed < ThinningStep() ? prepared.narrowed.size() : prepared.thinned.size());
  return prepared;
}

ScanSummary Slam::Summarize(const Scan& scan) const { return Prepare(scan).summary; }

std::vector<Vec2> Slam::ReadingPoints(const PreparedScan& prepared) const {
  const Scan& scan = *prepared.scan;
  std::vector<Vec2> points;
  for (const Measurement& m : prepared.usable) {
    const Pose2 sample = Between(scan.odom_end, scan.samples[m.sample].odom);
    points.push_back(sample.Transform(m.local_origin + m.local_direction * m.distance_m));
  }
  return points;
}

double Slam::ThinningStep() const { return DegToRad(params_.angle_between_scans_deg); }

double Slam::NarrowedThinningStep(const Scan& scan) const {
  const double set = DegToRad(params_.min_angle_uncertainty_deg);
  const double least = LeastSearchAngle();
  if (!(least < set)) return ThinningStep();
  // The ratio of the searches this scan runs with the narrowed least and with the set's: a
  // turn's or a blind stretch's drift widens both alike.
  const double drift =
      drift_.DriftAngle(OdometryNoise(params_, Decompose(Between(scan.odom_begin, scan.odom_end))));
  const double most = DegToRad(kMaxSearchAngleDeg);
  return ThinningStep() * std::min(std::max(drift, least), most) /
         std::min(std::max(drift, set), most);
}

std::vector<size_t> Slam::ThinByAngle(const Scan& scan, const std::vector<Measurement>& usable,
                                      double min_step) const {
  std::vector<size_t> kept;
  std::optional<double> last_angle;
  size_t last_sample = SIZE_MAX;
  bool keep = false;
  for (size_t i = 0; i < usable.size(); ++i) {
    const Measurement& m = usable[i];
    if (m.sample != last_sample) {  // decide once per sample: all its sensors share the angle
      last_sample = m.sample;
      const double angle = scan.samples[m.sample].platform_angle_rad;
      keep = !last_angle || std::abs(NormalizeAngle(angle - *last_angle)) >= min_step - 1e-12;
      if (keep) last_angle = angle;
    }
    if (keep) kept.push_back(i);
  }
  return kept;
}

double Slam::ScoreScan(const Scan& scan, const Pose2& end) const {
  const Particle& best = Best();
  const ScanPath path(scan, best.pose, kStartShare);
  const std::vector<Measurement> usable = CollectMeasurements(scan);
  std::vector<const Measurement*> matching;
  for (size_t i : ThinByAngle(scan, usable, ThinningStep())) matching.push_back(&usable[i]);
  return matcher_.LogLikelihood(best.map, nullptr, path, path.CorrectionTo(end), matching);
}

void Slam::Resample(size_t wanted, uint64_t step, uint64_t stream) {
  Rng rng = Rng::ForStream(config_.seed, step, stream, kStreamResampling);
  slam::Resample(particles_, wanted, rng);
  scans_since_resampling_ = 0;
}

struct Slam::Prediction {
  std::vector<ScanPath> paths;   // per particle
  std::vector<Pose2> nominal;    // per particle: odometry's end pose without its heading drift
  std::vector<Pose2> predicted;  // per particle: its end pose drawn from the motion model
  double trans = 0.0;            // odometry's translation over the scan (m)
  double drift_span = 0.0;       // DriftTracker::DriftSpan
  MotionNoise noise;             // of the motion model
  // Phase B's search: the motion model's spread over this scan plus the drift left uncorrected
  // since the last informative match, within the parameters' bounds; the motion prior's
  // deviation, the same but no less than a third of the least search spread (the candidates
  // explore about three prior deviations around it); the heading sweep (SlamConfig::heading_
  // sweep_*). Its candidate count is the plan's.
  MatchSearch search;
};

const char* ToString(ScanRefusal refusal) {
  switch (refusal) {
    case ScanRefusal::kNotFinite:
      return "not_finite";
    case ScanRefusal::kImplausibleMotion:
      return "implausible_motion";
    case ScanRefusal::kOutsideMap:
      return "outside_map";
    default:
      return "none";
  }
}

ScanRefusal Slam::CheckScan(const Scan& scan) const {
  const auto finite = [](const Pose2& p) {
    return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.theta);
  };
  if (!std::isfinite(scan.t_begin) || !std::isfinite(scan.t_end) || !finite(scan.odom_begin) ||
      !finite(scan.odom_end)) {
    return ScanRefusal::kNotFinite;
  }
  // Not OdometryIntegrator::MaxTravelM, which counts at most kMaxJumpWindowS between two
  // readings: a scan spans a silence of the scanner, however long, and the odometry the
  // assembler accepted over it is real motion.
  const double travel =
      robot_.base.max_speed_m_s * (std::max(0.0, scan.t_end - scan.t_begin) + kScanTravelSlackS);
  // Written so that an overflow to infinity (poses 1e300 apart) is refused too.
  const auto near = [&](const Pose2& p) {
    return std::hypot(p.x - scan.odom_begin.x, p.y - scan.odom_begin.y) <= travel;
  };
  if (!near(scan.odom_end)) return ScanRefusal::kImplausibleMotion;
  for (const ScanSample& sample : scan.samples) {
    if (!std::isfinite(sample.t) || !finite(sample.odom)) return ScanRefusal::kNotFinite;
    if (!near(sample.odom)) return ScanRefusal::kImplausibleMotion;
  }
  const Pose2 motion = Between(scan.odom_begin, scan.odom_end);
  for (const Particle& p : particles_) {
    if (!AcceptsPose(Compose(p.pose, motion))) return ScanRefusal::kOutsideMap;
  }
  return ScanRefusal::kNone;
}

ScanReport Slam::ProcessScan(const Scan& scan, const ScanPlan& plan) {
  return ProcessScan(Prepare(scan), plan);
}

ScanReport Slam::ProcessScan(const PreparedScan& prepared, const ScanPlan& plan) {
  const Scan& scan = *prepared.scan;
  const uint64_t step = static_cast<uint64_t>(scans_processed_);
  ScanReport report;
  report.scan = scan.index;
  report.refused = CheckScan(scan);
  if (report.refused != ScanRefusal::kNone) {
    ++scans_refused_;
    report.particles = static_cast<int>(particles_.size());
    report.pose = Best().pose;
    return report;
  }
  report.resampled = StartScan(scan, plan, step);

  const std::vector<Measurement>& usable = prepared.usable;
  report.usable_measurements = static_cast<int>(usable.size());
  const std::vector<const Measurement*> matching = SelectMatching(prepared, plan);

  const Prediction prediction = PredictMotion(scan, plan.refine, step);
  const WindowPlan windows = PlanWindows(prediction, matching, plan);
  if (!windows.empty()) {
    // The particles that cast through their tiles need the tiles' clearance, which the last
    // update left stale where a window served instead.
    ForEach(config_.parallel, particles_.size(), [&](size_t p) {
      if (!windows[p]) particles_[p].map.RefreshSummaries();
    });
  }
  const bool matched = MatchesScan(plan, matching.size());
  MatchResult match;
  if (matched) {
    match = MatchScan(prediction, matching, plan, windows, step);
    report.candidates = std::max(1, plan.candidates);
    report.refinement_ambiguity = match.ambiguity;
    report.rays.matching = match.rays;
    report.interrupted = match.interrupted;
    report.matching_measurements = static_cast<int>(matching.size());
  } else {
    match.chosen = prediction.predicted;
    match.chosen_ll.assign(particles_.size(), 0.0);
    report.candidates = 1;
  }

  // What the map did not correct accumulates until a scan matched on enough readings pins the
  // pose down again: the heading's drift moves the position too.
  if (matched && matching.size() >= DriftTracker::kInformativeMatches) {
    drift_.LearnFromMatch(scan, prediction.drift_span, match.chosen, prediction.nominal,
                          DegToRad(params_.min_angle_uncertainty_deg), particles_);
  } else if (plan.refine) {
    drift_.AddUncorrected(prediction.noise, prediction.trans);
  }

  const size_t updates = UpdateParticles(scan, usable, prediction, match, plan, windows);
  report.update_rays = static_cast<int>(updates);
  report.rays.update = static_cast<int64_t>(updates * particles_.size());

  FinishScan(match, step, report);
  return report;
}

bool Slam::StartScan(const Scan& scan, const ScanPlan& plan, uint64_t step) {
  for (Particle& p : particles_) {
    if (!p.history)
      p.history =
          std::make_shared<TrajectoryChunk>(TrajectoryChunk{{{scan.t_begin, p.pose}}, nullptr});
  }
  // A new particle count applies from this scan: drawn from the current weights.
  const auto wanted = static_cast<size_t>(std::max(1, plan.particles));
  if (wanted == particles_.size()) return false;
  Resample(wanted, step, 1);
  return true;
}

std::vector<const Measurement*> Slam::SelectMatching(const PreparedScan& prepared,
                                                     const ScanPlan& plan) const {
  const bool narrowed = plan.search == SearchMode::kNarrowed && !prepared.narrowed.empty();
  const std::vector<size_t>& thinned = narrowed ? prepared.narrowed : prepared.thinned;
  std::vector<const Measurement*> matching;
  for (size_t i :
       SpreadEvenly(thinned.size(), static_cast<size_t>(std::max(0, plan.matching_measurements)))) {
    matching.push_back(&prepared.usable[thinned[i]]);
  }
  return matching;
}

Slam::Prediction Slam::PredictMotion(const Scan& scan, bool refine, uint64_t step) const {
  const size_t n_particles = particles_.size();
  const MotionDelta motion = Decompose(Between(scan.odom_begin, scan.odom_end));
  Prediction out;
  out.noise = OdometryNoise(params_, motion);
  out.trans = std::abs(motion.trans);
  out.drift_span = drift_.DriftSpan(scan, motion);
  const double drift_pos = drift_.DriftPos(out.noise);
  const double drift_angle = drift_.DriftAngle(out.noise);
  const double min_angle = LeastSearchAngle();
  out.search.search = {std::clamp(drift_pos, params_.min_pos_uncertainty_m, kMaxSearchPosM),
                       std::clamp(drift_angle, min_angle, DegToRad(kMaxSearchAngleDeg))};
  out.search.prior = {std::max(drift_pos, params_.min_pos_uncertainty_m / 3.0),
                      std::max(drift_angle, min_angle / 3.0)};
  const double turn = std::abs(NormalizeAngle(motion.rot1 + motion.rot2));
  if (config_.heading_sweep_turn_deg > 0 && HasRangeScanner(robot_) &&
      turn > DegToRad(config_.heading_sweep_turn_deg)) {
    out.search.sweep = config_.heading_sweep_share * turn;
  }
  out.predicted.resize(n_particles);
  out.nominal.resize(n_particles);
  out.paths.reserve(n_particles);
  for (size_t p = 0; p < n_particles; ++p) {
    out.paths.emplace_back(scan, particles_[p].pose, kStartShare);
    out.nominal[p] = out.paths[p].nominal_end();
    if (!refine) {
      out.predicted[p] = out.nominal[p];
      continue;
    }
    // The drift over the scan is taken out of the end's heading; the samples in between
    // follow through the correction (its share from the start included: a fraction of a
    // degree over a scan, where a constant rate would grow linearly).
    const double drift = particles_[p].heading_drift * out.drift_span;
    out.nominal[p].theta = NormalizeAngle(out.nominal[p].theta - drift);
    Rng rng = Rng::ForStream(config_.seed, step, p, kStreamMotion);
    out.predicted[p] = SampleMotion(particles_[p].pose, motion, out.noise, rng);
    out.predicted[p].theta = NormalizeAngle(out.predicted[p].theta - drift);
  }
  return out;
}

double Slam::LeastSearchAngle() const {
  return drift_.LeastSearchAngle(DegToRad(params_.min_angle_uncertainty_deg));
}

bool Slam::MatchesScan(const ScanPlan& plan, size_t matching) const {
  return plan.refine && matching > 0 && (plan.candidates > 1 || particles_.size() > 1);
}

Slam::WindowPlan Slam::PlanWindows(const Prediction& prediction,
                                   const std::vector<const Measurement*>& matching,
                                   const ScanPlan& plan) const {
  if (!MatchesScan(plan, matching.size())) return {};
  MatchSearch search = prediction.search;
  search.candidates = static_cast<size_t>(std::max(1, plan.candidates));
  WindowPlan windows(particles_.size());
  for (size_t p = 0; p < particles_.size(); ++p) {
    windows[p] =
        PlanWindow(geometry_, prediction.paths[p], prediction.predicted[p], matching, search);
  }
  return windows;
}

MatchResult Slam::MatchScan(const Prediction& prediction,
                            const std::vector<const Measurement*>& matching, const ScanPlan& plan,
                            const WindowPlan& window_plan, uint64_t step) const {
  const size_t n_particles = particles_.size();
  const LogOdds occupied_above = EncodeLogOdds(config_.occupied_above_logodds);
  std::vector<std::optional<MatchWindow>> windows(n_particles);
  ForEach(config_.parallel, n_particles, [&](size_t p) {
    if (window_plan[p])
      windows[p].emplace(particles_[p].map, occupied_above, window_plan[p]->lo, window_plan[p]->hi);
  });
  std::vector<MatchRequest> requests(n_particles);
  for (size_t p = 0; p < n_particles; ++p) {
    requests[p] = {&particles_[p].map, windows[p] ? &*windows[p] : nullptr, &prediction.paths[p],
                   prediction.predicted[p], prediction.nominal[p]};
  }
  MatchSearch search = prediction.search;
  search.candidates = static_cast<size_t>(std::max(1, plan.candidates));
  return matcher_.Match(requests, matching, search, step, interrupt_);
}

size_t Slam::UpdateParticles(const Scan& scan, const std::vector<Measurement>& usable,
                             const Prediction& prediction, const MatchResult& match,
                             const ScanPlan& plan, const WindowPlan& windows) {
  const std::vector<size_t> updates =
      SpreadEvenly(usable.size(), static_cast<size_t>(std::max(0, plan.update_rays)));
  for (Particle& p : particles_) p.map.BeginWrite();  // in order: versions do not depend on threads
  ForEach(config_.parallel, particles_.size(), [&](size_t p) {
    Particle& particle = particles_[p];
    const ScanPath& path = prediction.paths[p];
    const Pose2 correction = path.CorrectionTo(match.chosen[p]);
    for (size_t u : updates) {
      const Measurement& m = usable[u];
      const Pose2 robot = path.SamplePose(m.sample, correction);
      const std::optional<UpdateProfile> profile =
          sensor_models_[static_cast<size_t>(m.sensor)].Update(m.raw);
      ApplyUpdateRay(particle.map, robot.Transform(m.local_origin), robot.theta + m.local_angle,
                     *profile);
    }
    // Lets the next scan's matching rays skip empty space (while the tiles just written are
    // this particle's alone). Without refinement nothing is matched: tiles stay stale, and
    // the first refresh after refinement resumes catches them all up. A particle matched
    // through a window (likely again next scan) leaves the tiles' clearance stale: ProcessScan
    // refreshes it when a scan casts through them.
    if (plan.refine) particle.map.RefreshSummaries(/*clearance=*/windows.empty() || !windows[p]);
    auto chunk = std::make_shared<TrajectoryChunk>();
    chunk->poses.reserve(config_.history_samples ? scan.samples.size() + 1 : 1);
    for (size_t i = 0; config_.history_samples && i < scan.samples.size(); ++i) {
      // A sample at the scan's start is the previous end pose, already in the history; samples
      // that share a time (a laser's sweep, read at one pose) give one pose.
      const double t = scan.samples[i].t;
      if (t > scan.t_begin && (chunk->poses.empty() || t > chunk->poses.back().t))
        chunk->poses.push_back({t, path.SamplePose(i, correction)});
    }
    // The odometry kept the particle inside the map's bound (CheckScan); its search's spread may
    // not have: the pose stays inside, where the engine takes poses (AcceptsPose).
    const Pose2 end = ClampToMapBound(match.chosen[p], geometry_);
    if (chunk->poses.empty() || chunk->poses.back().t < scan.t_end)
      chunk->poses.push_back({scan.t_end, end});
    chunk->parent = std::move(particle.history);
    particle.history = std::move(chunk);
    particle.pose = end;
    particle.log_weight += match.chosen_ll[p];
  });
  return updates.size();
}

void Slam::FinishScan(const MatchResult& match, uint64_t step, ScanReport& report) {
  const size_t n_particles = particles_.size();
  report.effective_sample_size = EffectiveSampleSize(particles_);
  report.best_log_likelihood = match.chosen_ll[BestIndex(particles_)];

  ++scans_since_resampling_;
  if (n_particles > 1 && scans_since_resampling_ >= params_.resampling_period_scans) {
    Resample(n_particles, step, 0);
    report.resampled = true;
  }
  report.particles = static_cast<int>(particles_.size());
  report.pose = Best().pose;
  ++scans_processed_;
}

}  // namespace slam
