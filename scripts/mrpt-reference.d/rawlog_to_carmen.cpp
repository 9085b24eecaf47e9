// A data conversion, not part of slamd: an MRPT rawlog of action/observation pairs (odometry
// increments and 2D laser scans) as a CARMEN text log of ODOM and ROBOTLASER1 records, which the
// project's tools read. The laser's place on the robot goes into each record's laser pose, its
// beams into the record's start angle, field of view and resolution.
//
// usage: rawlog_to_carmen IN.rawlog OUT.clf

#include <mrpt/obs/CActionCollection.h>
#include <mrpt/obs/CActionRobotMovement2D.h>
#include <mrpt/obs/CObservation2DRangeScan.h>
#include <mrpt/obs/CRawlog.h>
#include <mrpt/obs/CSensoryFrame.h>
#include <mrpt/poses/CPose2D.h>
#include <mrpt/system/datetime.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <string>

int main(int argc, char** argv) {
  if (argc != 3) {
    std::cerr << "usage: rawlog_to_carmen IN.rawlog OUT.clf\n";
    return 2;
  }
  mrpt::obs::CRawlog rawlog;
  if (!rawlog.loadFromRawLogFile(argv[1])) {
    std::cerr << argv[1] << ": cannot read the rawlog\n";
    return 1;
  }
  FILE* out = std::fopen(argv[2], "w");
  if (out == nullptr) {
    std::cerr << argv[2] << ": cannot write\n";
    return 1;
  }
  std::fprintf(
      out,
      "# Converted from the MRPT rawlog \"%s\" by scripts/mrpt-reference.d/rawlog_to_carmen.\n"
      "# ODOM x y theta tv rv accel timestamp hostname logger_timestamp\n"
      "# ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n "
      "r1..rn 0 laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv "
      "forward_safety side_safety turn_axis timestamp hostname logger_timestamp\n",
      std::filesystem::path(argv[1]).filename().c_str());
  mrpt::poses::CPose2D odometry;  // accumulated from the increments
  size_t scans = 0, moves = 0;
  for (size_t i = 0; i < rawlog.size(); ++i) {
    if (rawlog.getType(i) == mrpt::obs::CRawlog::etActionCollection) {
      const auto actions = rawlog.getAsAction(i);
      const auto move = actions->getBestMovementEstimation();
      if (!move) continue;
      odometry = odometry + (move->estimationMethod == mrpt::obs::CActionRobotMovement2D::emOdometry
                                 ? move->rawOdometryIncrementReading
                                 : move->poseChange->getMeanVal());
      ++moves;
      continue;
    }
    if (rawlog.getType(i) != mrpt::obs::CRawlog::etSensoryFrame) continue;
    const auto frame = rawlog.getAsObservations(i);
    const auto scan = frame->getObservationByClass<mrpt::obs::CObservation2DRangeScan>();
    if (!scan) continue;
    const double t = mrpt::Clock::toDouble(scan->timestamp);
    const size_t n = scan->getScanSize();
    const double step = n > 1 ? scan->aperture / static_cast<double>(n - 1) : 0.0;
    const double start = scan->rightToLeft ? -scan->aperture / 2.0 : scan->aperture / 2.0;
    const double resolution = scan->rightToLeft ? step : -step;
    const mrpt::poses::CPose2D mount(scan->sensorPose);
    const mrpt::poses::CPose2D laser = odometry + mount;
    std::fprintf(out, "ODOM %.6f %.6f %.6f 0 0 0 %.6f mrpt %.6f\n", odometry.x(), odometry.y(),
                 odometry.phi(), t, t);
    std::fprintf(out, "ROBOTLASER1 0 %.9f %.9f %.9f %.3f 0.01 0 %zu", start, scan->aperture,
                 resolution, scan->maxRange, n);
    for (size_t k = 0; k < n; ++k) {
      // No return: a reading at the maximum range, as a SICK reports it.
      const float r = scan->getScanRangeValidity(k) ? scan->getScanRange(k) : scan->maxRange;
      std::fprintf(out, " %.3f", static_cast<double>(r));
    }
    std::fprintf(out, " 0 %.6f %.6f %.6f %.6f %.6f %.6f 0 0 0 0 0 %.6f mrpt %.6f\n", laser.x(),
                 laser.y(), laser.phi(), odometry.x(), odometry.y(), odometry.phi(), t, t);
    ++scans;
  }
  std::fclose(out);
  std::fprintf(stderr, "%s: %zu scans, %zu odometry increments\n", argv[2], scans, moves);
  return scans > 0 ? 0 : 1;
}
