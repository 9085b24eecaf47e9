#pragma once
// FastSLAM 2.0 on a log-odds occupancy grid, adapted to the marXbot's rotating scanner
// (paper section V): per scan, phase A motion (motion_model.hpp, drift_tracker.hpp), B matching
// and pose refinement (scan_matcher.hpp), C grid update, D resampling (particle_set.hpp). Its
// cost is counted in rays and bounded by the plan given for each scan.

#include <atomic>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <vector>

#include "engine/drift_tracker.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/params.hpp"
#include "engine/particle_set.hpp"
#include "engine/pose.hpp"
#include "engine/robot.hpp"
#include "engine/scan.hpp"
#include "engine/scan_matcher.hpp"
#include "engine/scan_path.hpp"
#include "engine/sensor_model.hpp"

namespace slam {

/// Engine settings that are not tuned by the evolution strategy.
struct SlamConfig {
  double resolution_m = 0.01;
  double logodds_limit = 5.0;           // cells are clamped to [-limit, +limit]
  double occupied_above_logodds = 0.0;  // matching rays stop at cells above this
  UpdateModelConfig update;
  /// Robust likelihood floor of one measurement: log(exp(-r^2 / 2 sigma^2) + floor).
  double match_floor = 0.05;
  /// Matching rays stop this many sigmas beyond the measured distance.
  double match_range_sigmas = 3.0;
  /// A range scanner's readings are matched with a deviation of at least this many cells: a
  /// laser's own noise (a centimetre) is far below what a grid of 5 cm cells, built from poses
  /// that err by about a cell, can tell; matched that sharply, the likelihood has a narrow peak
  /// that the candidates miss and a map that is off by a cell rejects good poses (grid matchers
  /// use about one cell: GMapping's sigma of 5 cm at 5 cm cells). Chosen among 0 and 1 on the
  /// simulated laser experiments (docs/laser.md). The infrared sensors keep their calibrated noise.
  double range_sigma_min_cells = 1.0;
  /// A range scanner's heading sweep: when the odometry turned by more than this over a scan
  /// (degrees; 0: never), phase B's first candidates are headings spread evenly, every
  /// `heading_sweep_step_deg`, over +- `heading_sweep_share` of the turn around the prediction.
  /// Wheels that skid while turning err by a share of the turn, beyond what a Gaussian spread
  /// reaches. Not for the infrared scanner (the marXbot's gyro keeps its heading).
  double heading_sweep_turn_deg = 0.0;
  double heading_sweep_share = 0.6;
  double heading_sweep_step_deg = 2.0;
  /// Phase B's estimate: the peak of the log-likelihood fitted over the candidates, with the
  /// motion prior (true), or the best candidate alone (false, the paper's). docs/design.md,
  /// phase B.
  bool fit_peak = true;
  uint64_t seed = 1;
  /// A particle's history keeps a pose at every reading's time (true: offline evaluation
  /// interpolates the ground truth's poses there) or only each scan's end (false: a server
  /// that serves and saves scan ends, whose history then costs one pose a scan, not one a
  /// reading, over a long run).
  bool history_samples = true;
  bool parallel = true;  // oneTBB across particles and candidates; results equal the serial path

