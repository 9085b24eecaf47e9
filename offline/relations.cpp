#include "offline/relations.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "engine/io/text_fields.hpp"

namespace slam::offline {
namespace {

/// The trajectory's pose nearest in time to `t` when within `tolerance`.
const TimedPose* NearestPose(const std::vector<TimedPose>& trajectory, double t, double tolerance) {
  const auto after = std::lower_bound(trajectory.begin(), trajectory.end(), t,
                                      [](const TimedPose& p, double time) { return p.t < time; });
  const TimedPose* best = nullptr;
  if (after != trajectory.end()) best = &*after;
  if (after != trajectory.begin()) {
    const TimedPose& before = *std::prev(after);
    if (best == nullptr || t - before.t <= best->t - t) best = &before;
  }
  if (best == nullptr || std::abs(best->t - t) > tolerance) return nullptr;
  return best;
}

ErrorStatistics Statistics(const std::vector<double>& errors) {
  ErrorStatistics s;
  if (errors.empty()) return s;
  const double n = static_cast<double>(errors.size());
  for (double e : errors) {
    s.mean += e;
    s.squared_mean += e * e;
  }
  s.mean /= n;
  s.squared_mean /= n;
  double var = 0.0, squared_var = 0.0;
  for (double e : errors) {
    var += (e - s.mean) * (e - s.mean);
    squared_var += (e * e - s.squared_mean) * (e * e - s.squared_mean);
  }
  s.std_dev = std::sqrt(var / n);
  s.squared_std_dev = std::sqrt(squared_var / n);
  return s;
}

nlohmann::json StatisticsJson(const ErrorStatistics& s) {
  return {{"mean", s.mean},
          {"std", s.std_dev},
          {"squared_mean", s.squared_mean},
          {"squared_std", s.squared_std_dev}};
}

}  // namespace

Result<std::vector<Relation>> ParseRelations(std::string_view text, const std::string& source) {
  std::vector<Relation> relations;
  io::LineProblems problems(source);
  io::ForEachLine(text, [&](size_t line_number, std::string_view line) {
    const auto fields = io::SplitFields(line);
    if (fields.empty() || fields[0].front() == '#') return;
    if (fields.size() != 8) {
      problems.Add(line_number, "expected 8 fields \"t1 t2 x y z roll pitch yaw\", found " +
                                    std::to_string(fields.size()));
      return;
    }
    double v[8];
    for (size_t i = 0; i < 8; ++i) {
      if (!io::ParseFiniteDouble(fields[i], v[i])) {
        problems.Add(line_number, "field " + std::to_string(i + 1) + " \"" +
                                      std::string(fields[i]) + "\" is not a finite number");
        return;
      }
    }
    relations.push_back({v[0], v[1], Pose2{v[2], v[3], NormalizeAngle(v[7])}});
  });
  if (!problems.empty()) return Result<std::vector<Relation>>(problems.Errors(), source);
  if (relations.empty()) return Error(source + ": no relation in the file");
  return relations;
}

Result<std::vector<Relation>> LoadRelations(const std::string& path) {
  Result<std::string> text = io::ReadTextFile(path);
  if (!text.ok()) return {text.errors(), path};
  return ParseRelations(text.value(), path);
}

RelationsScore ScoreRelations(const std::vector<TimedPose>& trajectory,
                              const std::vector<Relation>& relations, double time_tolerance_s) {
  RelationsScore score;
  score.relations = relations.size();
  std::vector<double> translation, rotation;
  for (const Relation& relation : relations) {
    const TimedPose* first = NearestPose(trajectory, relation.t1, time_tolerance_s);
    const TimedPose* second = NearestPose(trajectory, relation.t2, time_tolerance_s);
    if (first == nullptr || second == nullptr) continue;
    RelationError error;
    error.index = static_cast<size_t>(&relation - relations.data());
    error.t1_pose = first->t;
    error.t2_pose = second->t;
    error.estimate = Between(first->pose, second->pose);
    error.translation_m =
        std::hypot(error.estimate.x - relation.motion.x, error.estimate.y - relation.motion.y);
    error.rotation_deg =
        RadToDeg(std::abs(NormalizeAngle(error.estimate.theta - relation.motion.theta)));
    translation.push_back(error.translation_m);
    rotation.push_back(error.rotation_deg);
    score.errors.push_back(error);
  }
  score.used = translation.size();
  score.translation_m = Statistics(translation);
  score.rotation_deg = Statistics(rotation);
  return score;
}

nlohmann::json RelationsToJson(const RelationsScore& score, double time_tolerance_s) {
  return {{"count", score.used},
          {"relations", score.relations},
          {"time_tolerance_s", time_tolerance_s},
          {"translational_m", StatisticsJson(score.translation_m)},
          {"rotational_deg", StatisticsJson(score.rotation_deg)}};
}

std::string RelationErrorsText(const std::vector<Relation>& relations, const RelationsScore& score,
                               const RelationsScore& odometry) {
  std::string text =
      "# t1\tt2\tx\ty\tyaw_deg\tpose_t1\tpose_t2\test_x\test_y\test_yaw_deg\t"
      "translational_m\trotational_deg\todom_x\todom_y\todom_yaw_deg\todom_translational_m\t"
      "odom_rotational_deg\n";
  size_t k = 0;  // odometry's errors, in the same order
  for (const RelationError& e : score.errors) {
    const Relation& r = relations.at(e.index);
    while (k < odometry.errors.size() && odometry.errors[k].index < e.index) ++k;
    const RelationError* odom = k < odometry.errors.size() && odometry.errors[k].index == e.index
                                    ? &odometry.errors[k]
                                    : nullptr;
    const double nan = std::nan("");
    // Sized by a first pass: a relations file may hold any finite number, 1e300 included, and
    // a fixed buffer would cut such a line.
    const auto format = [&](char* out, size_t size) {
      return std::snprintf(
          out, size,
          "%.6f\t%.6f\t%.4f\t%.4f\t%.3f\t%.6f\t%.6f\t%.4f\t%.4f\t%.3f\t%.4f\t%.3f\t%.4f\t%.4f\t"
          "%.3f\t%.4f\t%.3f\n",
          r.t1, r.t2, r.motion.x, r.motion.y, RadToDeg(r.motion.theta), e.t1_pose, e.t2_pose,
          e.estimate.x, e.estimate.y, RadToDeg(e.estimate.theta), e.translation_m, e.rotation_deg,
          odom ? odom->estimate.x : nan, odom ? odom->estimate.y : nan,
          odom ? RadToDeg(odom->estimate.theta) : nan, odom ? odom->translation_m : nan,
          odom ? odom->rotation_deg : nan);
    };
    const size_t length = static_cast<size_t>(format(nullptr, 0));
    const size_t at = text.size();
    text.resize(at + length + 1);  // snprintf writes a terminating NUL
    format(text.data() + at, length + 1);
    text.resize(at + length);
  }
  return text;
}

}  // namespace slam::offline
