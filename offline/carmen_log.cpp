#include "offline/carmen_log.hpp"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>

#include "engine/io/text_fields.hpp"

namespace slam::offline {
namespace {

constexpr size_t kMaxReadings = 100000;  // far beyond any scanner: a count beyond it is garbage

/// Reads the fields of one record in order; the first failure is kept as the record's problem.
class FieldReader {
 public:
  explicit FieldReader(const std::vector<std::string_view>& fields) : fields_(fields) {}

  bool Number(double& value, const char* what) {
    if (!problem_.empty()) return false;
    if (next_ >= fields_.size()) {
      problem_ = std::string("ends before ") + what;
      return false;
    }
    if (!io::ParseFiniteDouble(fields_[next_], value)) {
      problem_ =
          std::string(what) + " \"" + std::string(fields_[next_]) + "\" is not a finite number";
      return false;
    }
    ++next_;
    return true;
  }
  bool Count(size_t& value, const char* what) {
    double v = 0.0;
    if (!Number(v, what)) return false;
    // The range first: converting a double beyond size_t's range is undefined.
    if (!(v >= 0.0 && v <= static_cast<double>(kMaxReadings)) || v != std::floor(v)) {
      problem_ = std::string(what) + " " + std::string(fields_[next_ - 1]) + " is not a count";
      return false;
    }
    value = static_cast<size_t>(v);
    return true;
  }
  bool Pose(Pose2& pose, const char* what) {
    return Number(pose.x, what) && Number(pose.y, what) && Number(pose.theta, what);
  }
  bool Readings(std::vector<float>& values, size_t n, const char* what) {
    values.resize(n);
    for (size_t i = 0; i < n; ++i) {
      double v = 0.0;
      if (!Number(v, what)) return false;
      if (!(std::abs(v) <= std::numeric_limits<float>::max())) {  // would become infinite
        problem_ = std::string(what) + " " + std::string(fields_[next_ - 1]) + " is out of range";
        return false;
      }
      values[i] = static_cast<float>(v);
    }
    return true;
  }
  bool Skip(size_t n, const char* what) {
    if (!problem_.empty()) return false;
    if (next_ + n > fields_.size()) {
      problem_ = std::string("ends before ") + what;
      return false;
    }
    next_ += n;
    return true;
  }
  size_t left() const { return fields_.size() - next_; }
  const std::string& problem() const { return problem_; }
  void Fail(std::string problem) {
    if (problem_.empty()) problem_ = std::move(problem);
  }

