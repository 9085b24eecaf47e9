// Fuzzes the CARMEN log reader (offline/carmen_log) and the benchmark relations reader
// (offline/relations) with the input as text. Invariants: every line is counted once, as a
// comment, a malformed line, an ignored message or a record; the records kept match their
// counters; at most 20 problems are kept, one per malformed line; every number kept is finite;
// relations either parse whole (finite, the yaw wrapped) or give errors.

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "fuzz/fuzz_check.hpp"
#include "offline/carmen_log.hpp"
#include "offline/relations.hpp"

using slam::fuzz::Check;

namespace {

bool Finite(const slam::Pose2& p) {
  return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.theta);
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
      for (float r : laser.ranges) Check(std::isfinite(r), "range not finite");
      if (laser.robot_odometry) Check(Finite(*laser.robot_odometry), "odometry not finite");
      if (laser.laser_pose) Check(Finite(*laser.laser_pose), "laser pose not finite");
    }
    for (const auto& odometry : log.odometry) {
      Check(std::isfinite(odometry.t) && Finite(odometry.pose), "ODOM not finite");
    }
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
