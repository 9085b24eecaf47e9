// CARMEN logs as experiments (experiment_reader.hpp): the front laser's records become scans.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <map>
#include <utility>

#include "engine/io/text_fields.hpp"
#include "engine/odometry.hpp"
#include "engine/sensor_model.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/statistics.hpp"

namespace slam::offline {
namespace {

constexpr double kLargestRangeM = kRangeRawMax * kRangeRawM;

bool IsFrontLaser(const std::string& message) {
  return message == "FLASER" || message == "RAWLASER1" || message == "ROBOTLASER1";
}

/// The front laser's message type the log has most of (a log may carry one laser twice, as
/// FLASER and ROBOTLASER1); empty when it has none.
std::string FrontMessage(const CarmenLog& log) {
  std::map<std::string, size_t> count;
  for (const CarmenLaser& laser : log.lasers) {
    if (IsFrontLaser(laser.message)) ++count[laser.message];
  }
  std::string best;
  for (const auto& [message, n] : count) {
    if (best.empty() || n > count[best]) best = message;
  }
  return best;
}

std::optional<double> ParamNumber(const CarmenLog& log, const std::string& key) {
  const auto it = log.params.find(key);
  if (it == log.params.end()) return std::nullopt;
  double value = 0.0;
  if (!io::ParseFiniteDouble(it->second, value)) return std::nullopt;
  return value;
}

std::string LaserTypeName(int type) {
  switch (type) {
    case 0:
      return "SICK LMS";
    case 1:
      return "SICK PLS";
    case 2:
      return "Hokuyo URG";
    case 3:
      return "simulated laser";
    case 4:
      return "SICK S300";
    default:
      return "laser";
  }
}

BeamPattern FlaserBeams(const CarmenLog& log, int n) {
  // The old FLASER records carry ranges only. CARMEN's convention: the field of view is centred
  // ahead and the first beam is on its right edge. The field is PARAM laser_front_laser_fov
  // where the log has it; else 100 degrees for 400 or 401 beams (a SICK LMS in its 100-degree
  // mode, 0.25 degree apart, as CARMEN's own reader guesses from the count: spread over 180
  // degrees they would be 1.8 times too far apart), else 180. The beams are PARAM
  // laser_front_laser_resolution apart where the log has it, 0.25 degree for the 100-degree
  // mode, else spread evenly from edge to edge.
  const bool lms_100 = n == 400 || n == 401;
  const std::optional<double> fov_param = ParamNumber(log, "laser_front_laser_fov");
  const std::optional<double> resolution = ParamNumber(log, "laser_front_laser_resolution");
  const double fov = fov_param.value_or(lms_100 ? 100.0 : 180.0);
  double increment = n > 1 ? fov / (n - 1) : 0.0;
  if (resolution && *resolution > 0.0) {
    increment = *resolution;
  } else if (lms_100 && !fov_param) {
    increment = 0.25;
  }
  return {-fov / 2.0, increment, n};
}

/// The robot's odometry between ODOM records: those whose time is after the previous kept one,
/// interpolated linearly (the angle the short way round).
class OdometryTrack {
 public:
  explicit OdometryTrack(const std::vector<CarmenOdometry>& records) {
    for (const CarmenOdometry& r : records) {
      if (track_.empty() || r.t > track_.back().t) track_.push_back({r.t, r.pose});
    }
  }
  std::optional<Pose2> At(double t) const {
    if (track_.empty() || t < track_.front().t || t > track_.back().t) return std::nullopt;
    const auto after = std::lower_bound(track_.begin(), track_.end(), t,
                                        [](const TimedPose& p, double time) { return p.t < time; });
    if (after->t == t || after == track_.begin()) return after->pose;
    const TimedPose& before = *std::prev(after);
    return Interpolate(before.pose, after->pose, (t - before.t) / (after->t - before.t));
  }

