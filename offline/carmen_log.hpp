#pragma once
// CARMEN text logs (the format of the classic 2D SLAM data sets: Intel lab, FR079, MIT CSAIL...):
// the records this project uses, parsed line by line.
//
//   ODOM x y theta tv rv accel timestamp hostname logger_timestamp
//   FLASER n r1..rn [x y theta odom_x odom_y odom_theta] timestamp hostname logger_timestamp
//   RLASER (as FLASER: the rear laser)
//   RAWLASER1..4 type start_angle fov resolution max_range accuracy remission_mode
//                n r1..rn m e1..em timestamp hostname logger_timestamp
//   ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode
//                n r1..rn m e1..em laser_x laser_y laser_theta robot_x robot_y robot_theta
//                tv rv forward_safety side_safety turn_axis timestamp hostname logger_timestamp
//   PARAM name value [hostname timestamp ...]
//
// Angles in radians, distances in metres, times in seconds (the record's own timestamp, the one
// before the host name, is used). The same rules for bad input as the CAN logs: a line that does
// not parse (wrong field count, a non-number, a non-finite value) is counted and skipped, and
// the first few are kept as "file:line: detail" messages; message types this project does not
// use (TRUEPOS, SONAR, NMEA, ...) and comment lines ('#') are counted and skipped. So is a record
// beyond the bounds below (too many readings, a pose too far away, a line too long): a file
// costs memory for what it holds, never for what it claims.

#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "engine/pose.hpp"
#include "engine/result.hpp"

namespace slam::offline {

/// Bounds of what a record may hold; a line beyond them is malformed (counted, skipped, named).
/// Readings (or remissions) in one record: 65 536, ten times the densest 2D scanner's sweep (a
/// SICK LMS5xx at 1/24 degree gives 4 561 beams, a slowly turning RPLIDAR S2 about 6 400), so
/// that one record's scan stays within 3 MiB (a reading becomes a 48-byte ScanSample).
inline constexpr size_t kCarmenMaxReadings = 65536;
/// Bytes in one line: room for kCarmenMaxReadings readings and as many remissions at 32 bytes
/// each. A longer line is never held whole (LoadCarmenLog reads the file line by line).
inline constexpr size_t kCarmenMaxLineBytes = size_t{4} << 20;
/// A pose's coordinates (odometry, laser and robot poses): 10 000 km from the origin, beyond
/// any robot's run (and any UTM coordinate), far within what the engine's arithmetic keeps
/// exact to the micrometre. Angles: a million radians (160 000 turns, for an odometry that
/// never wraps its heading).
inline constexpr double kCarmenMaxPoseM = 1e7;
inline constexpr double kCarmenMaxAngleRad = 1e6;

struct CarmenOdometry {
  size_t line = 0;
  double t = 0.0;
  Pose2 pose;       // accumulated odometry
  double tv = 0.0;  // translational and rotational velocity, when logged
  double rv = 0.0;
};

/// The beam geometry a RAWLASER / ROBOTLASER1 record carries (FLASER / RLASER do not).
struct CarmenBeams {
  int laser_type = 0;  // CARMEN's: 0 SICK LMS, 1 SICK PLS, 2 Hokuyo URG, 3 simulated, 4 SICK S300
  double start_angle_rad = 0.0;
  double fov_rad = 0.0;
  double resolution_rad = 0.0;
  double max_range_m = 0.0;
  double accuracy_m = 0.0;
};

struct CarmenLaser {
  size_t line = 0;
  std::string message;  // FLASER, RLASER, RAWLASER1..4, ROBOTLASER1
  double t = 0.0;
  std::vector<float> ranges;
  std::optional<CarmenBeams> beams;
  /// The robot's odometry at the scan and the laser's pose in the same frame, when the record
  /// carries them (FLASER / RLASER with poses, ROBOTLASER1).
  std::optional<Pose2> robot_odometry;
  std::optional<Pose2> laser_pose;
};

struct CarmenCounters {
  uint64_t lines = 0;
  uint64_t comments = 0;       // '#' lines and blank lines
  uint64_t bad_lines = 0;      // malformed records, skipped
  uint64_t ignored_lines = 0;  // well-formed lines of message types this project does not use
  uint64_t odometry = 0;
  uint64_t lasers = 0;
  uint64_t params = 0;
  std::map<std::string, uint64_t> ignored_messages;  // per message type
};

struct CarmenLog {
  std::string source;
  std::vector<CarmenOdometry> odometry;  // in file order
  std::vector<CarmenLaser> lasers;       // in file order
  std::map<std::string, std::string> params;
  CarmenCounters counters;
  std::vector<std::string> problems;  // the first bad lines, "file:line: detail"
};

/// Parses CARMEN log text; `source` names the input in messages. Fails only when the text holds
/// no laser record at all (the errors then include the first bad lines).
Result<CarmenLog> ParseCarmenLog(std::string_view text, const std::string& source);

/// Reads and parses a CARMEN log file, line by line (never more than one line of at most
/// kCarmenMaxLineBytes in memory besides the records kept).
Result<CarmenLog> LoadCarmenLog(const std::string& path);

/// True when `path` looks like a CARMEN log rather than an experiment directory: a regular file
/// whose first record line starts with a CARMEN message name.
bool LooksLikeCarmenLog(const std::string& path);

}  // namespace slam::offline
