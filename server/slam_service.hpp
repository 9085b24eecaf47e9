#pragma once
// The live SLAM of slamd: the link thread's events -> scans -> the engine under the ray-budget
// scheduler, on a thread of its own (docs/design.md section 2). After every scan it publishes an
// immutable snapshot; readers (HTTP threads) take the latest one and never make it wait.
// Commands from readers (budget, parameters, reset) are applied by the SLAM thread between
// scans.

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "engine/occupancy_grid.hpp"
#include "engine/params.hpp"
#include "engine/pose.hpp"
#include "engine/quality.hpp"
#include "engine/relocalizer.hpp"
#include "engine/result.hpp"
#include "engine/robot.hpp"
#include "engine/scan_assembler.hpp"
#include "engine/slam.hpp"
#include "engine/thread_safety.hpp"
#include "hw_link/link.hpp"
#include "scheduler/budgeted_step.hpp"
#include "scheduler/params_catalog.hpp"
#include "scheduler/ray_budget_scheduler.hpp"
#include "server/state_store.hpp"
#include "sim/virtual_marxbot.hpp"

namespace slam::server {

/// What one scan cost and achieved.
struct ScanMetrics {
  int64_t scan = 0;   // scans processed since start, resumed ones excluded
  int64_t quota = 0;  // rays allowed
  int64_t rays_planned = 0;
  int64_t rays_used = 0;
  int particles = 0;
  int candidates = 0;
  double ess = 0.0;             // effective sample size after the scan
  double scan_period_s = 0.0;   // robot time the scan covers
  double latency_s = 0.0;       // from the scan's last event reaching slamd to its snapshot
  double busy_s = 0.0;          // wall time the SLAM thread spent on it
  double cpu_s = 0.0;           // SLAM thread CPU time spent on it
  double cpu_share = 0.0;       // cpu_s / scan_period_s
  double realtime_ratio = 0.0;  // scan_period_s / busy_s: how many times faster than real time
  bool late = false;            // latency above the scan period: the next scan was already due
  /// The scan went to the relocaliser (nothing matched or mapped; rays 0).
  bool relocalizing = false;
  /// Point lookups of the scan besides its rays: the relocaliser's search, or the loss
  /// detector's check (kLookupsPerRay of them are paid as one quota ray).
  int64_t lookups = 0;
  // Against the ground truth (simulated sources), both trajectories aligned by the rigid
  // transform that fits this run so far best, as the ATE is: the latest pose's distance, and
  // the RMS over the run (its ATE so far).
  std::optional<double> pose_error_m;
  std::optional<double> ate_m;
};

/// Why the SLAM relocalises: a map resumed without the robot's pose, a request (POST
/// /api/v1/relocalize), a pose given as a hint with its uncertainty (POST /api/v1/pose), or the
/// loss detector (the tracker's readings contradict the map: the robot was carried, or slipped).
enum class RelocalizationCause { kResume, kRequest, kHint, kLost };
/// "resume", "request", "hint", "lost".
const char* ToString(RelocalizationCause cause);

/// One relocalisation the engine took.
struct RelocalizationRecord {
  RelocalizationCause cause = RelocalizationCause::kRequest;
  double t = 0.0;  // robot time (as in snapshots) of the scan that completed it
  Pose2 pose;      // where it put the robot, map frame
  double score = 0.0;
  double runner_up_score = 0.0;
  int points = 0;  // readings in its multiscan
  int searches = 0;
  int64_t lookups = 0;
  int scans = 0;          // scans it searched over
  double search_s = 0.0;  // robot time from its start to the answer
};

/// A pose the user gives for the robot (POST /api/v1/pose), map frame.
struct PoseRequest {
  Pose2 pose;
  /// Given: the pose is a hint, and the relocaliser searches the map within three deviations
  /// of it (the missing one of the two takes kDefaultHintSigmaM or kDefaultHintSigmaDeg).
  /// Neither: the robot is put there as it is.
  std::optional<double> sigma_m;
  std::optional<double> sigma_deg;
  static constexpr double kDefaultHintSigmaM = 0.2;
  static constexpr double kDefaultHintSigmaDeg = 10.0;
};

/// What is wrong with a pose request (JSON pointers /x, /y, /theta_deg, /sigma_m, /sigma_deg):
/// values not finite, a position beyond the map's bound at `resolution_m`, deviations not
/// positive or beyond 50 m and 180 degrees. Empty when valid.
ConfigErrors ValidatePoseRequest(const PoseRequest& request, double resolution_m);

/// Everything a reader needs, as of one scan. Immutable once published.
struct SlamSnapshot {
  uint64_t sequence = 0;  // increases with every publication
  uint64_t epoch = 0;     // resets so far
  /// Versions reported to clients are engine tile versions plus this base, so that they only
  /// grow across resets and restarts.
  uint64_t version_base = 0;
  uint64_t map_version = 0;  // the largest reported tile version
  double resolution_m = 0.01;
  std::vector<TileRef> tiles;  // the best particle's
  bool has_pose = false;
  TimedPose pose;  // the best particle's latest, in the map frame, time with time_offset
  std::shared_ptr<const TrajectoryChunk> history;         // the best particle's (engine times)
  std::shared_ptr<const std::vector<TimedPose>> resumed;  // trajectory loaded at start
  double time_offset_s = 0.0;  // added to engine times (continues a resumed trajectory)
  std::optional<ScanMetrics> last;
  std::optional<Pose2> truth;  // ground truth at `pose.t`, map frame (simulated sources)
  /// The latest scan's readings in the robot's frame at `pose` (Slam::ReadingPoints); null
  /// before the first scan, after a reset, and always without ServiceOptions::scan_points.
  std::shared_ptr<const std::vector<Vec2>> scan_points;
  /// Set while the SLAM relocalises (the pose is then the last one known, not updated, and the
  /// map is not changed): why.
  std::optional<RelocalizationCause> relocalizing;
  std::optional<RelocalizationRecord> last_relocalization;
  /// While relocalising, after a search that ended unsure: the distinct places it scored, best
  /// first, carried by the odometry to the latest scan (RelocalizerStep::rejected_candidates):
  /// where the robot may be. Empty otherwise.
  std::vector<GlobalMatch> relocalization_places;
  double relocalization_places_t = 0.0;  // robot time (as `pose.t`) of the scan they are at

