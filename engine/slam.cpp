#include "engine/slam.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
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
#include "engine/fast_math.hpp"
#include "engine/match_window.hpp"
#include "engine/matching_rays.hpp"
#include "engine/random.hpp"
#include "engine/update_ray.hpp"

namespace slam {

namespace {

// Random stream kinds, so that motion, candidates and resampling never share draws.
constexpr uint64_t kStreamMotion = 0;
constexpr uint64_t kStreamResampling = 1;
constexpr uint64_t kStreamCandidate = 2;  // + candidate index

// Phase B's search spread, widened by drift left uncorrected, stays within these: beyond, the
// candidates a budget affords are too sparse to find the pose, and a wrong match costs more
// than none.
constexpr double kMaxSearchPosM = 0.25;
constexpr double kMaxSearchAngleDeg = 20.0;
// A scan matched on at least this many readings corrects the drift (a few readings along one
// wall do not).
constexpr size_t kInformativeMatches = 12;

// The heading drift estimate follows the heading corrections of informative matches averaged
// over this time (s): long enough to average out their jitter (0.4 to 0.7 degree a scan on a
// perfect map, docs/accuracy.md), short enough to follow a MEMS gyro's bias as it wanders (over
// minutes).
constexpr double kHeadingDriftTimeS = 30.0;
// The estimate's bound: more than any gyro's bias after its start-up calibration.
constexpr double kMaxHeadingDriftDegS = 2.0;
// A heading from the encoders errs with the distance driven, not with time: wheels of unequal
// diameters turn the odometry by a constant angle per metre (Borenstein and Feng's systematic
// odometry errors; the Intel lab's Pioneer, 3.3 degrees a metre, docs/laser.md), and a robot
// standing still does not drift. The estimate averages over this distance (about the 30 s above
// at the 0.2 to 0.3 m/s robots drive), and its bound allows a 5 % mismatch of the wheels on a
// 30 cm axle.
constexpr double kHeadingDriftDistanceM = 10.0;
constexpr double kMaxHeadingDriftDegM = 10.0;
// A range scanner's heading search follows the heading corrections its informative matches have
// been making (their root mean square over about kCorrectionAveragingScans scans): it spans
// kCorrectionSigmas of them, within the parameter set's minimum angle uncertainty (a robot whose
// odometry errs like a tracked one keeps the set's search) and never below kLeastSearchShare of
// it. A good odometry (a Pioneer's errs by about a degree a scan) narrows it, so that a match on
// a few dozen rays cannot walk the heading away one plausible step after another
// (docs/laser.md, "A heading search that follows the corrections").
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
// The largest MatchWindow a particle gets (4 bytes a cell: 16 MiB), whatever its rays: more
// means rays far longer than the scanner's, or very fine cells, cast through the map instead.
// Below it a window holds at most 4 x 16 bytes per ray its particle casts.
constexpr int64_t kMaxMatchWindowCells = int64_t{1} << 22;

/// Particle weights normalised to sum to 1 (from log weights, without overflow).
std::vector<double> NormalizedWeights(const std::vector<Particle>& particles) {
  double max_lw = -std::numeric_limits<double>::infinity();
  for (const Particle& p : particles) max_lw = std::max(max_lw, p.log_weight);
  std::vector<double> weight(particles.size());
  double total = 0.0;
  for (size_t p = 0; p < particles.size(); ++p)
    total += weight[p] = std::exp(particles[p].log_weight - max_lw);
  for (double& w : weight) w /= total;
  return weight;
}

// Runs body(i) for i in [0, n), across threads or in order; each i must be independent.
template <typename Body>
void ForEach(bool parallel, size_t n, const Body& body) {
  if (parallel && n > 1) {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& r) {
      for (size_t i = r.begin(); i != r.end(); ++i) body(i);
    });
  } else {
    for (size_t i = 0; i < n; ++i) body(i);
  }
}

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

// The motion between two odometry poses as rotation, translation, rotation (phase A). Backward
// motion is a negative translation, so that reversing does not look like a half-turn.
struct MotionDelta {
  double rot1 = 0.0;
  double trans = 0.0;
  double rot2 = 0.0;
};

MotionDelta Decompose(const Pose2& delta) {
  MotionDelta m;
  m.trans = std::hypot(delta.x, delta.y);
  if (m.trans > 1e-9) {
    m.rot1 = std::atan2(delta.y, delta.x);
    if (std::abs(m.rot1) > kPi / 2) {
      m.rot1 = NormalizeAngle(m.rot1 - kPi);
      m.trans = -m.trans;
    }
  }
  m.rot2 = NormalizeAngle(delta.theta - m.rot1);
  return m;
}

Pose2 Recompose(const MotionDelta& m) {
  return {m.trans * std::cos(m.rot1), m.trans * std::sin(m.rot1), NormalizeAngle(m.rot1 + m.rot2)};
}

// Phase B's fit of the log-likelihood's peak (FittedPeak): it needs kPeakFitMinCandidates
// (slam.hpp), and its peak may lie at most this many search spreads from the best candidate
// (farther, the quadratic is extrapolated: the best candidate stays).
constexpr double kPeakFitMaxStep = 2.0;
// Candidates whose log-likelihood lies more than this many units per matched reading below the
// best one's are left out of the fit: they sit on the likelihood's floor, and where the peak is
// sharp (a map that fits the readings well) a quadratic through them misplaces it (by up to a
// degree on a drawn map; chosen among 1, 1.5, 2 and none on the validation worlds).
constexpr double kPeakFitWindowPerReading = 1.5;

