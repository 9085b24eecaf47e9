#include "offline/experiment_reader.hpp"

#include <cmath>
#include <filesystem>
#include <limits>
#include <vector>

#include "engine/io/experiment_meta.hpp"
#include "engine/io/robot_json.hpp"
#include "engine/io/tum.hpp"
#include "hw_link/frame_decoder.hpp"
#include "hw_link/transports.hpp"

namespace slam::offline {
namespace {

uint64_t Counter(const hw::SourceCounters& counters, const std::string& name) {
  for (const auto& [key, value] : counters) {
    if (key == name) return value;
  }
  return 0;
}

// The replay's time is the log's with clock jumps taken out (OpenCandumpReplay): between two
// jumps it is the log's time shifted by a constant. A stretch of frames with one shift:
struct ClockSegment {
  double logged_first = 0.0;  // the log's times of its first and last frame
  double logged_last = 0.0;
  double shift = 0.0;  // logged - replay time
};

// A jump changes the shift by at least 1 s (a step back) or 4 s (a step ahead); rounding of
// the two times to doubles, by about a microsecond.
constexpr double kShiftChangeS = 0.5;
// Ground-truth poses this close to a stretch of frames belong to it (a tracker samples at tens
// of Hz, the bus at hundreds): less than half the 1 s a jump leaves in the replay's time.
constexpr double kSegmentSlackS = 0.2;

class LogClock {
 public:
  void Observe(const hw::TimedFrame& frame) {
    if (!frame.source_t) return;
    const double logged = *frame.source_t;
    const double shift = logged - frame.t;
    if (segments_.empty() || std::abs(shift - segments_.back().shift) > kShiftChangeS) {
      segments_.push_back({logged, logged, shift});
    } else {
      segments_.back().logged_last = logged;
    }
  }

  /// Ground-truth poses stamped by the log's clock, in the replay's time. Poses in no stretch
  /// of frames (a silence taken out as a jump) or in several (a step back repeated the log's
  /// times) cannot be placed: they are left out and counted in `dropped`.
  std::vector<TimedPose> ToReplayTime(const std::vector<TimedPose>& logged,
                                      uint64_t& dropped) const {
    if (segments_.size() < 2) {
      // No jump: one shift (zero when the log's clock never jumped, as OpenCandumpReplay starts
      // the replay's time at the log's).
      std::vector<TimedPose> out = logged;
      const double shift = segments_.empty() ? 0.0 : segments_.front().shift;
      for (TimedPose& pose : out) pose.t -= shift;
      return out;
    }
    std::vector<TimedPose> out;
    out.reserve(logged.size());
    for (const TimedPose& pose : logged) {
      const ClockSegment* home = nullptr;
      int homes = 0;
      for (size_t k = 0; k < segments_.size(); ++k) {
        const ClockSegment& s = segments_[k];
        const double from =
            k == 0 ? -std::numeric_limits<double>::infinity() : s.logged_first - kSegmentSlackS;
        const double to = k + 1 == segments_.size() ? std::numeric_limits<double>::infinity()
                                                    : s.logged_last + kSegmentSlackS;
        if (pose.t >= from && pose.t <= to) {
          home = &s;
          ++homes;
        }
      }
      if (homes != 1) {
        ++dropped;
        continue;
      }
      out.push_back({pose.t - home->shift, pose.pose});
    }
    return out;
  }