  /// Tile version as reported (0 for a missing tile).
  uint64_t ReportedVersion(const Tile& tile) const { return version_base + tile.version; }
};

/// One pose per scan end (plus the start), resumed part first, times with the offset applied.
std::vector<TimedPose> ScanEndTrajectory(const SlamSnapshot& snapshot);

/// The best particle's map as a grid holding the snapshot's tiles (shared, not copied);
/// `encoded_logodds_limit` is the cells' clamp in the grid's encoding (EncodeLogOdds).
OccupancyGrid SnapshotGrid(const SlamSnapshot& snapshot, int encoded_logodds_limit);

enum class SlamState { kWaiting, kRunning, kRelocalizing };
const char* ToString(SlamState state);

/// Running totals for /metrics and /status.
struct ServiceCounters {
  SlamState state = SlamState::kWaiting;
  int64_t scans = 0;
  int64_t late_scans = 0;
  /// Scans the engine refused (odometry not finite, implausibly fast, or beyond the map's
  /// bound): nothing was done with them and the pose held.
  int64_t refused_scans = 0;
  int64_t rays_planned = 0;
  int64_t rays_used = 0;
  int64_t resets = 0;
  /// Relocalisation: scans that went to it, its lookups, answers taken, answers the engine
  /// refused (off the map), searches that ended unsure, and poses given (POST /api/v1/pose
  /// without deviations).
  int64_t relocalizing_scans = 0;
  int64_t relocalization_lookups = 0;
  int64_t relocalizations = 0;
  int64_t relocalizations_refused = 0;
  int64_t relocalization_searches_unsure = 0;
  int64_t poses_set = 0;
  int64_t losses = 0;  // the loss detector found the tracker lost
  double busy_s = 0.0;
  double cpu_s = 0.0;
  double robot_s = 0.0;
  /// Scan latency histogram: counts of latency <= each bound in kLatencyBuckets (cumulative
  /// counts are built when exporting), plus the sum.
  std::vector<uint64_t> latency_counts;
  double latency_sum_s = 0.0;
  ScanAssemblerCounters assembler;
};

/// Upper bounds of the latency histogram, seconds.
const std::vector<double>& LatencyBuckets();

struct ServiceOptions {
  RobotDescription robot;
  ParamsChoice params;  // the shipped sets by quota unless one is given (--params)
  SlamConfig config;    // config.parallel is forced off: the CPU share is the SLAM thread's
  BudgetSettings budget;
  SchedulerConfig scheduler;
  ScanAssemblerConfig assembler;
  /// Restored state (map, trajectory) to continue from, if any.
  std::optional<SavedState> resume;
  /// The robot's pose on the restored map, when known (slamd --pose); otherwise the SLAM
  /// relocalises on the restored map before it maps anything (a robot may have been carried
  /// while slamd was off; the virtual marXbot starts over from its start pose).
  std::optional<Pose2> resume_pose;
  RelocalizerConfig relocalizer;
  /// The loss detector (loss_detector.hpp): on, a tracker whose readings contradict the map
  /// stops mapping and relocalises.
  bool detect_loss = true;
  LossDetectorConfig loss_detector;
  /// Localisation only (slamd --localize): tracks and relocalises on the resumed map, never
  /// changes it (no update ray is cast; resets and saves are refused by the server).
  bool localize_only = false;
  /// Keep each scan's readings for the snapshot (SlamSnapshot::scan_points, Foxglove's /scan);
  /// off, the SLAM thread does not compute them.
  bool scan_points = true;
};

class SlamService {
 public:
  /// `truth_source` (may be null): the virtual marXbot inside `link`, for the ground truth.
  /// Preconditions: options valid (robot, params, config, budget).
  SlamService(hw::Link& link, sim::VirtualMarxbotSource* truth_source,
              const ServiceOptions& options);
  ~SlamService();  // stops the thread
  SlamService(const SlamService&) = delete;
  SlamService& operator=(const SlamService&) = delete;