// A search or prior spread: position (m) and heading (rad) standard deviations.
struct Spread {
  double pos, angle;
};

// The pose maximising a quadratic fitted to the candidates' log-likelihoods plus the motion
// prior (a Gaussian of spread `prior` around `nominal`). The quadratic is fitted by least
// squares in units of the search spread, weighted by a Gaussian of that spread around `best`.
// Its curvature is clamped to at most zero, and its slope along each principal direction
// shrunk by that direction's share of the information: a direction in which the likelihood
// does not fall off (along a corridor's walls) tells nothing, and there the prior decides. One
// candidate's luck (the likelihood on a grid is rough at the scale of a cell, and a few readings
// fit many poses) moves the fit little, where it decides the best candidate (docs/accuracy.md, "The
// likelihood's peak"). Empty when the fit is ill-posed or its peak lies farther than
// kPeakFitMaxStep spreads from `best`.
std::optional<Pose2> FittedPeak(std::span<const Pose2> poses, std::span<const double> ll,
                                size_t readings, const Pose2& best, const Pose2& nominal,
                                Spread search, Spread prior) {
  const double top = *std::max_element(ll.begin(), ll.end());
  const double lowest = top - kPeakFitWindowPerReading * static_cast<double>(readings);
  using Vector10 = Eigen::Matrix<double, 10, 1>;
  Eigen::Matrix<double, 10, 10> normal = Eigen::Matrix<double, 10, 10>::Zero();
  Vector10 rhs = Vector10::Zero();
  size_t used = 0;
  for (size_t i = 0; i < poses.size(); ++i) {
    if (!std::isfinite(ll[i]) || ll[i] < lowest) continue;  // interrupted, or on the floor
    const double u = (poses[i].x - best.x) / search.pos, v = (poses[i].y - best.y) / search.pos,
                 t = NormalizeAngle(poses[i].theta - best.theta) / search.angle;
    const double w = std::exp(-0.5 * (u * u + v * v + t * t));
    Vector10 f;
    f << 1, u, v, t, u * u, v * v, t * t, u * v, u * t, v * t;
    normal.selfadjointView<Eigen::Lower>().rankUpdate(f, w);
    rhs += w * ll[i] * f;
    ++used;
  }
  if (used < kPeakFitMinCandidates) return std::nullopt;
  const Vector10 a = normal.selfadjointView<Eigen::Lower>().ldlt().solve(rhs);
  if (!a.allFinite()) return std::nullopt;
  Eigen::Matrix3d curvature;
  curvature << 2 * a[4], a[7], a[8], a[7], 2 * a[5], a[9], a[8], a[9], 2 * a[6];
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(curvature);
  const Eigen::Matrix3d falling = eigen.eigenvectors() *
                                  eigen.eigenvalues().cwiseMin(0.0).asDiagonal() *
                                  eigen.eigenvectors().transpose();
  // Maximise a + g.x + x'Hx/2 - (x - n)'P(x - n)/2: (P - H) x = g + P n.
  const Eigen::Vector3d precision(Square(search.pos / prior.pos), Square(search.pos / prior.pos),
                                  Square(search.angle / prior.angle));
  const Eigen::Vector3d centre((nominal.x - best.x) / search.pos, (nominal.y - best.y) / search.pos,
                               NormalizeAngle(nominal.theta - best.theta) / search.angle);
  const Eigen::Matrix3d lhs = Eigen::Matrix3d(precision.asDiagonal()) - falling;
  // The fitted slope along each principal direction counts in proportion to that direction's
  // share of the information (its curvature against the prior's precision there): along a
  // direction the readings hardly tell apart, the slope is the fit's noise.
  Eigen::Vector3d along = eigen.eigenvectors().transpose() * a.segment<3>(1);
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d v = eigen.eigenvectors().col(k);
    const double information = std::max(0.0, -eigen.eigenvalues()[k]);
    along[k] *= information / (information + v.cwiseProduct(v).dot(precision));
  }
  const Eigen::Vector3d gradient = eigen.eigenvectors() * along;
  const Eigen::Vector3d step = lhs.ldlt().solve(gradient + precision.cwiseProduct(centre));
  if (!step.allFinite() || step.norm() > kPeakFitMaxStep) return std::nullopt;
  return Pose2{best.x + step[0] * search.pos, best.y + step[1] * search.pos,
               NormalizeAngle(best.theta + step[2] * search.angle)};
}

/// `pose` with its position moved inside the map's bound where it is not (half a cell inside).
Pose2 ClampToMapBound(const Pose2& pose, const GridGeometry& geometry) {
  if (geometry.InMapBound(pose.translation())) return pose;
  const double limit = (kMapCellBound - 0.5) * geometry.resolution();
  return {std::clamp(pose.x, -limit, limit), std::clamp(pose.y, -limit, limit), pose.theta};
}

}  // namespace

