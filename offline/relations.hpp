#pragma once
// The relations metric of the Freiburg SLAM benchmark (Kümmerle et al., "On measuring the
// accuracy of SLAM algorithms", Autonomous Robots 2009), as its metricEvaluator computes it.
//
// A relation is the robot's true displacement from its pose at time t1 to its pose at time t2,
// in the frame of the first pose. A trajectory is scored on a relation by its own displacement
// between its poses nearest in time to t1 and t2 (each within 0.1 s, else the relation is left
// out): the translational error is the distance between the two displacements' translations,
// the rotational error the absolute difference of their angles. Reported: the number of
// relations used, and the mean and (population) standard deviation of the absolute errors and
// of the squared errors, translations in metres, rotations in degrees (squared: m^2, deg^2).
//
// The relations file: one relation per line, "t1 t2 x y z roll pitch yaw" (seconds, metres,
// radians); blank lines and lines starting with '#' are skipped. A planar evaluation uses x, y
// and yaw. Malformed lines are errors naming file:line, as for groundtruth.tum: ground truth
// that is wrong must not give a score.

#include <cstddef>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "engine/pose.hpp"
#include "engine/result.hpp"

namespace slam::offline {

struct Relation {
  double t1 = 0.0;
  double t2 = 0.0;
  Pose2 motion;  // the pose at t2 seen from the pose at t1
};

/// Parses relations text; `source` names the input in errors ("intel.relations:12: ...").
Result<std::vector<Relation>> ParseRelations(std::string_view text, const std::string& source);

/// Reads and parses a relations file.
Result<std::vector<Relation>> LoadRelations(const std::string& path);

/// Mean and population standard deviation of absolute and of squared errors.
struct ErrorStatistics {
  double mean = 0.0;
  double std_dev = 0.0;
  double squared_mean = 0.0;
  double squared_std_dev = 0.0;
};

/// One relation as the trajectory scored it.
struct RelationError {
  size_t index = 0;      // of the relation, in the file's order (0-based)
  double t1_pose = 0.0;  // times of the trajectory's poses it was scored on
  double t2_pose = 0.0;
  Pose2 estimate;              // the trajectory's displacement between them
  double translation_m = 0.0;  // distance between its translation and the relation's
  double rotation_deg = 0.0;   // absolute difference of the angles
};

struct RelationsScore {
  size_t relations = 0;  // in the file
  size_t used = 0;       // with a trajectory pose within the time tolerance at both ends
  ErrorStatistics translation_m;
  ErrorStatistics rotation_deg;
  std::vector<RelationError> errors;  // each relation used, in the file's order
};

/// Scores `trajectory` (times strictly increasing) on `relations`. With no relation used, the
/// statistics are zero and `used` says so.
RelationsScore ScoreRelations(const std::vector<TimedPose>& trajectory,
                              const std::vector<Relation>& relations,
                              double time_tolerance_s = 0.1);

/// The score as the replay JSON's `relations` object (docs/design.md section 8): count (used),
/// relations (in the file), time_tolerance_s, translational_m and rotational_deg, each with
/// mean, std, squared_mean, squared_std.
nlohmann::json RelationsToJson(const RelationsScore& score, double time_tolerance_s = 0.1);

/// Each relation the trajectory was scored on, one per line, as tab-separated text with a '#'
/// header naming the columns (docs/design.md section 8): the relation (t1, t2, x, y, yaw in
/// degrees), the poses' times, the trajectory's displacement and its errors, and the same for
/// `odometry` (a score of the same relations; "nan" where it left one out).
std::string RelationErrorsText(const std::vector<Relation>& relations, const RelationsScore& score,
                               const RelationsScore& odometry);

}  // namespace slam::offline