  void Start();
  void Stop();

  /// The latest snapshot (never null).
  std::shared_ptr<const SlamSnapshot> Snapshot() const;
  /// Waits until a snapshot newer than `sequence` is published, at most `timeout`; returns the
  /// latest snapshot either way.
  std::shared_ptr<const SlamSnapshot> WaitNewer(uint64_t sequence,
                                                std::chrono::milliseconds timeout) const;

  /// Budget settings (applied from the next scan).
  BudgetSettings Budget() const { return scheduler_.settings(); }
  /// The budget with its revision, read together: bumped by every change of the budget, and only
  /// then (the budget's ETag). Thread-safe.
  struct RevisedBudget {
    BudgetSettings budget;
    uint64_t revision = 0;
  };
  RevisedBudget BudgetRevised() const;
  /// What ChangeBudget did.
  struct BudgetChange {
    bool precondition_failed = false;  // nothing changed: the precondition refused the revision
    ConfigErrors errors;               // nothing changed: what the change found wrong
    BudgetSettings budget;             // the budget after
    uint64_t revision = 0;             // and its revision
  };
  /// Replaces the budget with `change(current)` (a validated budget, or what is wrong) if
  /// `precondition(revision)` holds, atomically with every other change of the budget (HTTP,
  /// Foxglove). Thread-safe.
  BudgetChange ChangeBudget(
      const std::function<bool(uint64_t revision)>& precondition,
      const std::function<Result<BudgetSettings>(const BudgetSettings&)>& change);
  /// ChangeBudget to `settings`, unconditionally. Precondition: valid.
  void SetBudget(const BudgetSettings& settings);
  /// The parameter set the next scan runs with: the one given, or the shipped set of the
  /// current quota.
  ParamsSet Params() const;
  /// The shipped set of the current quota (what a null member of a PATCH resets to).
  ParamsSet ShippedParamsNow() const;
  /// Whether the parameters follow the quota (the shipped sets) or are one given set.
  bool ParamsFollowQuota() const;
  /// Bumped whenever Params() changes (a set given, or another shipped set for a new quota),
  /// and only then: the parameters' ETag. Thread-safe.
  uint64_t ParamsRevision() const;
  /// Runs `params` (named `name`) from the next scan, whatever the quota. Precondition: valid.
  void SetParams(const std::string& name, const SlamParams& params);
  /// Goes back to the shipped set of each scan's quota from the next scan.
  void UseShippedParams();
  /// The parameter set in use with its revision, read together.
  struct RevisedParams {
    ParamsSet set;
    uint64_t revision = 0;
  };
  RevisedParams ParamsRevised() const;
  /// UseShippedParams, atomically with every other change of the parameters; what is in use
  /// after.
  RevisedParams ResetParams();
  /// What ChangeParams did.
  struct ParamsChange {
    bool precondition_failed = false;  // nothing changed: the precondition refused the revision
    ConfigErrors errors;               // nothing changed: what the change found wrong
    SlamParams params;                 // the parameters the change made (valid when no errors)
    uint64_t revision = 0;             // the revision after
  };
  /// Replaces the parameters with `change(current, shipped)` (the set in use and the shipped set
  /// of the current quota; a validated result, or what is wrong) if `precondition(revision)`
  /// holds, atomically with every other change of the parameters. A result equal to the shipped
  /// set follows the budget's sets again; another is named after the set it came from
  /// ("NAME, patched") and stays whatever the budget. Thread-safe.
  ParamsChange ChangeParams(
      const std::function<bool(uint64_t revision)>& precondition,
      const std::function<Result<SlamParams>(const SlamParams& current, const SlamParams& shipped)>&
          change);
  /// Clears the map and trajectory; takes effect before the next scan.
  void RequestReset();
  /// Puts the robot at a pose, or relocalises around it (PoseRequest); takes effect before the
  /// next scan and ends any relocalisation under way. Precondition: ValidatePoseRequest is empty.
  void RequestPose(const PoseRequest& request);
  /// Relocalises on the map as it is (the whole map) from the next scan; false (nothing
  /// requested) when nothing is mapped yet.
  bool RequestRelocalize();

