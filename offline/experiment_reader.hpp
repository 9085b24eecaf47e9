#pragma once
// Reading recorded experiments (docs/design.md section 5) for replays and the tuner: the
// directory's files are checked, can.log goes through the same decoding as live data (candump
// replay -> Aseba reassembly -> event decoder -> scan assembler), nothing is dropped for lack of
// time.
//
// What is an error and what is a counted skip:
// - robot.json, can.log and meta.json are required; a missing, unreadable or malformed one is
//   an error naming the file (and the line, for JSON with a known position). A robot with a
//   range scanner (laser) is recorded as a CARMEN log, log.clf, in place of can.log.
// - groundtruth.tum and world.json are optional; when present they must be well formed
//   (groundtruth.tum: times strictly increasing, errors give file:line). Its times are the log's
//   clock's; where that clock jumped (can.log's replay takes the jumps out) they are moved with
//   the scans, and poses that fall in a jump are left out and counted.
// - Inside can.log, garbled lines (a truncated last line too), malformed Aseba fragments and
//   unknown messages are counted and skipped, as on a live link. A log that yields no scan at all
//   is an error, with the counters that explain why.

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "engine/io/experiment_meta.hpp"
#include "engine/pose.hpp"
#include "engine/robot.hpp"
#include "engine/scan.hpp"
#include "engine/scan_assembler.hpp"
#include "hw_link/aseba.hpp"
#include "hw_link/event_decoder.hpp"
#include "hw_link/frame_source.hpp"
#include "offline/carmen_log.hpp"
#include "sim/world.hpp"

namespace slam::offline {

/// What decoding can.log counted.
struct ExperimentCounters {
  uint64_t frames = 0;         // frames read from the log
  uint64_t bad_lines = 0;      // garbled log lines skipped
  uint64_t ignored_lines = 0;  // comments and blank lines
  hw::ReassemblyCounters reassembly;
  hw::DecoderCounters decoder;
  ScanAssemblerCounters assembler;
  uint64_t clock_jumps = 0;  // steps of the log's clock taken out of the replay's time
  /// Ground-truth poses left out: stamped inside a clock jump (or a silence taken for one) or
  /// in a stretch of time the log repeats after a step back, they match no replayed time.
  uint64_t ground_truth_unplaced = 0;
  /// CARMEN logs: laser records left out because their time was not after the previous scan's
  /// (the log's order is kept; their odometry still counts), or because no odometry covered it.
  uint64_t scans_out_of_order = 0;
  uint64_t scans_without_odometry = 0;

  /// Frames, lines and messages rejected anywhere on the way: garbled lines, frames the Aseba
  /// reassembly dropped, messages the decoder did not recognise.
  uint64_t FramesRejected() const { return bad_lines + reassembly.Rejected() + decoder.Rejected(); }
};

struct Experiment {
  std::string dir;
  io::ExperimentMeta meta;
  RobotDescription robot;
  std::vector<Scan> scans;
  /// In the replay's time (the log's with clock jumps taken out, as the scans'); empty without
  /// groundtruth.tum.
  std::vector<TimedPose> ground_truth;
  std::optional<sim::World> world;  // simulated experiments only
  double t_first = 0.0;             // times of the first and last frame of can.log
  double t_last = 0.0;
  ExperimentCounters counters;
  /// The first lines skipped as malformed, "file:line: why" (CARMEN logs; a CAN log's garbled
  /// lines are only counted).
  std::vector<std::string> problems;
  /// What the reader assumed where the data did not say it (a CARMEN log's derived robot, the
  /// first 20 odometry restarts it took), one line each.
  std::vector<std::string> notes;

  /// Recorded time covered by can.log, seconds.
  double duration_s() const { return t_last - t_first; }
};

/// Reads and decodes the experiment in `dir`; the errors (Message(): one line each) name their
/// files. `dir` may also be a CARMEN log (LooksLikeCarmenLog), read with LoadCarmenExperiment.
Result<Experiment> LoadExperiment(const std::string& dir,
                                  const ScanAssemblerConfig& assembler = {});

/// How a CARMEN log becomes an experiment.
struct CarmenOptions {
  /// The robot; derived from the log when not given (DeriveCarmenRobot).
  std::optional<RobotDescription> robot;
};

/// Reads a CARMEN text log as an experiment: one scan per laser record of the front laser
/// (FLASER, RAWLASER1 or ROBOTLASER1, whichever the log has most of), its beams the scan's
/// samples at the record's time and odometry (the record's own, else interpolated between ODOM
/// lines), ranges as RangeToRaw. Malformed lines are counted (counters.bad_lines) and skipped;
/// meta.name is the file's name, meta.source "robot". No ground truth.
Result<Experiment> LoadCarmenExperiment(const std::string& path, const CarmenOptions& options = {});
/// The same from a log already parsed (ParseCarmenLog), `path` naming it in messages.
Result<Experiment> CarmenExperiment(const CarmenLog& log, const std::string& path,
                                    const CarmenOptions& options = {});

/// Where a CARMEN log's front laser sits on its robot (robot frame: x ahead, y left, theta
/// counter-clockwise), and what says so, or why the centre (words for the user).
struct CarmenMount {
  Pose2 pose;
  std::string source;
};

/// The front laser's place: from PARAM robot_frontlaser_offset, _side_offset and
/// _angular_offset where the log has any of them; else from the records that carry both the
/// laser's pose and the robot's odometry (FLASER with poses, ROBOTLASER1), when at least 99 % of
/// them put the laser within 1 cm and 0.5 degrees of one place (a raw log; a log whose poses
/// were corrected after the run does not); else the robot's centre.
CarmenMount DeriveCarmenMount(const CarmenLog& log);

/// A robot for a CARMEN log: one range sensor where DeriveCarmenMount puts it, its beams from the
/// records (RAWLASER / ROBOTLASER1) or the CARMEN convention (FLASER: PARAM laser_front_laser_fov,
/// else 180 degrees, first beam at -fov/2, the last at +fov/2), its maximum range from PARAM
/// robot_front_laser_max or the records, a no-return value where the log saturates at its largest
/// reading, and a generic laser noise (1 cm + 0.5 % of the range).
RobotDescription DeriveCarmenRobot(const CarmenLog& log, const std::string& name);

}  // namespace slam::offline