  /// Empty when valid.
  ConfigErrors Validate() const;
};

/// Which readings phase B matches: the set's thinning, or the lighter thinning of a range
/// scanner whose heading search has narrowed (ScanSummary::matching_available).
enum class SearchMode { kSet, kNarrowed };

/// What the engine may spend on one scan (produced by the scheduler).
struct ScanPlan {
  static constexpr int kUnlimited = std::numeric_limits<int>::max();
  int particles = 1;                       // particle count from this scan on (a change
                                           // resamples before the scan)
  int candidates = 1;                      // pose candidates per particle (1 = no refinement)
  SearchMode search = SearchMode::kSet;    // the readings the candidates match
  int matching_measurements = kUnlimited;  // cap on those matched per candidate
  int update_rays = kUnlimited;            // cap on grid-update rays per particle
  bool refine = true;                      // false: phase B off, odometry-only mapping
};

struct RayCounts {
  int64_t matching = 0;
  int64_t update = 0;
  int64_t total() const { return matching + update; }
};

/// The numbers of a scan that a plan depends on.
struct ScanSummary {
  int usable_measurements = 0;    // readings inside their sensor's use window (update rays)
  int matching_measurements = 0;  // of those, kept for matching after thinning by angle
  // Kept after the lighter thinning of a range scanner whose heading search has narrowed
  // (Slam::LeastSearchAngle; SearchMode::kNarrowed): a narrower search needs fewer candidates,
  // so a plan may match more readings with each (SplitQuota). Not above matching_measurements
  // otherwise.
  int matching_available = 0;
  // A narrowed search keeps at least this many candidates per particle: what phase B's peak
  // fit needs.
  int narrowed_candidates_min = kPeakFitMinCandidates;
};

/// A scan prepared for Slam::ProcessScan: its usable readings measured once, their thinnings
/// for matching and its summary. It refers to `scan`, which must outlive it, and holds for the
/// next ProcessScan with the same parameters (the thinning follows the heading search).
struct PreparedScan {
  const Scan* scan = nullptr;
  std::vector<Measurement> usable;  // inside their sensor's use window (the update rays)
  std::vector<size_t> thinned;      // indices into usable: the set's thinning
  std::vector<size_t> narrowed;     // the narrowed search's thinning; empty when not narrower
  ScanSummary summary;
};

/// Why Slam::ProcessScan refused a scan: nothing was done with it, the particles hold where
/// they were (as across a restart of the base's odometry).
enum class ScanRefusal {
  kNone,
  kNotFinite,          // a time or an odometry pose is not finite
  kImplausibleMotion,  // the odometry moves further than the robot drives in the scan's time
  kOutsideMap,         // the odometry would take a particle beyond the map's bound
};
/// "none", "not_finite", "implausible_motion", "outside_map".
const char* ToString(ScanRefusal refusal);

/// What the engine did with one scan.
struct ScanReport {
  int64_t scan = 0;
  Pose2 pose;  // best particle's pose at the end of the scan
  RayCounts rays;
  int particles = 0;
  int candidates = 0;             // per particle
  int usable_measurements = 0;    // inside their use window (before thinning and the cap)
  int matching_measurements = 0;  // matched per candidate
  int update_rays = 0;            // per particle
  bool resampled = false;
  double effective_sample_size = 0.0;
  double best_log_likelihood = 0.0;  // of the best particle's chosen candidate
  /// How little the measurements told the candidates apart, averaged over particles: the
  /// likelihood-weighted RMS distance of the candidates from the chosen one, over the RMS
  /// distance the proposal alone gives (sqrt(2) sigma). About 0 when one candidate dominates,
  /// about 1 when the likelihood is flat; 0 without refinement.
  double refinement_ambiguity = 0.0;
  /// The interrupt flag (Slam::set_interrupt) cut the scan's refinement short: some candidates
  /// beyond each particle's first were not evaluated (nor counted in `rays`).
  bool interrupted = false;
  /// Not kNone when the scan was refused (Slam::ProcessScan): then nothing else was done.
  ScanRefusal refused = ScanRefusal::kNone;
};

class Slam {
 public:
  /// Share of a match's correction that moves the whole scan, from its first sample on; the
  /// rest grows linearly over the scan (ScanPath; docs/design.md, phase B). Chosen on the
  /// validation worlds among 0 (the paper's: the start stays where the previous match put it),
  /// 0.3, 0.5, 0.7 and 1.
  static constexpr double kStartShare = 0.7;

  /// Preconditions: Validate(robot), Validate(params) and config.Validate() are empty.
  Slam(const RobotDescription& robot, const SlamParams& params, const SlamConfig& config);