  ServiceCounters Counters() const;
  /// The ground truth so far in the map frame (decimated to 10 Hz), empty if not simulated.
  std::vector<TimedPose> GroundTruth() const;
  bool simulated() const { return truth_source_ != nullptr; }
  bool localize_only() const { return options_.localize_only; }
  /// Lifts the virtual marXbot and sets it down at `target` (by default where it was half its
  /// run ago): its odometry does not see it, the ground truth does. Thread-safe. The pose it
  /// lands on, or why not (a target that is not free, or no virtual marXbot).
  Result<Pose2> KidnapSimulatedRobot(const std::optional<Pose2>& target);
  const RobotDescription& robot() const { return options_.robot; }
  const SlamConfig& config() const { return options_.config; }
  /// config().logodds_limit (natural log-odds) in the grid's cell encoding (EncodeLogOdds).
  int encoded_logodds_limit() const;

 private:
  void Run();
  /// Before a scan: its period sets a CPU share's quota, and with it Params().
  void FollowPeriod(double scan_period_s);
  /// Bumps params_revision_ if Params() is no longer what it was at the last revision.
  void ReviseParams() SLAM_REQUIRES(mutex_);
  /// One scan through the budget, then its metrics, counters and errors against the ground
  /// truth, published.
  void ProcessScan(const Scan& scan, int64_t receive_ns);
  ScanMetrics MetricsOf(const BudgetedStep::Result& step, double period, int64_t wall_start,
                        int64_t receive_ns) const;
  /// A scan's times and CPU account: busy, latency, CPU share, late.
  static void Time(ScanMetrics& m, const BudgetedStep::Result& step, double period,
                   int64_t wall_start, int64_t receive_ns);
  /// The ground truth's poses not yet in truth_map_, in the map frame (the world aligned to it
  /// at the first scan's start); none without a simulated source.
  std::vector<TimedPose> NewlyMappedTruth();
  void CountScan(const ScanMetrics& m, double period, const std::vector<TimedPose>& newly_mapped);
  /// The scan ends' ATE and the latest pose's error against the ground truth, when aligned.
  void MeasureAgainstTruth(ScanMetrics& m);
  void ApplyCommands();
  void BuildEngine();
  /// Starts relocalising on the best particle's map (over `region`, a hint's, carried by the
  /// odometry from the latest scan's end).
  void StartRelocalizing(RelocalizationCause cause, const GlobalRegion& region = {});
  /// Applies a pose request between scans.
  void ApplyPose(const PoseRequest& request);
  /// A search under way from now, for `cause`: its places, time and scans start afresh.
  void BeginSearch(RelocalizationCause cause);
  /// The loss detector found the tracker lost (the step has started relocalising): counted,
  /// logged, the search's bookkeeping begun.
  void NoteLoss(const LossCheck& check);
  /// A scan that went to the relocaliser: counted, logged when it ends, published.
  void ProcessRelocalizingScan(const BudgetedStep::Result& step, const Scan& scan, double period,
                               int64_t wall_start, int64_t receive_ns);
  /// Counts what every scan shares (latency, CPU, robot time) into `c`.
  static void CountCommon(ServiceCounters& c, const ScanMetrics& m, double period);
  void Publish(const std::optional<ScanMetrics>& metrics);
  void UpdateGroundTruth();

