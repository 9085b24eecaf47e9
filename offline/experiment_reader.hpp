#pragma once
// Reading recorded experiments (docs/design.md section 5) for replays and the tuner: the
// directory's files are checked, can.log goes through the same decoding as live data (candump
// replay -> Aseba reassembly -> event decoder -> scan assembler), nothing is dropped for lack of
// time.
//
// What is an error and what is a counted skip:
// - robot.json, can.log and meta.json are required; a missing, unreadable or malformed one is
//   an error naming the file (and the line, for JSON with a known position).
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

  /// Recorded time covered by can.log, seconds.
  double duration_s() const { return t_last - t_first; }
};

/// Reads and decodes the experiment in `dir`; the errors (Message(): one line each) name their
/// files.
Result<Experiment> LoadExperiment(const std::string& dir,
                                  const ScanAssemblerConfig& assembler = {});

}  // namespace slam::offline