 private:
  std::vector<TimedPose> track_;
};

// CARMEN stamps a record when it arrives, not when it was measured, and bunches records that
// arrive together (the Intel log: 0.60 m of motion between records 0.01 s apart): the odometry's
// plausible step gets this much time beyond the records' own gap (the CAN path, stamped by the
// robot, gets OdometryIntegrator::kJumpSlackS).
constexpr double kCarmenJumpSlackS = 0.5;

// A raw log's laser records put the laser at one place on the robot: this close to their median,
// in at least this share of the records that carry both poses.
constexpr double kMountAgreementM = 0.01;
constexpr double kMountAgreementDeg = 0.5;
constexpr double kMountAgreementShare = 0.99;

std::string MountText(const Pose2& mount) {
  char text[96];
  std::snprintf(text, sizeof(text), "%.3f m ahead, %.3f m left, turned %.1f deg", mount.x, mount.y,
                RadToDeg(mount.theta));
  return text;
}

}  // namespace

CarmenMount DeriveCarmenMount(const CarmenLog& log) {
  const std::optional<double> ahead = ParamNumber(log, "robot_frontlaser_offset");
  const std::optional<double> side = ParamNumber(log, "robot_frontlaser_side_offset");
  const std::optional<double> turned = ParamNumber(log, "robot_frontlaser_angular_offset");
  if (ahead || side || turned) {
    const Pose2 mount{ahead.value_or(0.0), side.value_or(0.0),
                      NormalizeAngle(turned.value_or(0.0))};
    return {mount, "from the log's PARAM robot_frontlaser_* lines"};
  }
  const std::string front = FrontMessage(log);
  std::vector<Pose2> seen;  // the laser in the robot's frame, per record
  for (const CarmenLaser& laser : log.lasers) {
    if (laser.message != front || !laser.laser_pose || !laser.robot_odometry) continue;
    seen.push_back(Between(*laser.robot_odometry, *laser.laser_pose));
  }
  if (seen.empty())
    return {{}, "the log does not say where (no PARAM robot_frontlaser_*, no laser poses)"};
  std::vector<double> xs, ys, cosines, sines;
  for (const Pose2& p : seen) {
    xs.push_back(p.x);
    ys.push_back(p.y);
    cosines.push_back(std::cos(p.theta));
    sines.push_back(std::sin(p.theta));
  }
  const auto median_of = [](std::vector<double> values) {
    return SummarizeFive(std::move(values)).median;
  };
  const Pose2 median{median_of(xs), median_of(ys),
                     std::atan2(median_of(sines), median_of(cosines))};
  size_t agree = 0;
  for (const Pose2& p : seen) {
    agree += std::abs(p.x - median.x) <= kMountAgreementM &&
             std::abs(p.y - median.y) <= kMountAgreementM &&
             std::abs(NormalizeAngle(p.theta - median.theta)) <= DegToRad(kMountAgreementDeg);
  }
  if (static_cast<double>(agree) < kMountAgreementShare * static_cast<double>(seen.size())) {
    return {{},
            "the " + front + " records' laser poses are not one place on the robot (" +
                std::to_string(seen.size() - agree) + " of " + std::to_string(seen.size()) +
                " elsewhere; poses corrected after the run?): a robot.json beside the log "
                "says where it is"};
  }
  // Rounded to the millimetre and the tenth of a degree, far finer than a mount matters, so that
  // a laser on the centre sits on it exactly (+ 0.0: no negative zero to print).
  const auto round_to = [](double value, double step) {
    return std::round(value / step) * step + 0.0;
  };
  const Pose2 mount{round_to(median.x, 0.001), round_to(median.y, 0.001),
                    DegToRad(round_to(RadToDeg(median.theta), 0.1))};
  return {mount, "from the " + front + " records' laser poses against their odometry"};
}

namespace {

/// DeriveCarmenRobot with the laser at `mount` (DeriveCarmenMount's, derived once by the caller).
RobotDescription CarmenRobotAt(const CarmenLog& log, const std::string& name, const Pose2& mount) {
  const std::string front = FrontMessage(log);
  const CarmenLaser* first = nullptr;
  for (const CarmenLaser& laser : log.lasers) {
    if (laser.message == front) {
      first = &laser;
      break;
    }
  }
  RobotDescription robot;
  robot.name = "CARMEN log " + name;
  // CARMEN's ODOM records are the base's dead reckoning, which its base modules (Pioneer, rflex,
  // Segway...) integrate from the wheels' encoders alone: their heading errs per metre driven.
  // A log from a base that fuses a gyro needs a robot description that says so.
  robot.base.heading_from_gyro = false;
  robot.scanner.mount_radius_m = 0.0;
  robot.scanner.offset_x_m = mount.x;
  robot.scanner.offset_y_m = mount.y;
  robot.scanner.sensors = {{"laser", RadToDeg(mount.theta)}};

  SensorTypeDescription type;
  type.kind = SensorKind::kRange;
  const int n = first != nullptr ? static_cast<int>(first->ranges.size()) : 0;
  double max_range = 0.0;  // the records' own, when they say it
  if (first != nullptr && first->beams) {
    type.model = LaserTypeName(first->beams->laser_type);
    type.beams = {RadToDeg(first->beams->start_angle_rad), RadToDeg(first->beams->resolution_rad),
                  n};
    max_range = first->beams->max_range_m;
  } else {
    type.model = "laser";
    type.beams = FlaserBeams(log, n);
  }
  max_range = ParamNumber(log, "robot_front_laser_max").value_or(max_range);

  // The readings: the largest, how often, and the largest below it. A scanner without an echo
  // reports one fixed value (SICK: 81.83 m); readings at the largest value in at least 0.1 % of
  // the beams are taken for that.
  double largest = 0.0, below = 0.0;
  size_t total = 0, at_largest = 0;
  for (const CarmenLaser& laser : log.lasers) {
    if (laser.message != front) continue;
    for (float r : laser.ranges) {
      if (!(r > 0.0f) || !std::isfinite(r)) continue;
      ++total;
      if (r > largest) {
        below = largest;
        largest = r;
        at_largest = 1;
      } else if (r == largest) {
        ++at_largest;
      } else {
        below = std::max<double>(below, r);
      }
    }
  }
  const bool saturates = at_largest >= 2 && at_largest * 1000 >= total;
  double no_return = saturates ? largest : 0.0;
  if (no_return == 0.0 && max_range > 0.0) no_return = max_range;
  double use_max = saturates ? below : largest;
  if (max_range > 0.0) use_max = std::min(use_max, max_range);
  use_max = std::min(use_max, kLargestRangeM);
  if (no_return > 0.0 && use_max >= no_return) use_max = std::nextafter(no_return, 0.0);
  if (!(use_max > 0.02)) use_max = kLargestRangeM;  // a log without readings: anything goes
  type.range_min_m = 0.0;
  type.range_max_m = use_max;
  type.use_min_m = 0.02;
  type.use_max_m = use_max;
  type.no_return_m = no_return > use_max ? no_return : 0.0;
  type.sigma_m = {0.01, 0.005, 0.0};
  robot.sensor_types["laser"] = type;
  return robot;
}

}  // namespace

RobotDescription DeriveCarmenRobot(const CarmenLog& log, const std::string& name) {
  return CarmenRobotAt(log, name, DeriveCarmenMount(log).pose);
}

Result<Experiment> LoadCarmenExperiment(const std::string& path, const CarmenOptions& options) {
  Result<CarmenLog> parsed = LoadCarmenLog(path);
  if (!parsed.ok()) return {parsed.errors(), path};
  return CarmenExperiment(parsed.value(), path, options);
}

Result<Experiment> CarmenExperiment(const CarmenLog& log, const std::string& path,
                                    const CarmenOptions& options) {
  Experiment experiment;
  experiment.dir = path;
  experiment.meta.name = std::filesystem::path(path).stem().string();
  experiment.meta.source = "robot";
  if (options.robot) {
    experiment.robot = *options.robot;
  } else {
    const CarmenMount mount = DeriveCarmenMount(log);
    experiment.robot = CarmenRobotAt(log, experiment.meta.name, mount.pose);
    experiment.notes.push_back("laser " + MountText(mount.pose) + ", " + mount.source);
  }
  ConfigErrors invalid = Validate(experiment.robot);
  if (!invalid.empty()) {
    for (ConfigError& e : invalid) e.detail = "robot for " + path + ": " + e.detail;
    return invalid;
  }
  const ScannerSensor& sensor = experiment.robot.scanner.sensors.front();
  const SensorTypeDescription& type = experiment.robot.sensor_types.at(sensor.type);
  if (type.kind != SensorKind::kRange || experiment.robot.scanner.sensors.size() != 1) {
    return Error(path + ": a CARMEN log needs a robot with one range sensor (\"kind\": \"range\")");
  }

  ExperimentCounters& counters = experiment.counters;
  counters.frames = log.counters.lasers + log.counters.odometry;
  counters.bad_lines = log.counters.bad_lines;
  counters.ignored_lines = log.counters.comments + log.counters.ignored_lines;
  experiment.problems = log.problems;

  const std::string front = FrontMessage(log);
  const OdometryTrack track(log.odometry);
  std::vector<const CarmenLaser*> records;
  for (const CarmenLaser& laser : log.lasers) {
    if (laser.message != front) continue;
    if (laser.ranges.size() != static_cast<size_t>(type.beams.count)) {
      ++counters.bad_lines;
      if (experiment.problems.size() < 20) {
        experiment.problems.push_back(
            path + ":" + std::to_string(laser.line) + ": " + laser.message + " has " +
            std::to_string(laser.ranges.size()) + " readings, the robot's laser " +
            std::to_string(type.beams.count) + " beams");
      }
      continue;
    }
    records.push_back(&laser);
  }

  double t_first = std::numeric_limits<double>::infinity(), t_last = -t_first;
  for (const CarmenLaser& laser : log.lasers) {
    t_first = std::min(t_first, laser.t);
    t_last = std::max(t_last, laser.t);
  }
  for (const CarmenOdometry& odometry : log.odometry) {
    t_first = std::min(t_first, odometry.t);
    t_last = std::max(t_last, odometry.t);
  }

  std::optional<double> last_t;
  Pose2 last_odometry;  // the previous scan's, in the run's odometry frame
  Pose2 last_raw;       // the same, as the log has it
  // The run's odometry frame from the log's: a base that restarts mid-run (its odometry back at
  // zero, or anywhere) would teleport the prior. A step longer than the robot drives in the
  // time between two records (OdometryIntegrator::MaxTravelM, with kCarmenJumpSlackS) is taken
  // for a restart: counted, named, and the pose holds across it.
  Pose2 reset;
  for (size_t k = 0; k < records.size(); ++k) {
    const CarmenLaser& laser = *records[k];
    if (last_t && !(laser.t > *last_t)) {
      ++counters.scans_out_of_order;
      continue;
    }
    const std::optional<Pose2> raw =
        laser.robot_odometry ? laser.robot_odometry : track.At(laser.t);
    if (!raw) {
      ++counters.scans_without_odometry;
      continue;
    }
    if (last_t) {
      const double step_m = std::hypot(raw->x - last_raw.x, raw->y - last_raw.y);
      if (step_m > OdometryIntegrator::MaxTravelM(experiment.robot.base, laser.t - *last_t,
                                                  kCarmenJumpSlackS)) {
        ++counters.assembler.odometry_jumps;
        reset = Compose(last_odometry, Inverse(*raw));
        if (counters.assembler.odometry_jumps <= 20) {
          char text[160];
          std::snprintf(text, sizeof(text),
                        ": the odometry jumps %.2f m in %.3f s (over %.1f m/s): taken for a "
                        "restart of the base, the pose held across it",
                        step_m, laser.t - *last_t, experiment.robot.base.max_speed_m_s);
          experiment.notes.push_back(path + ":" + std::to_string(laser.line) + text);
        }
      }
    }
    last_raw = *raw;
    const Pose2 odometry = Compose(reset, *raw);
    Scan scan;
    scan.index = static_cast<int64_t>(experiment.scans.size());
    scan.t_end = laser.t;
    if (last_t) {
      scan.t_begin = *last_t;
      scan.odom_begin = last_odometry;
    } else {
      // The first scan spans as long as the gap to the next record (the CPU-share quota
      // follows a scan's duration); it moves nothing.
      const double gap = k + 1 < records.size() ? records[k + 1]->t - laser.t : 1.0;
      scan.t_begin = laser.t - std::clamp(gap, 1e-3, 10.0);
      scan.odom_begin = odometry;
    }
    scan.odom_end = odometry;
    scan.samples.resize(laser.ranges.size());
    for (size_t i = 0; i < laser.ranges.size(); ++i) {
      ScanSample& sample = scan.samples[i];
      sample.t = laser.t;
      sample.odom = odometry;
      sample.platform_angle_rad = DegToRad(type.beams.AngleDeg(static_cast<int>(i)));
      sample.raw[0] = RangeToRaw(laser.ranges[i]);
    }
    experiment.scans.push_back(std::move(scan));
    last_t = laser.t;
    last_odometry = odometry;
  }
  experiment.t_first = t_first;
  experiment.t_last = t_last;
  if (experiment.scans.empty()) {
    return Error(path + ": no usable scan: " + std::to_string(records.size()) + " " + front +
                 " records with the robot's " + std::to_string(type.beams.count) + " beams, " +
                 std::to_string(counters.scans_without_odometry) + " without odometry");
  }
  return experiment;
}

}  // namespace slam::offline