// The robot's path through one scan for one particle: the odometry path anchored at the particle's
// start pose, plus a correction that moves the end onto a chosen pose. The correction is shared
// between the start and the drift over the scan: kStartShare of it applies from the first
// sample on, the rest grows linearly in time. The start is the previous scan's match, off by
// about as much as the odometry drifts over a scan (a match on a perfect map, from the true start:
// 1.2 cm and 0.5 to 0.7 degree at the end; the odometry: 0.3 to 0.9 cm and 0.2 to 0.6 degree). A
// correction that grows from zero (the paper's) holds the start where the previous match put it,
// and leaves the end to absorb both errors.
class Slam::ScanPath {
 public:
  ScanPath(const Scan& scan, const Pose2& start) {
    const double span = scan.t_end - scan.t_begin;
    nominal_.reserve(scan.samples.size());
    cos_.reserve(scan.samples.size());
    sin_.reserve(scan.samples.size());
    fraction_.reserve(scan.samples.size());
    for (const ScanSample& s : scan.samples) {
      nominal_.push_back(Compose(start, Between(scan.odom_begin, s.odom)));
      cos_.push_back(std::cos(nominal_.back().theta));
      sin_.push_back(std::sin(nominal_.back().theta));
      const double f = span > 0 ? std::clamp((s.t - scan.t_begin) / span, 0.0, 1.0) : 1.0;
      fraction_.push_back(kStartShare + (1.0 - kStartShare) * f);
    }
    nominal_end_ = Compose(start, Between(scan.odom_begin, scan.odom_end));
  }

  const Pose2& nominal_end() const { return nominal_end_; }

  /// Correction that moves the nominal end onto `end`.
  Pose2 CorrectionTo(const Pose2& end) const {
    return {end.x - nominal_end_.x, end.y - nominal_end_.y,
            NormalizeAngle(end.theta - nominal_end_.theta)};
  }

  /// Pose at sample i under a correction.
  Pose2 SamplePose(size_t i, const Pose2& correction) const {
    const double s = fraction_[i];
    const Pose2& n = nominal_[i];
    return {n.x + s * correction.x, n.y + s * correction.y,
            NormalizeAngle(n.theta + s * correction.theta)};
  }