  /// Measures a scan once for Summarize's numbers, ProcessScan and ReadingPoints.
  PreparedScan Prepare(const Scan& scan) const;

  /// Runs phases A-D on one prepared scan within `plan` and reports what was done. A scan whose
  /// times or odometry are not finite, whose odometry moves further than the robot drives in the
  /// scan's time (kScanTravelSlackS beyond it), or would take a particle beyond the map's bound
  /// is refused (ScanReport::refused, counted in scans_refused()): the particles hold.
  ScanReport ProcessScan(const PreparedScan& prepared, const ScanPlan& plan);
  /// ProcessScan(Prepare(scan), plan).
  ScanReport ProcessScan(const Scan& scan, const ScanPlan& plan);
  /// Time allowed beyond a scan's own duration in its odometry's plausible travel (the base's
  /// max_speed_m_s over both): readings are stamped when they arrive, in batches.
  static constexpr double kScanTravelSlackS = 1.0;

  /// Starts every particle from a known map and pose (a saved map, or a map drawn by hand);
  /// the map's tiles are shared, not copied. Refuses (false, nothing changed) a pose that
  /// AcceptsPose refuses. Precondition: same resolution as the config.
  bool Restore(const OccupancyGrid& map, const Pose2& pose);

  /// Puts every particle at `pose` on the best particle's map (a relocalisation, or a pose the
  /// user gives): the weights restart equal, the histories continue from the best's (with the
  /// jump), the drift learnt is kept. Refuses (false, nothing changed) a pose AcceptsPose
  /// refuses.
  bool Relocate(const Pose2& pose);

  /// Every particle's map becomes `map` (tiles shared, not copied); poses, weights and histories
  /// are kept: what a tracker that was lost mapped since `map` is taken back. Precondition: same
  /// resolution as the config.
  void ReplaceMap(const OccupancyGrid& map);

  /// Whether the engine takes `pose` as a particle's: finite, its position inside the map's
  /// bound (GridGeometry::InMapBound at the config's resolution).
  bool AcceptsPose(const Pose2& pose) const;

  /// Log-likelihood (eq. 2) of a scan's matching measurements on the best particle's map, if
  /// the scan ended at `end` (from the particle's current pose). For diagnostics and tests.
  double ScoreScan(const Scan& scan, const Pose2& end) const;

  /// Counts what a scan offers, for the scheduler to plan with (Prepare(scan).summary). For a
  /// range scanner it also depends on the corrections earlier matches made
  /// (matching_available): it holds for the next ProcessScan with the same parameters.
  ScanSummary Summarize(const Scan& scan) const;

  /// Where the scan's readings (those inside their sensor's use window) lie in the robot's
  /// frame at the scan's end, each placed by the odometry from its sample to the end: the scan
  /// as a viewer draws it around the robot.
  std::vector<Vec2> ReadingPoints(const PreparedScan& prepared) const;

  /// While `flag` (may be null) is true, a scan evaluates each particle's first candidate only
  /// and skips the rest: a scan of a huge budget (seconds of work) then ends within
  /// milliseconds of a stop or cancel request, the engine consistent. The flag must outlive
  /// the engine's use of it; results do not depend on it while it stays false.
  void set_interrupt(const std::atomic<bool>* flag) { interrupt_ = flag; }

  /// Replaces the tuned parameters from the next scan on (precondition: valid).
  void SetParams(const SlamParams& params) { params_ = params; }
  const SlamParams& params() const { return params_; }
  /// Phase B's least heading search for the next scan (rad): the set's minimum angle
  /// uncertainty, narrowed for a range scanner to the corrections its matches have been making.
  double LeastSearchAngle() const;
  const SlamConfig& config() const { return config_; }

  const std::vector<Particle>& particles() const { return particles_; }
  /// The particle with the largest weight (lowest index on ties).
  const Particle& Best() const { return particles_[BestIndex(particles_)]; }
  /// The best particle's trajectory, time-ordered, starting at the origin.
  std::vector<TimedPose> Trajectory() const { return History(Best()); }
  int64_t scans_processed() const { return scans_processed_; }
  /// Scans ProcessScan refused (not counted in scans_processed()).
  int64_t scans_refused() const { return scans_refused_; }