 private:
  const std::vector<std::string_view>& fields_;
  size_t next_ = 1;  // after the message name
  std::string problem_;
};

/// The tail of every record: "timestamp hostname logger_timestamp".
bool Timestamp(FieldReader& in, double& t) {
  if (in.left() != 3) {
    in.Fail("expected \"timestamp hostname logger_timestamp\" at the end, found " +
            std::to_string(in.left()) + " fields");
    return false;
  }
  return in.Number(t, "timestamp") && in.Skip(2, "the host name");
}

bool ParseOdometry(FieldReader& in, CarmenOdometry& odometry) {
  double accel = 0.0;
  return in.Pose(odometry.pose, "the pose") && in.Number(odometry.tv, "tv") &&
         in.Number(odometry.rv, "rv") && in.Number(accel, "accel") && Timestamp(in, odometry.t);
}

/// FLASER / RLASER: "n r1..rn", then either six pose numbers or none, then the timestamp.
bool ParseOldLaser(FieldReader& in, CarmenLaser& laser) {
  size_t n = 0;
  if (!in.Count(n, "the number of readings") || !in.Readings(laser.ranges, n, "a range")) {
    return false;
  }
  if (in.left() == 9) {
    Pose2 laser_pose, odometry;
    if (!in.Pose(laser_pose, "the laser pose") || !in.Pose(odometry, "the odometry pose")) {
      return false;
    }
    laser.laser_pose = laser_pose;
    laser.robot_odometry = odometry;
  }
  return Timestamp(in, laser.t);
}

/// RAWLASERn and ROBOTLASER1's common head: the beams, the ranges and the remissions.
bool ParseNewLaserHead(FieldReader& in, CarmenLaser& laser) {
  CarmenBeams beams;
  double type = 0.0, remission_mode = 0.0;
  size_t n = 0, remissions = 0;
  if (!in.Number(type, "the laser type") || !in.Number(beams.start_angle_rad, "start_angle") ||
      !in.Number(beams.fov_rad, "fov") || !in.Number(beams.resolution_rad, "resolution") ||
      !in.Number(beams.max_range_m, "max_range") || !in.Number(beams.accuracy_m, "accuracy") ||
      !in.Number(remission_mode, "remission_mode") || !in.Count(n, "the number of readings") ||
      !in.Readings(laser.ranges, n, "a range") ||
      !in.Count(remissions, "the number of remissions") || !in.Skip(remissions, "the remissions")) {
    return false;
  }
  if (!(type >= 0.0 && type <= 1000.0) || type != std::floor(type)) {
    in.Fail("the laser type is not a CARMEN laser type number");
    return false;
  }
  beams.laser_type = static_cast<int>(type);
  if (!(beams.resolution_rad > 0.0) && n > 1) {
    in.Fail("the angular resolution is not positive");
    return false;
  }
  laser.beams = beams;
  return true;
}

bool ParseRobotLaser(FieldReader& in, CarmenLaser& laser) {
  Pose2 laser_pose, robot;
  if (!ParseNewLaserHead(in, laser) || !in.Pose(laser_pose, "the laser pose") ||
      !in.Pose(robot, "the robot pose") || !in.Skip(5, "the velocities and safety distances")) {
    return false;
  }
  laser.laser_pose = laser_pose;
  laser.robot_odometry = robot;
  return Timestamp(in, laser.t);
}

bool IsLaserMessage(std::string_view name) {
  return name == "FLASER" || name == "RLASER" || name == "ROBOTLASER1" ||
         (name.size() == 9 && name.substr(0, 8) == "RAWLASER" && name[8] >= '1' && name[8] <= '4');
}

}  // namespace

Result<CarmenLog> ParseCarmenLog(std::string_view text, const std::string& source) {
  CarmenLog log;
  log.source = source;
  CarmenCounters& counters = log.counters;
  io::LineProblems problems(source);
  io::ForEachLine(text, [&](size_t line_number, std::string_view line) {
    ++counters.lines;
    const auto fields = io::SplitFields(line);
    if (fields.empty() || fields[0].front() == '#') {
      ++counters.comments;
      return;
    }
    const std::string_view name = fields[0];
    FieldReader in(fields);
    bool ok = false;
    if (name == "ODOM") {
      CarmenOdometry odometry;
      odometry.line = line_number;
      if ((ok = ParseOdometry(in, odometry))) {
        log.odometry.push_back(odometry);
        ++counters.odometry;
      }
    } else if (IsLaserMessage(name)) {
      CarmenLaser laser;
      laser.line = line_number;
      laser.message = std::string(name);
      ok = name == "FLASER" || name == "RLASER" ? ParseOldLaser(in, laser)
           : name == "ROBOTLASER1"              ? ParseRobotLaser(in, laser)
                                   : ParseNewLaserHead(in, laser) && Timestamp(in, laser.t);
      if (ok) {
        log.lasers.push_back(std::move(laser));
        ++counters.lasers;
      }
    } else if (name == "PARAM") {
      if (fields.size() >= 3) {
        log.params[std::string(fields[1])] = std::string(fields[2]);
        ++counters.params;
        ok = true;
      } else {
        in.Fail("expected \"PARAM name value\"");
      }
    } else {
      ++counters.ignored_lines;
      ++counters.ignored_messages[std::string(name.substr(0, 32))];
      return;
    }
    if (!ok) {
      ++counters.bad_lines;
      problems.Add(line_number, std::string(name.substr(0, 32)) + ": " + in.problem());
    }
  });
  log.problems = problems.kept();
  if (log.lasers.empty()) {
    ConfigErrors errors{{"", source +
                                 ": no laser record (FLASER, RLASER, RAWLASER1-4, "
                                 "ROBOTLASER1) in " +
                                 std::to_string(counters.lines) + " lines (" +
                                 std::to_string(counters.bad_lines) + " malformed)"}};
    for (const std::string& problem : log.problems) errors.push_back({"", problem});
    return Result<CarmenLog>(std::move(errors), source);
  }
  return log;
}

Result<CarmenLog> LoadCarmenLog(const std::string& path) {
  Result<std::string> text = io::ReadTextFile(path);
  if (!text.ok()) return {text.errors(), path};
  return ParseCarmenLog(text.value(), path);
}

bool LooksLikeCarmenLog(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) return false;
  std::ifstream in(path, std::ios::binary);
  std::string line;
  for (int i = 0; i < 1000 && std::getline(in, line); ++i) {
    const auto fields = io::SplitFields(line);
    if (fields.empty() || fields[0].front() == '#') continue;
    return fields[0] == "ODOM" || fields[0] == "PARAM" || IsLaserMessage(fields[0]) ||
           fields[0] == "TRUEPOS";
  }
  return false;
}

}  // namespace slam::offline