  /// The same pose as a position and the cosine and sine of its heading (what rays need).
  struct Frame {
    double x, y, cos, sin;
    /// Maps a point of the robot's frame to the map.
    Vec2 Point(const Vec2& p) const {
      return {x + cos * p.x() - sin * p.y(), y + sin * p.x() + cos * p.y()};
    }
    /// Rotates a direction of the robot's frame into the map.
    Vec2 Direction(const Vec2& d) const {
      return {cos * d.x() - sin * d.y(), sin * d.x() + cos * d.y()};
    }
  };
  /// The bounding box of the sample positions under a correction (min x, min y, max x, max y).
  std::array<double, 4> Extent(const Pose2& correction) const {
    std::array<double, 4> box{
        std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
        -std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
    for (size_t i = 0; i < nominal_.size(); ++i) {
      const double x = nominal_[i].x + fraction_[i] * correction.x,
                   y = nominal_[i].y + fraction_[i] * correction.y;
      box = {std::min(box[0], x), std::min(box[1], y), std::max(box[2], x), std::max(box[3], y)};
    }
    return box;
  }

  Frame SampleFrame(size_t i, const Pose2& correction) const {
    const double s = fraction_[i];
    const Pose2& n = nominal_[i];
    const double turn = s * correction.theta;
    if (std::abs(turn) > kSmallTurnRad) {
      const double theta = n.theta + turn;
      return {n.x + s * correction.x, n.y + s * correction.y, std::cos(theta), std::sin(theta)};
    }
    // The nominal heading's cosine and sine, turned by the correction's share: a candidate's
    // frames without a libm call each (they cost as much as casting the ray).
    const auto [c, sn] = SmallTurn(turn);
    return {n.x + s * correction.x, n.y + s * correction.y, cos_[i] * c - sin_[i] * sn,
            sin_[i] * c + cos_[i] * sn};
  }

 private:
  std::vector<Pose2> nominal_;
  std::vector<double> cos_, sin_;  // of the nominal headings
  std::vector<double> fraction_;
  Pose2 nominal_end_;
};

// A usable reading of one sensor at one sample, with its geometry in the robot's frame.
struct Slam::Measurement {
  size_t sample = 0;
  int sensor = 0;
  uint16_t raw = 0;
  double distance_m = 0.0;
  double sigma_m = 0.0;
  double local_angle = 0.0;  // sensor direction relative to the robot's heading
  Vec2 local_origin = Vec2::Zero();
  Vec2 local_direction = Vec2::UnitX();  // (cos, sin) of local_angle
  double match_range_m = 0.0;            // how far its matching ray looks
};

TrajectoryChunk::~TrajectoryChunk() {
  std::shared_ptr<const TrajectoryChunk> next = std::move(parent);
  while (next && next.use_count() == 1) {
    std::shared_ptr<const TrajectoryChunk> grand = std::move(next->parent);
    next = std::move(grand);
  }
}

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

Slam::Slam(const RobotDescription& robot, const SlamParams& params, const SlamConfig& config)
    : robot_(robot), params_(params), config_(config), geometry_(config.resolution_m) {
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
  unmatched_var_pos_ = 0.0;
  unmatched_var_angle_ = 0.0;
  correction_var_angle_.reset();
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

const Particle& Slam::Best() const {
  size_t best = 0;
  for (size_t i = 1; i < particles_.size(); ++i) {
    if (particles_[i].log_weight > particles_[best].log_weight) best = i;
  }
  return particles_[best];
}

std::vector<TimedPose> Slam::Trajectory() const { return History(Best()); }

std::vector<TimedPose> Slam::History(const Particle& particle) {
  std::vector<const TrajectoryChunk*> chunks;
  for (const TrajectoryChunk* c = particle.history.get(); c != nullptr; c = c->parent.get()) {
    chunks.push_back(c);
  }
  std::vector<TimedPose> poses;
  for (auto it = chunks.rbegin(); it != chunks.rend(); ++it) {
    poses.insert(poses.end(), (*it)->poses.begin(), (*it)->poses.end());
  }
  return poses;
}

std::vector<Slam::Measurement> Slam::CollectMeasurements(const Scan& scan) const {
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

std::vector<Vec2> Slam::ReadingPoints(const Scan& scan) const {
  std::vector<Vec2> points;
  for (const Measurement& m : CollectMeasurements(scan)) {
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
  const double drift = DriftAngle(scan);
  const double most = DegToRad(kMaxSearchAngleDeg);
  return ThinningStep() * std::min(std::max(drift, least), most) /
         std::min(std::max(drift, set), most);
}

double Slam::DriftAngle(const Scan& scan) const {
  const MotionDelta motion = Decompose(Between(scan.odom_begin, scan.odom_end));
  const double angle_const = DegToRad(params_.angle_error_const_deg);
  const double rot1 = params_.angle_error_ratio * std::abs(motion.rot1) + angle_const;
  const double rot2 = params_.angle_error_ratio * std::abs(motion.rot2) + angle_const;
  return std::sqrt(Square(rot1) + Square(rot2) + unmatched_var_angle_);
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

double Slam::LogLikelihood(const OccupancyGrid& map, const MatchWindow* window,
                           const ScanPath& path, const Pose2& correction,
                           const std::vector<const Measurement*>& matching) const {
  const LogOdds occupied_above = EncodeLogOdds(config_.occupied_above_logodds);
  // The candidate's rays, cast as one batch (several in flight); buffers reused per thread.
  thread_local std::vector<RayQuery> rays;
  thread_local std::vector<RayHit> hits;
  rays.clear();
  size_t sample = SIZE_MAX;
  ScanPath::Frame frame{};
  for (const Measurement* m : matching) {
    if (m->sample != sample) {  // the sensors of one sample share its pose
      sample = m->sample;
      frame = path.SampleFrame(sample, correction);
    }
    rays.push_back(
        {frame.Point(m->local_origin), frame.Direction(m->local_direction), m->match_range_m});
  }
  if (window != nullptr) {
    CastToObstacles(*window, rays, hits);
  } else {
    CastToObstacles(map, rays, occupied_above, hits);
  }
  // Eq. (2), robust to outliers: the sum of log(g + floor), as the log of products of its terms
  // (each in [floor, 1 + floor)), taken whenever a product nears the ends of the double range:
  // one log for many rays instead of one each.
  double ll = 0.0, product = 1.0;
  for (size_t i = 0; i < matching.size(); ++i) {
    const Measurement& m = *matching[i];
    const RayHit& hit = hits[i];
    double g = 0.0;
    if (hit.hit) {
      // The surface lies somewhere along the ray's crossing of the first occupied cell, which is
      // longer than a cell for oblique walls: expect it in the middle of the crossing.
      const double r = (m.distance_m - 0.5 * (hit.distance_m + hit.exit_m)) / m.sigma_m;
      g = std::exp(-0.5 * r * r);
    }
    product *= g + config_.match_floor;
    if (!(product > 1e-150 && product < 1e150)) {
      ll += std::log(product);
      product = 1.0;
    }
  }
  return ll + std::log(product);
}

double Slam::ScoreScan(const Scan& scan, const Pose2& end) const {
  const Particle& best = Best();
  const ScanPath path(scan, best.pose);
  const std::vector<Measurement> usable = CollectMeasurements(scan);
  std::vector<const Measurement*> matching;
  for (size_t i : ThinByAngle(scan, usable, ThinningStep())) matching.push_back(&usable[i]);
  return LogLikelihood(best.map, nullptr, path, path.CorrectionTo(end), matching);
}

ScanSummary Slam::Summarize(const Scan& scan) const {
  const std::vector<Measurement> usable = CollectMeasurements(scan);
  const auto thinned = static_cast<int>(ThinByAngle(scan, usable, ThinningStep()).size());
  const double narrowed = NarrowedThinningStep(scan);
  return {static_cast<int>(usable.size()), thinned,
          narrowed < ThinningStep() ? static_cast<int>(ThinByAngle(scan, usable, narrowed).size())
                                    : thinned};
}

void Slam::Resample(size_t wanted, uint64_t step, uint64_t stream) {
  Rng rng = Rng::ForStream(config_.seed, step, stream, kStreamResampling);
  const size_t n = particles_.size();
  const std::vector<double> weight = NormalizedWeights(particles_);
  std::vector<size_t> order(n);
  std::iota(order.begin(), order.end(), size_t{0});
  std::stable_sort(order.begin(), order.end(),
                   [&](size_t a, size_t b) { return weight[a] > weight[b]; });
  const double u0 = rng.Uniform() / static_cast<double>(wanted);
  std::vector<Particle> next;
  next.reserve(wanted);
  double cumulative = weight[order[0]];
  size_t k = 0;
  for (size_t j = 0; j < wanted; ++j) {
    const double target = u0 + static_cast<double>(j) / static_cast<double>(wanted);
    while (cumulative < target && k + 1 < n) cumulative += weight[order[++k]];
    next.push_back(particles_[order[k]]);
    next.back().log_weight = 0.0;
  }
  particles_ = std::move(next);
  scans_since_resampling_ = 0;
}

struct Slam::Prediction {
  std::vector<ScanPath> paths;   // per particle
  std::vector<Pose2> nominal;    // per particle: odometry's end pose without its heading drift
  std::vector<Pose2> predicted;  // per particle: its end pose drawn from the motion model
  double trans = 0.0;            // odometry's translation over the scan (m)
  // What a particle's heading drift is multiplied by over this scan: its time (s) where the
  // heading comes from a gyro, its signed distance (m) where it comes from the encoders.
  double drift_span = 0.0;
  double sigma_trans = 0.0, sigma_rot1 = 0.0, sigma_rot2 = 0.0;  // of the motion model
  // Spread of phase B's search: the motion model's over this scan, plus the drift left
  // uncorrected since the last informative match, within the parameters' bounds.
  double search_pos = 0.0, search_angle = 0.0;
  // Deviation of the motion prior in phase B's score: the same, but no less than a third of the
  // least search spread (the candidates explore about three prior deviations around it).
  double prior_pos = 0.0, prior_angle = 0.0;
  // Half the width of the heading sweep (rad), 0 without one (SlamConfig::heading_sweep_*).
  double sweep = 0.0;
};

struct Slam::MatchResult {
  std::vector<Pose2> chosen;      // per particle: the winning candidate (the prediction without
  std::vector<double> chosen_ll;  // matching) and its log-likelihood (0 without matching)
  bool matched = false;           // phase B ran
  size_t candidates = 1;          // per particle
  int64_t matching_rays = 0;
  double ambiguity = 0.0;  // ScanReport::refinement_ambiguity
  bool interrupted = false;
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

  const std::vector<Measurement> usable = CollectMeasurements(scan);
  report.usable_measurements = static_cast<int>(usable.size());
  const std::vector<const Measurement*> matching = SelectMatching(scan, usable, plan);

  const Prediction prediction = PredictMotion(scan, plan.refine, step);
  const WindowPlan windows = PlanWindows(prediction, matching, plan);
  if (!windows.empty()) {
    // The particles that cast through their tiles need the tiles' clearance, which the last
    // update left stale where a window served instead.
    ForEach(config_.parallel, particles_.size(), [&](size_t p) {
      if (!windows[p]) particles_[p].map.RefreshSummaries();
    });
  }
  const MatchResult match = MatchScan(prediction, matching, plan, windows, step);
  report.candidates = static_cast<int>(match.candidates);
  if (match.matched) {
    report.refinement_ambiguity = match.ambiguity;
    report.rays.matching = match.matching_rays;
    report.interrupted = match.interrupted;
    report.matching_measurements = static_cast<int>(matching.size());
  }

  // What the map did not correct accumulates until a scan matched on enough readings pins the
  // pose down again: the heading's drift moves the position too.
  if (match.matched && matching.size() >= kInformativeMatches) {
    unmatched_var_pos_ = 0.0;
    unmatched_var_angle_ = 0.0;
    // The heading the match corrected beyond the drift already taken out is drift still there:
    // per second, a scan's worth of it over the averaging time; per metre, weighted by how far
    // the scan drove.
    const bool per_metre = !robot_.base.heading_from_gyro;
    const double most = DegToRad(per_metre ? kMaxHeadingDriftDegM : kMaxHeadingDriftDegS);
    const double weight =
        prediction.drift_span / std::max(std::abs(prediction.drift_span), kMinHeadingDriftStepM);
    const Pose2 odometry = Between(scan.odom_begin, scan.odom_end);
    const bool still = std::hypot(odometry.x, odometry.y) < kMinHeadingDriftStepM &&
                       std::abs(odometry.theta) < DegToRad(kStillTurnDeg);
    if (HasRangeScanner(robot_) && !still) {
      double mean_sq = 0.0;
      for (size_t p = 0; p < particles_.size(); ++p) {
        mean_sq += Square(NormalizeAngle(match.chosen[p].theta - prediction.nominal[p].theta));
      }
      mean_sq /= static_cast<double>(particles_.size());
      // It starts where the set's own search stands.
      double& var = correction_var_angle_
                        ? *correction_var_angle_
                        : correction_var_angle_.emplace(Square(
                              DegToRad(params_.min_angle_uncertainty_deg) / kCorrectionSigmas));
      var += (mean_sq - var) / kCorrectionAveragingScans;
    }
    for (size_t p = 0; p < particles_.size(); ++p) {
      const double turn = NormalizeAngle(match.chosen[p].theta - prediction.nominal[p].theta);
      double& drift = particles_[p].heading_drift;
      const double learnt =
          per_metre ? turn * weight / kHeadingDriftDistanceM : turn / kHeadingDriftTimeS;
      drift = std::clamp(drift - learnt, -most, most);
    }
  } else if (plan.refine) {
    unmatched_var_pos_ +=
        Square(prediction.sigma_trans) + Square(prediction.trans) * unmatched_var_angle_;
    unmatched_var_angle_ += Square(prediction.sigma_rot1) + Square(prediction.sigma_rot2);
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

std::vector<const Slam::Measurement*> Slam::SelectMatching(const Scan& scan,
                                                           const std::vector<Measurement>& usable,
                                                           const ScanPlan& plan) const {
  // A plan asking for more readings than the set's thinning keeps (not merely unlimited) asks
  // for the narrowed search's.
  std::vector<size_t> thinned = ThinByAngle(scan, usable, ThinningStep());
  const double narrowed = NarrowedThinningStep(scan);
  if (plan.matching_measurements != ScanPlan::kUnlimited &&
      plan.matching_measurements > static_cast<int>(thinned.size()) && narrowed < ThinningStep()) {
    thinned = ThinByAngle(scan, usable, narrowed);
  }
  std::vector<const Measurement*> matching;
  for (size_t i :
       SpreadEvenly(thinned.size(), static_cast<size_t>(std::max(0, plan.matching_measurements)))) {
    matching.push_back(&usable[thinned[i]]);
  }
  return matching;
}

Slam::Prediction Slam::PredictMotion(const Scan& scan, bool refine, uint64_t step) const {
  const size_t n_particles = particles_.size();
  const MotionDelta motion = Decompose(Between(scan.odom_begin, scan.odom_end));
  const double angle_const = DegToRad(params_.angle_error_const_deg);
  Prediction out;
  out.sigma_trans = params_.dist_error_ratio * std::abs(motion.trans) + params_.dist_error_const_m;
  out.sigma_rot1 = params_.angle_error_ratio * std::abs(motion.rot1) + angle_const;
  out.sigma_rot2 = params_.angle_error_ratio * std::abs(motion.rot2) + angle_const;
  out.trans = std::abs(motion.trans);
  out.drift_span =
      robot_.base.heading_from_gyro ? std::max(0.0, scan.t_end - scan.t_begin) : motion.trans;
  const double drift_pos = std::sqrt(Square(out.sigma_trans) + unmatched_var_pos_);
  const double drift_angle = DriftAngle(scan);
  const double min_angle = LeastSearchAngle();
  out.search_pos = std::clamp(drift_pos, params_.min_pos_uncertainty_m, kMaxSearchPosM);
  out.search_angle = std::clamp(drift_angle, min_angle, DegToRad(kMaxSearchAngleDeg));
  out.prior_pos = std::max(drift_pos, params_.min_pos_uncertainty_m / 3.0);
  out.prior_angle = std::max(drift_angle, min_angle / 3.0);
  const double turn = std::abs(NormalizeAngle(motion.rot1 + motion.rot2));
  if (config_.heading_sweep_turn_deg > 0 && HasRangeScanner(robot_) &&
      turn > DegToRad(config_.heading_sweep_turn_deg)) {
    out.sweep = config_.heading_sweep_share * turn;
  }
  out.predicted.resize(n_particles);
  out.nominal.resize(n_particles);
  out.paths.reserve(n_particles);
  for (size_t p = 0; p < n_particles; ++p) {
    out.paths.emplace_back(scan, particles_[p].pose);
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
    MotionDelta noisy = motion;
    noisy.rot1 += rng.Normal(out.sigma_rot1);
    noisy.trans += rng.Normal(out.sigma_trans);
    noisy.rot2 += rng.Normal(out.sigma_rot2);
    out.predicted[p] = Compose(particles_[p].pose, Recompose(noisy));
    out.predicted[p].theta = NormalizeAngle(out.predicted[p].theta - drift);
  }
  return out;
}

double Slam::LeastSearchAngle() const {
  const double set = DegToRad(params_.min_angle_uncertainty_deg);
  if (!HasRangeScanner(robot_) || !correction_var_angle_) return set;
  return std::clamp(kCorrectionSigmas * std::sqrt(*correction_var_angle_), kLeastSearchShare * set,
                    set);
}

bool Slam::MatchesScan(const ScanPlan& plan, size_t matching) const {
  return plan.refine && matching > 0 && (plan.candidates > 1 || particles_.size() > 1);
}

Slam::WindowPlan Slam::PlanWindows(const Prediction& prediction,
                                   const std::vector<const Measurement*>& matching,
                                   const ScanPlan& plan) const {
  const size_t n_particles = particles_.size();
  if (!MatchesScan(plan, matching.size())) return {};
  const auto n_candidates = static_cast<size_t>(std::max(1, plan.candidates));
  // A particle whose candidates cast enough rays gets a MatchWindow over the cells they can
  // reach: each matching ray from its sample's pose under the predicted correction, its end
  // widened by kWindowTurnSigmas of the candidates' heading spread over the ray's reach, and
  // all of it by 4 sigma_pos (candidates drawn farther cast through the map). The rays' own
  // ends rather than the longest ray all around: near a wall, the window stops a little
  // beyond it instead of a ray's length beyond (about 40 % fewer cells in the arenas).
  // Same answers either way; what a window costs per cell and saves per ray is measured by
  // BM_MatchWindowBuild and BM_MatchingRayWindow (bench/).
  constexpr int64_t kCellsPerRayPaid = 16;
  constexpr double kWindowTurnSigmas = 2.0;
  WindowPlan windows(n_particles);
  for (size_t p = 0; p < n_particles; ++p) {
    const ScanPath& path = prediction.paths[p];
    const Pose2 correction = path.CorrectionTo(prediction.predicted[p]);
    std::array<double, 4> box = path.Extent(correction);
    for (const Measurement* m : matching) {
      const ScanPath::Frame frame = path.SampleFrame(m->sample, correction);
      const Vec2 origin = frame.Point(m->local_origin);
      const Vec2 end = frame.Point(m->local_origin + m->local_direction * m->match_range_m);
      const double turn = std::max(kWindowTurnSigmas * prediction.search_angle, prediction.sweep) *
                          (m->local_origin.norm() + m->match_range_m);
      box = {std::min({box[0], origin.x(), end.x() - turn}),
             std::min({box[1], origin.y(), end.y() - turn}),
             std::max({box[2], origin.x(), end.x() + turn}),
             std::max({box[3], origin.y(), end.y() + turn})};
    }
    const double pad = 4.0 * prediction.search_pos + 3.0 * config_.resolution_m;
    // Near the map's bound (or beyond it), no window: the rays go through the grid, which
    // clips them to the bound.
    if (!geometry_.InMapBound({box[0] - pad, box[1] - pad}) ||
        !geometry_.InMapBound({box[2] + pad, box[3] + pad})) {
      continue;
    }
    const CellIndex lo = geometry_.CellOf({box[0] - pad, box[1] - pad});
    const CellIndex hi = geometry_.CellOf({box[2] + pad, box[3] + pad});
    const int64_t cells = (int64_t{hi.x} - lo.x + 1) * (int64_t{hi.y} - lo.y + 1);
    const auto rays = static_cast<int64_t>(n_candidates * matching.size());
    if (cells <= kMaxMatchWindowCells && rays * kCellsPerRayPaid >= cells) windows[p] = {lo, hi};
  }
  return windows;
}

Slam::MatchResult Slam::MatchScan(const Prediction& prediction,
                                  const std::vector<const Measurement*>& matching,
                                  const ScanPlan& plan, const WindowPlan& window_plan,
                                  uint64_t step) const {
  const size_t n_particles = particles_.size();
  const std::vector<ScanPath>& paths = prediction.paths;
  const std::vector<Pose2>& predicted = prediction.predicted;
  MatchResult out;
  out.chosen = predicted;
  out.chosen_ll.assign(n_particles, 0.0);
  out.matched = MatchesScan(plan, matching.size());
  if (!out.matched) return out;
  const size_t n_candidates = static_cast<size_t>(std::max(1, plan.candidates));
  out.candidates = n_candidates;

  const double sigma_pos = prediction.search_pos;
  const double sigma_angle = prediction.search_angle;
  const LogOdds occupied_above = EncodeLogOdds(config_.occupied_above_logodds);
  std::vector<std::optional<MatchWindow>> windows(n_particles);
  ForEach(config_.parallel, n_particles, [&](size_t p) {
    if (window_plan[p])
      windows[p].emplace(particles_[p].map, occupied_above, window_plan[p]->lo, window_plan[p]->hi);
  });
  // The search: the first half of each particle's candidates are drawn around its prediction
  // (candidate 0 is the prediction itself), wide enough to re-acquire a pose that drifted; the
  // rest in up to kClimbRounds rounds around the best so far, the spread halving each round, to
  // settle close to the likelihood's peak. Rounds run one after the other; the candidates of a
  // round run in parallel, each from its own random stream, so serial equals parallel.
  constexpr size_t kClimbRounds = 4;
  const size_t explore = std::max<size_t>(1, (n_candidates + 1) / 2);
  const size_t round_size =
      std::max<size_t>(1, (n_candidates - explore + kClimbRounds - 1) / kClimbRounds);
  std::vector<Pose2> candidate_pose(n_particles * n_candidates);
  std::vector<double> candidate_ll(n_particles * n_candidates);
  std::vector<size_t> best(n_particles);  // per particle: index of its best candidate so far
  for (size_t p = 0; p < n_particles; ++p) best[p] = p * n_candidates;
  std::atomic<size_t> skipped{0};
  // Each candidate's score is its log-likelihood plus its log-prior under the motion model
  // around the odometry's end pose: where the readings tell the candidates little apart, the
  // odometry wins rather than the luckiest candidate (the maximum of many noisy likelihoods).
  std::vector<double> candidate_score(n_particles * n_candidates);
  const auto log_prior = [&](size_t p, const Pose2& c) {
    const Pose2& nominal = prediction.nominal[p];
    return -0.5 * (Square(c.x - nominal.x) + Square(c.y - nominal.y)) /
               Square(prediction.prior_pos) -
           0.5 * Square(NormalizeAngle(c.theta - nominal.theta)) / Square(prediction.prior_angle);
  };
  // The heading sweep (a large odometry turn): the first explore candidates after the
  // prediction, evenly over +- sweep, at most half of them.
  size_t sweep_count = 0;
  if (prediction.sweep > 0 && explore >= 5) {
    const auto wanted = static_cast<size_t>(
        2 * std::floor(prediction.sweep / DegToRad(config_.heading_sweep_step_deg)) + 1);
    sweep_count = std::min(wanted, (explore - 1) / 2);
    if (sweep_count % 2 == 0) --sweep_count;  // odd: symmetric around the prediction
  }
  size_t first = 0;
  for (int round = 0; first < n_candidates; ++round) {
    const size_t last = std::min(n_candidates, round == 0 ? explore : first + round_size);
    const size_t width = last - first;
    const double scale = std::ldexp(1.0, -round);  // 1, 1/2, 1/4, ...
    std::vector<Pose2> centre(n_particles);
    for (size_t p = 0; p < n_particles; ++p) {
      centre[p] = round == 0 ? predicted[p] : candidate_pose[best[p]];
    }
    ForEach(config_.parallel, n_particles * width, [&](size_t k) {
      const size_t p = k / width, c = first + k % width;
      const size_t index = p * n_candidates + c;
      if (c > 0 && interrupt_ != nullptr && interrupt_->load(std::memory_order_relaxed)) {
        candidate_pose[index] = predicted[p];
        candidate_ll[index] = -std::numeric_limits<double>::infinity();  // never chosen
        candidate_score[index] = candidate_ll[index];
        skipped.fetch_add(1, std::memory_order_relaxed);
        return;
      }
      Pose2 end = centre[p];
      if (round == 0 && c >= 1 && c <= sweep_count) {
        const double offset = sweep_count == 1
                                  ? 0.0
                                  : prediction.sweep * (2.0 * static_cast<double>(c - 1) /
                                                            static_cast<double>(sweep_count - 1) -
                                                        1.0);
        end.theta = NormalizeAngle(end.theta + offset);
      } else if (c > 0) {
        Rng rng = Rng::ForStream(config_.seed, step, p, kStreamCandidate + c);
        end.x += rng.Normal(scale * sigma_pos);
        end.y += rng.Normal(scale * sigma_pos);
        end.theta = NormalizeAngle(end.theta + rng.Normal(scale * sigma_angle));
      }
      const MatchWindow* window = windows[p] ? &*windows[p] : nullptr;
      candidate_pose[index] = end;
      candidate_ll[index] =
          LogLikelihood(particles_[p].map, window, paths[p], paths[p].CorrectionTo(end), matching);
      candidate_score[index] = candidate_ll[index] + log_prior(p, end);
    });
    for (size_t p = 0; p < n_particles; ++p) {
      for (size_t c = first; c < last; ++c) {
        const size_t i = p * n_candidates + c;
        if (candidate_score[i] > candidate_score[best[p]]) best[p] = i;
      }
    }
    first = last;
  }
  double ambiguity = 0.0;
  for (size_t p = 0; p < n_particles; ++p) {
    out.chosen[p] = candidate_pose[best[p]];
    // The particle's weight takes the best candidate's log-likelihood, wherever the fit moves it.
    out.chosen_ll[p] = candidate_ll[best[p]];
    if (config_.fit_peak && n_candidates >= static_cast<size_t>(kPeakFitMinCandidates)) {
      const size_t begin = p * n_candidates;
      const std::optional<Pose2> peak =
          FittedPeak(std::span(candidate_pose).subspan(begin, n_candidates),
                     std::span(candidate_ll).subspan(begin, n_candidates), matching.size(),
                     candidate_pose[best[p]], prediction.nominal[p], {sigma_pos, sigma_angle},
                     {prediction.prior_pos, prediction.prior_angle});
      if (peak) out.chosen[p] = *peak;
    }
    if (explore > 1) {
      // The first round's posterior (weights exp(ll - its best ll)) around its winner: how
      // little the measurements told the candidates drawn from the proposal apart.
      size_t winner = p * n_candidates;
      for (size_t c = 1; c < explore; ++c) {
        if (candidate_ll[p * n_candidates + c] > candidate_ll[winner])
          winner = p * n_candidates + c;
      }
      double weight_sum = 0.0, spread_sq = 0.0;
      for (size_t c = 0; c < explore; ++c) {
        const size_t i = p * n_candidates + c;
        const double w = std::exp(candidate_ll[i] - candidate_ll[winner]);
        const double dx = candidate_pose[i].x - candidate_pose[winner].x,
                     dy = candidate_pose[i].y - candidate_pose[winner].y;
        weight_sum += w;
        spread_sq += w * (dx * dx + dy * dy);
      }
      ambiguity += std::sqrt(spread_sq / weight_sum) / std::max(std::sqrt(2.0) * sigma_pos, 1e-9);
    }
  }
  out.ambiguity = ambiguity / static_cast<double>(n_particles);
  out.matching_rays =
      static_cast<int64_t>((n_particles * n_candidates - skipped.load()) * matching.size());
  out.interrupted = skipped.load() > 0;
  return out;
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
  const std::vector<double> weight = NormalizedWeights(particles_);
  double sum_sq = 0.0;
  for (double w : weight) sum_sq += w * w;
  report.effective_sample_size = 1.0 / sum_sq;
  report.best_log_likelihood = match.chosen_ll[static_cast<size_t>(&Best() - particles_.data())];

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
