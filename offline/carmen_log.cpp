#include "offline/carmen_log.hpp"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <optional>

#include "engine/io/text_fields.hpp"

namespace slam::offline {
namespace {

/// The fields of one line, separated by spaces, tabs or carriage returns, read in order without
/// a copy (a record of many beams is one long line: a vector of its fields would cost four times
/// the line).
class FieldCursor {
 public:
  explicit FieldCursor(std::string_view line) : line_(line) {
    for (size_t i = 0; i < line_.size();) {
      while (i < line_.size() && Blank(line_[i])) ++i;
      if (i == line_.size()) break;
      ++count_;
      while (i < line_.size() && !Blank(line_[i])) ++i;
    }
  }
  size_t count() const { return count_; }
  size_t taken() const { return taken_; }
  /// The next field; precondition: taken() < count().
  std::string_view Next() {
    while (Blank(line_[pos_])) ++pos_;
    const size_t start = pos_;
    while (pos_ < line_.size() && !Blank(line_[pos_])) ++pos_;
    ++taken_;
    return line_.substr(start, pos_ - start);
  }

 private:
  static bool Blank(char c) { return c == ' ' || c == '\t' || c == '\r'; }

  std::string_view line_;
  size_t pos_ = 0;
  size_t count_ = 0;
  size_t taken_ = 0;
};

/// Reads the fields of one record in order (after its message name); the first failure is kept
/// as the record's problem.
class FieldReader {
 public:
  explicit FieldReader(FieldCursor& fields) : fields_(fields) {}

  bool Number(double& value, const char* what) {
    if (!problem_.empty()) return false;
    if (fields_.taken() >= fields_.count()) {
      problem_ = std::string("ends before ") + what;
      return false;
    }
    last_ = fields_.Next();
    if (!io::ParseFiniteDouble(last_, value)) {
      problem_ = std::string(what) + " \"" + std::string(last_.substr(0, 64)) +
                 "\" is not a finite number";
      return false;
    }
    return true;
  }
  bool Count(size_t& value, const char* what) {
    double v = 0.0;
    if (!Number(v, what)) return false;
    // The range first: converting a double beyond size_t's range is undefined.
    if (!(v >= 0.0 && v <= 0x1p53) || v != std::floor(v)) {
      problem_ = std::string(what) + " " + std::string(last_) + " is not a count";
      return false;
    }
    if (v > static_cast<double>(kCarmenMaxReadings)) {
      problem_ = std::string(what) + " " + std::string(last_) + " is more than " +
                 std::to_string(kCarmenMaxReadings) + " (no laser scanner has so many beams)";
      return false;
    }
    value = static_cast<size_t>(v);
    return true;
  }
  bool Pose(Pose2& pose, const char* what) {
    if (!Number(pose.x, what) || !Number(pose.y, what) || !Number(pose.theta, what)) return false;
    if (!(std::abs(pose.x) <= kCarmenMaxPoseM && std::abs(pose.y) <= kCarmenMaxPoseM)) {
      char text[160];
      std::snprintf(text, sizeof(text), " (%g, %g) is beyond %g m of the origin", pose.x, pose.y,
                    kCarmenMaxPoseM);
      problem_ = what + std::string(text);
      return false;
    }
    if (!(std::abs(pose.theta) <= kCarmenMaxAngleRad)) {
      char text[160];
      std::snprintf(text, sizeof(text), "'s angle %g is beyond %g rad", pose.theta,
                    kCarmenMaxAngleRad);
      problem_ = what + std::string(text);
      return false;
    }
    return true;
  }
  bool Readings(std::vector<float>& values, size_t n, const char* what) {
    if (!problem_.empty()) return false;
    if (n > left()) {  // before allocating for them
      problem_ = std::string("ends before ") + what + " (" + std::to_string(n) + " announced, " +
                 std::to_string(left()) + " fields left)";
      return false;
    }
    values.resize(n);
    for (size_t i = 0; i < n; ++i) {
      double v = 0.0;
      if (!Number(v, what)) return false;
      if (!(std::abs(v) <= std::numeric_limits<float>::max())) {  // would become infinite
        problem_ = std::string(what) + " " + std::string(last_) + " is out of range";
        return false;
      }
      values[i] = static_cast<float>(v);
    }
    return true;
  }
  bool Skip(size_t n, const char* what) {
    if (!problem_.empty()) return false;
    if (n > left()) {
      problem_ = std::string("ends before ") + what;
      return false;
    }
    for (size_t i = 0; i < n; ++i) fields_.Next();
    return true;
  }
  size_t left() const { return fields_.count() - fields_.taken(); }
  const std::string& problem() const { return problem_; }
  void Fail(std::string problem) {
    if (problem_.empty()) problem_ = std::move(problem);
  }