  hw::Link& link_;
  sim::VirtualMarxbotSource* truth_source_;
  ServiceOptions options_;
  RayBudgetScheduler scheduler_;

  // SLAM thread only.
  std::unique_ptr<Slam> engine_;
  ScanAssembler assembler_;
  uint64_t version_base_ = 0;
  uint64_t epoch_ = 0;
  uint64_t sequence_ = 0;
  std::shared_ptr<const std::vector<TimedPose>> resumed_;
  std::shared_ptr<const std::vector<Vec2>> scan_points_;  // the latest scan's, for snapshots
  double time_offset_s_ = 0.0;
  size_t truth_read_ = 0;                        // ground-truth poses taken from the source
  std::vector<TimedPose> truth_world_;           // since the last reset, world frame, 10 Hz
  std::optional<RigidTransform2> world_to_map_;  // set at the first scan after (re)start
  Relocalizer relocalizer_;
  LossDetector loss_detector_;
  std::optional<RelocalizationCause> relocalizing_;  // while relocalizer_ is active
  double relocalizing_since_t_ = -1.0;               // robot time of its first scan (-1: none yet)
  int relocalizing_scans_ = 0;
  std::optional<RelocalizationRecord> last_relocalization_;
  std::optional<Pose2> last_odom_;  // the latest scan's odometry at its end
  double last_t_end_ = 0.0;         // ... and its end (engine time)
  // The last unsure search's places (RelocalizerStep::rejected_candidates) since the search
  // under way started, where the odometry read places_odom_; published while relocalising.
  std::vector<GlobalMatch> places_;
  Pose2 places_odom_;

  // Shared with readers.
  mutable Mutex mutex_;
  mutable std::condition_variable published_;
  std::shared_ptr<const SlamSnapshot> snapshot_ SLAM_GUARDED_BY(mutex_);
  ServiceCounters counters_ SLAM_GUARDED_BY(mutex_);
  std::vector<TimedPose> truth_map_ SLAM_GUARDED_BY(mutex_);  // map frame
  // Serialise changes of the budget, and of the parameters; taken before mutex_, never after.
  mutable Mutex budget_mutex_;
  Mutex params_change_mutex_;
  uint64_t budget_revision_ SLAM_GUARDED_BY(budget_mutex_) = 1;
  ParamsChoice params_ SLAM_GUARDED_BY(mutex_);
  bool params_changed_ SLAM_GUARDED_BY(mutex_) = false;
  uint64_t params_revision_ SLAM_GUARDED_BY(mutex_) = 1;
  ParamsSet revised_params_ SLAM_GUARDED_BY(mutex_);    // Params() at the last revision
  double last_period_s_ SLAM_GUARDED_BY(mutex_) = 0.0;  // of the last scan: a CPU share's quota
  // SLAM thread only: each scan through the budget (the engine's set included).
  std::unique_ptr<BudgetedStep> step_;
  bool reset_requested_ SLAM_GUARDED_BY(mutex_) = false;
  std::optional<PoseRequest> pose_requested_ SLAM_GUARDED_BY(mutex_);
  bool relocalize_requested_ SLAM_GUARDED_BY(mutex_) = false;

  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace slam::server