 private:
  std::vector<ClockSegment> segments_;
};

}  // namespace

Result<Experiment> LoadExperiment(const std::string& dir,
                                  const ScanAssemblerConfig& assembler_config) {
  std::error_code ec;
  if (LooksLikeCarmenLog(dir)) return LoadCarmenExperiment(dir);
  if (!std::filesystem::is_directory(dir, ec)) {
    return Error(dir + ": not an experiment directory (" +
                 (std::filesystem::exists(dir, ec) ? "not a directory" : "does not exist") + ")");
  }
  const std::filesystem::path base(dir);
  const auto file = [&](const char* name) { return (base / name).string(); };

  Experiment experiment;
  experiment.dir = dir;
  std::vector<std::string> errors;

  // A robot with a laser is recorded as a CARMEN log (log.clf) instead of can.log; beside it
  // robot.json and meta.json are optional (the robot is then derived from the log, and the
  // directory names the experiment).
  const bool carmen =
      !std::filesystem::exists(file("can.log"), ec) && std::filesystem::exists(file("log.clf"), ec);
  const bool has_robot = !carmen || std::filesystem::exists(file("robot.json"), ec);
  const bool has_meta = !carmen || std::filesystem::exists(file("meta.json"), ec);
  if (has_robot) {
    auto robot = io::LoadRobot(file("robot.json"));
    if (!robot.ok()) {
      errors.push_back(robot.Message());
    } else {
      experiment.robot = robot.value();
    }
  }
  if (has_meta) {
    auto meta = io::LoadExperimentMeta(file("meta.json"));
    if (!meta.ok()) {
      errors.push_back(meta.Message());
    } else {
      experiment.meta = std::move(meta).value();
    }
  }
  if (std::filesystem::exists(file("groundtruth.tum"), ec)) {
    auto truth = io::LoadTum(file("groundtruth.tum"));
    if (!truth.ok()) {
      errors.push_back(truth.Message());
    } else {
      experiment.ground_truth = std::move(truth).value();
    }
  }
  if (std::filesystem::exists(file("world.json"), ec)) {
    Result<sim::World> world = sim::LoadWorld(file("world.json"));
    if (!world.ok()) {
      for (const ConfigError& e : world.errors()) errors.push_back(e.detail);
    } else {
      experiment.world = std::move(world).value();
    }
  }
  if (!carmen && !std::filesystem::exists(file("can.log"), ec)) {
    errors.push_back(file("can.log") + ": cannot open (No such file or directory)");
  }
  if (!errors.empty()) {
    ConfigErrors all;
    for (std::string& e : errors) all.push_back({"", std::move(e), 0});
    return all;
  }

  if (carmen) {
    CarmenOptions options;
    if (has_robot) options.robot = experiment.robot;
    Result<Experiment> log = LoadCarmenExperiment(file("log.clf"), options);
    if (!log.ok()) return log;
    Experiment& read = log.value();
    read.dir = dir;
    if (has_meta) {
      read.meta = std::move(experiment.meta);
    } else {
      std::filesystem::path named = std::filesystem::absolute(base, ec).lexically_normal();
      if (!named.has_filename()) named = named.parent_path();  // "dir/"
      if (!named.filename().empty()) read.meta.name = named.filename().string();
    }
    read.ground_truth = std::move(experiment.ground_truth);
    read.world = std::move(experiment.world);
    return log;
  }

  hw::OpenResult opened = hw::OpenCandumpReplay(file("can.log"));
  if (!opened.ok()) return opened.errors();
  hw::FrameSource& source = *opened.value();
  hw::FrameDecoder decoder(experiment.robot);
  ScanAssembler assembler(experiment.robot, assembler_config);
  LogClock clock;
  const Result<void> decoded = DecodeToEnd(
      source, decoder, [&](const RobotEvent& event) { assembler.Add(event, experiment.scans); },
      [&](const hw::TimedFrame& frame) { clock.Observe(frame); });
  if (!decoded.ok()) return Error(file("can.log") + ": " + decoded.Message());

  ExperimentCounters& counters = experiment.counters;
  counters.frames = decoder.frames();
  const hw::SourceCounters source_counters = source.Counters();
  counters.bad_lines = Counter(source_counters, "bad_lines");
  counters.ignored_lines = Counter(source_counters, "ignored_lines");
  counters.reassembly = decoder.reassembly();
  counters.decoder = decoder.decoder();
  counters.assembler = assembler.counters();
  counters.clock_jumps = Counter(source_counters, "clock_jumps");
  // The ground truth is stamped by the log's clock; the scans by the replay's.
  experiment.ground_truth =
      clock.ToReplayTime(experiment.ground_truth, counters.ground_truth_unplaced);
  experiment.t_first = decoder.first_time();
  experiment.t_last = decoder.last_time();
  if (experiment.scans.empty()) {
    return Error(file("can.log") + ": no complete scan in " + std::to_string(counters.frames) +
                 " frames (" + std::to_string(counters.bad_lines) + " garbled lines, " +
                 std::to_string(counters.reassembly.Rejected()) + " rejected fragments, " +
                 std::to_string(counters.decoder.odometry) + " odometry and " +
                 std::to_string(counters.decoder.scanner) + " scanner events, " +
                 std::to_string(counters.decoder.Rejected()) + " unknown messages)");
  }
  return experiment;
}

}  // namespace slam::offline