 private:
  FieldCursor& fields_;
  std::string_view last_;
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

/// The records of a log, one line at a time (ParseCarmenLog's text, LoadCarmenLog's file).
class CarmenParser {
 public:
  explicit CarmenParser(const std::string& source) : problems_(source) { log_.source = source; }

  void Line(size_t line_number, std::string_view line) {
    if (line.size() > kCarmenMaxLineBytes) {
      TooLong(line_number);
      return;
    }
    CarmenCounters& counters = log_.counters;
    ++counters.lines;
    FieldCursor fields(line);
    if (fields.count() == 0) {
      ++counters.comments;
      return;
    }
    const std::string_view name = fields.Next();
    if (name.front() == '#') {
      ++counters.comments;
      return;
    }
    FieldReader in(fields);
    bool ok = false;
    if (name == "ODOM") {
      CarmenOdometry odometry;
      odometry.line = line_number;
      if ((ok = ParseOdometry(in, odometry))) {
        log_.odometry.push_back(odometry);
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
        log_.lasers.push_back(std::move(laser));
        ++counters.lasers;
      }
    } else if (name == "PARAM") {
      if (fields.count() >= 3) {
        const std::string_view key = fields.Next();
        log_.params[std::string(key)] = std::string(fields.Next());
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
      problems_.Add(line_number, std::string(name.substr(0, 32)) + ": " + in.problem());
    }
  }

  /// A line longer than kCarmenMaxLineBytes (not read whole): counted as malformed and named.
  void TooLong(size_t line_number) {
    ++log_.counters.lines;
    ++log_.counters.bad_lines;
    problems_.Add(line_number, "longer than " + std::to_string(kCarmenMaxLineBytes) +
                                   " bytes (no record of at most " +
                                   std::to_string(kCarmenMaxReadings) + " readings is): skipped");
  }

  Result<CarmenLog> Finish() && {
    const CarmenCounters& counters = log_.counters;
    log_.problems = problems_.kept();
    if (log_.lasers.empty()) {
      ConfigErrors errors{{"", log_.source +
                                   ": no laser record (FLASER, RLASER, RAWLASER1-4, "
                                   "ROBOTLASER1) in " +
                                   std::to_string(counters.lines) + " lines (" +
                                   std::to_string(counters.bad_lines) + " malformed)"}};
      for (const std::string& problem : log_.problems) errors.push_back({"", problem});
      return Result<CarmenLog>(std::move(errors), log_.source);
    }
    return std::move(log_);
  }

 private:
  CarmenLog log_;
  io::LineProblems problems_;
};

/// Calls line(number, text) for each line of the file `in` (numbered from 1), and too_long(number)
/// instead for a line longer than kCarmenMaxLineBytes, which is never held whole: memory stays
/// within one line of at most that many bytes, whatever the file. False on a read error.
template <typename Line, typename TooLong>
bool ForEachFileLine(std::FILE* in, Line&& line, TooLong&& too_long) {
  std::vector<char> block(1 << 16);
  std::string current;
  size_t number = 0;
  bool overlong = false;  // the current line passed the bound: skipped to its end
  while (true) {
    const size_t n = std::fread(block.data(), 1, block.size(), in);
    if (n == 0) break;
    std::string_view rest(block.data(), n);
    while (!rest.empty()) {
      const size_t newline = rest.find('\n');
      const std::string_view piece = rest.substr(0, newline);
      if (!overlong) {
        if (current.size() + piece.size() > kCarmenMaxLineBytes) {
          overlong = true;
          std::string().swap(current);
        } else {
          current.append(piece);
        }
      }
      if (newline == std::string_view::npos) break;
      ++number;
      if (overlong) {
        too_long(number);
      } else {
        line(number, std::string_view(current));
      }
      current.clear();
      overlong = false;
      rest.remove_prefix(newline + 1);
    }
  }
  if (std::ferror(in)) return false;
  // The last line may lack its newline.
  if (overlong) {
    too_long(++number);
  } else if (!current.empty()) {
    line(++number, std::string_view(current));
  }
  return true;
}

/// The file at `path` opened for reading, or an error naming it.
Result<std::FILE*> OpenLog(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    return Result<std::FILE*>(ConfigErrors{{"", path + ": is a directory, not a file"}}, path);
  }
  std::FILE* in = std::fopen(path.c_str(), "rb");
  if (in == nullptr) {
    const int error = errno;
    return Result<std::FILE*>(
        ConfigErrors{{"", path + ": cannot open (" + std::strerror(error) + ")"}}, path);
  }
  return in;
}

}  // namespace

Result<CarmenLog> ParseCarmenLog(std::string_view text, const std::string& source) {
  CarmenParser parser(source);
  io::ForEachLine(
      text, [&](size_t line_number, std::string_view line) { parser.Line(line_number, line); });
  return std::move(parser).Finish();
}

Result<CarmenLog> LoadCarmenLog(const std::string& path) {
  Result<std::FILE*> opened = OpenLog(path);
  if (!opened.ok()) return {opened.errors(), path};
  std::FILE* in = opened.value();
  CarmenParser parser(path);
  const bool read = ForEachFileLine(
      in, [&](size_t number, std::string_view line) { parser.Line(number, line); },
      [&](size_t number) { parser.TooLong(number); });
  std::fclose(in);
  if (!read) return Result<CarmenLog>(ConfigErrors{{"", path + ": read error"}}, path);
  return std::move(parser).Finish();
}

bool LooksLikeCarmenLog(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) return false;
  Result<std::FILE*> opened = OpenLog(path);
  if (!opened.ok()) return false;
  std::FILE* in = opened.value();
  // The first record line's first field decides, read from at most the first 1000 lines and
  // kHead bytes of each (a message name is far shorter): no line is ever held whole, nor read
  // further than its head unless it is a comment.
  constexpr size_t kHead = 64;
  std::optional<bool> verdict;
  std::string head;
  bool skipping = false;  // a comment or blank head: on to the next line
  int lines = 0;
  // The verdict on a line's head, if it has a record's name (complete: `whole` line, or a blank
  // after it).
  const auto decide = [&](bool whole) {
    FieldCursor fields(head);
    if (fields.count() == 0) return;
    const std::string_view name = fields.Next();
    if (name.front() == '#') return;
    if (!whole && name.end() == head.data() + head.size()) {
      verdict = false;  // longer than any message name
      return;
    }
    verdict = name == "ODOM" || name == "PARAM" || IsLaserMessage(name) || name == "TRUEPOS";
  };
  for (int c = std::getc(in); c != EOF && !verdict && lines < 1000; c = std::getc(in)) {
    if (c == '\n') {
      if (!skipping) decide(true);
      ++lines;
      head.clear();
      skipping = false;
    } else if (!skipping) {
      head.push_back(static_cast<char>(c));
      if (head.size() == kHead) {
        decide(false);
        skipping = true;
      }
    }
  }
  if (!verdict && !skipping && lines < 1000) decide(true);  // a last line without its newline
  std::fclose(in);
  return verdict.value_or(false);
}

}  // namespace slam::offline
