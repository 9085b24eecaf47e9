// Fuzzes the CARMEN log reader (offline/carmen_log) and the benchmark relations reader
// (offline/relations) with the input as text. Invariants: every line is counted once, as a
// comment, a malformed line, an ignored message or a record; the records kept match their
// counters; at most 20 problems are kept, one per malformed line; every number kept is finite
// and within the reader's bounds (readings per record, poses' coordinates and angles); relations
// either parse whole (finite, the yaw wrapped) or give errors. A log that parses becomes an
// experiment (or an error) whose first scans are replayed through the SLAM at a small budget:
// the replay ends (a hang is a libFuzzer timeout) with every pose finite and inside the map's
// bound. The seeds (fuzz/corpus/fuzz_carmen/) hold huge and extreme values: 1e300, -1e300,
// nan, inf, 1e9, max double, long lines, many beams.

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string_view>
#include <vector>

#include "engine/grid_geometry.hpp"
#include "fuzz/fuzz_check.hpp"
#include "offline/carmen_log.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/relations.hpp"
#include "offline/replay.hpp"

using slam::fuzz::Check;

namespace {

bool Finite(const slam::Pose2& p) {
  return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.theta);
}

bool WithinReaderBounds(const slam::Pose2& p) {
  return std::abs(p.x) <= slam::offline::kCarmenMaxPoseM &&
         std::abs(p.y) <= slam::offline::kCarmenMaxPoseM &&
         std::abs(p.theta) <= slam::offline::kCarmenMaxAngleRad;
}

// The log as an experiment, its first few scans replayed at a small budget on this thread.
void ReplayStart(const slam::offline::CarmenLog& log) {
  const auto experiment = slam::offline::CarmenExperiment(log, "fuzz.clf");
  if (!experiment.ok()) {
    Check(!experiment.errors().empty(), "an experiment refused without errors");
    return;
  }
  const slam::offline::Experiment& e = experiment.value();
  for (const slam::Scan& scan : e.scans) {
    Check(Finite(scan.odom_begin) && Finite(scan.odom_end), "scan odometry not finite");
  }
  constexpr size_t kScans = 4;
  const std::vector<slam::Scan> first(
      e.scans.begin(),
      e.scans.begin() + static_cast<std::ptrdiff_t>(std::min(e.scans.size(), kScans)));
  slam::offline::ReplayOptions options;
  options.config.parallel = false;
  options.budget.rays_per_scan = 2000;
  const slam::offline::ReplayResult run = slam::offline::Replay(e.robot, first, {}, options);
  Check(run.scans == static_cast<int64_t>(first.size()), "a replay stopped short");
  const slam::GridGeometry& geometry = run.map.geometry();
  for (const slam::TimedPose& p : run.trajectory) {
    Check(Finite(p.pose) && geometry.InMapBound(p.pose.translation()),
          "a pose outside the map's bound");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const auto parsed = slam::offline::ParseCarmenLog(text, "fuzz.clf");
  if (parsed.ok()) {
    const slam::offline::CarmenLog& log = parsed.value();
    const slam::offline::CarmenCounters& c = log.counters;
    Check(c.lines == c.comments + c.bad_lines + c.ignored_lines + c.odometry + c.lasers + c.params,
          "a line counted twice or not at all");
    Check(log.lasers.size() == c.lasers && log.odometry.size() == c.odometry,
          "records kept differ from their counters");
    Check(!log.lasers.empty(), "a log without laser records was accepted");
    Check(log.problems.size() == std::min<uint64_t>(c.bad_lines, 20), "problems kept");
    for (const auto& laser : log.lasers) {
      Check(std::isfinite(laser.t), "laser time not finite");
      Check(laser.ranges.size() <= slam::offline::kCarmenMaxReadings, "too many readings kept");
      for (float r : laser.ranges) Check(std::isfinite(r), "range not finite");
      if (laser.robot_odometry) {
        Check(Finite(*laser.robot_odometry) && WithinReaderBounds(*laser.robot_odometry),
              "odometry not finite or beyond the bound");
      }
      if (laser.laser_pose) {
        Check(Finite(*laser.laser_pose) && WithinReaderBounds(*laser.laser_pose),
              "laser pose not finite or beyond the bound");
      }
    }
    for (const auto& odometry : log.odometry) {
      Check(std::isfinite(odometry.t) && Finite(odometry.pose) && WithinReaderBounds(odometry.pose),
            "ODOM not finite or beyond the bound");
    }
    ReplayStart(log);
  } else {
    Check(!parsed.errors().empty(), "a failure without errors");
  }

  const auto relations = slam::offline::ParseRelations(text, "fuzz.relations");
  if (relations.ok()) {
    for (const auto& r : relations.value()) {
      Check(std::isfinite(r.t1) && std::isfinite(r.t2) && Finite(r.motion), "relation not finite");
      Check(r.motion.theta > -slam::kPi - 1e-12 && r.motion.theta <= slam::kPi + 1e-12,
            "yaw not wrapped");
    }
    // Scoring a trajectory built from the relations' own times never breaks.
    std::vector<slam::TimedPose> trajectory;
    for (const auto& r : relations.value()) {
      if (trajectory.empty() || r.t1 > trajectory.back().t) trajectory.push_back({r.t1, r.motion});
    }
    const auto score = slam::offline::ScoreRelations(trajectory, relations.value());
    Check(score.used <= score.relations, "more relations used than given");
    Check(std::isfinite(score.translation_m.mean) && std::isfinite(score.rotation_deg.mean) &&
              score.translation_m.std_dev >= 0.0,
          "statistics not finite");
  }
  return 0;
}