 private:
  struct Prediction;
  using WindowPlan = std::vector<std::optional<WindowBounds>>;

  // ProcessScan's steps, in order.
  /// Whether the scan may move the particles (ScanRefusal::kNone), or why not.
  ScanRefusal CheckScan(const Scan& scan) const;
  /// Gives every particle a history and applies the plan's particle count (drawn from the
  /// current weights); true when it resampled.
  bool StartScan(const Scan& scan, const ScanPlan& plan, uint64_t step);
  /// The readings inside their sensor's use window (the update rays).
  std::vector<Measurement> CollectMeasurements(const Scan& scan) const;
  /// Those kept for matching: the plan's search mode's thinning, then capped.
  std::vector<const Measurement*> SelectMatching(const PreparedScan& prepared,
                                                 const ScanPlan& plan) const;
  /// The readings kept for matching: the first, then each at least `step` (rad) of platform
  /// angle past the last kept.
  std::vector<size_t> ThinByAngle(const Scan& scan, const std::vector<Measurement>& usable,
                                  double step) const;
  /// ThinByAngle's step: the set's angle between scans, and the lighter one of a narrowed heading
  /// search (the set's times LeastSearchAngle over the set's minimum angle uncertainty).
  double ThinningStep() const;
  double NarrowedThinningStep(const Scan& scan) const;
  /// Phase A: each particle's path through the scan and its end pose sampled from the motion
  /// model (noise-free without refinement: odometry-only mapping), and phase B's search spread.
  Prediction PredictMotion(const Scan& scan, bool refine, uint64_t step) const;
  /// Whether phase B runs: refinement on, readings to match, and more than one pose to weigh.
  bool MatchesScan(const ScanPlan& plan, size_t matching) const;
  /// Which particles' phase B pays for a MatchWindow, and over which cells (per particle;
  /// empty when nothing is matched). The others cast their rays through their grid's tiles.
  WindowPlan PlanWindows(const Prediction& prediction,
                         const std::vector<const Measurement*>& matching,
                         const ScanPlan& plan) const;
  /// Phase B: the scan matcher over every particle.
  MatchResult MatchScan(const Prediction& prediction,
                        const std::vector<const Measurement*>& matching, const ScanPlan& plan,
                        const WindowPlan& windows, uint64_t step) const;
  /// Phase C: the plan's share of the usable readings updates each particle's map along its
  /// ray from its sample's refined pose; extends the histories, moves the particles and adds
  /// the chosen candidates' log-likelihoods to their weights. The number of update rays each.
  /// Tiles' clearance is refreshed only for the particles that cast through their tiles this
  /// scan (`windows`); the others' stays stale until a scan casts through them.
  size_t UpdateParticles(const Scan& scan, const std::vector<Measurement>& usable,
                         const Prediction& prediction, const MatchResult& match,
                         const ScanPlan& plan, const WindowPlan& windows);
  /// Phase D: the effective sample size, then resampling every resampling_period_scans.
  void FinishScan(const MatchResult& match, uint64_t step, ScanReport& report);
  /// Draws `wanted` particles in proportion to their weights (random stream `stream` of scan
  /// `step`).
  void Resample(size_t wanted, uint64_t step, uint64_t stream);

  RobotDescription robot_;
  SlamParams params_;
  SlamConfig config_;
  GridGeometry geometry_;
  std::vector<SensorModel> sensor_models_;  // one per scanner sensor, in event word order
  ScanMatcher matcher_;
  std::vector<Particle> particles_;
  DriftTracker drift_;
  int64_t scans_processed_ = 0;
  int64_t scans_refused_ = 0;
  int64_t scans_since_resampling_ = 0;
  const std::atomic<bool>* interrupt_ = nullptr;
};

}  // namespace slam
