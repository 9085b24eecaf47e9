// A reference, not part of slamd: MRPT's Rao-Blackwellised particle filter (CMetricMapBuilderRBPF,
// Debian's libmrpt-slam) on a CARMEN log whose FLASER records carry their odometry (as the Intel
// copy in ../shared/data/intel does), one pose per laser record written as TUM, so that
// slam-relations scores it as it scores our replays. scripts/mrpt-reference builds and runs it.
//
// usage: rbpf_on_carmen CONFIG.ini LOG.clf OUT.tum SEED
// The config's [MappingApplication] section is read as MRPT's rbpf-slam reads it. Writes OUT.tum,
// OUT.tum.json (records read, CPU time) and, when the config builds a points map (the ICP-based
// one does), OUT.tum.points: the most likely particle's map, one "x y" per line, to draw.

#include <mrpt/config/CConfigFile.h>
#include <mrpt/maps/CMultiMetricMap.h>
#include <mrpt/maps/CSimplePointsMap.h>
#include <mrpt/obs/CActionCollection.h>
#include <mrpt/obs/CActionRobotMovement2D.h>
#include <mrpt/obs/CObservation2DRangeScan.h>
#include <mrpt/obs/CSensoryFrame.h>
#include <mrpt/poses/CPose2D.h>
#include <mrpt/random.h>
#include <mrpt/slam/CMetricMapBuilderRBPF.h>
#include <mrpt/system/datetime.h>

#include <cmath>
#include <cstdio>
#include <ctime>
#include <deque>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

namespace {

struct Record {
  double t = 0.0;
  mrpt::poses::CPose2D odometry;
  std::vector<float> ranges;
};

// The FLASER records with poses: "FLASER n r1..rn x y theta odom_x odom_y odom_theta t host t".
std::vector<Record> ReadFlaser(const std::string& path, size_t& skipped) {
  std::vector<Record> records;
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream fields(line);
    std::string kind;
    int n = 0;
    if (!(fields >> kind) || kind != "FLASER" || !(fields >> n) || n <= 0) continue;
    Record r;
    r.ranges.resize(static_cast<size_t>(n));
    for (float& range : r.ranges) fields >> range;
    double lx, ly, lt, ox, oy, ot;
    if (!(fields >> lx >> ly >> lt >> ox >> oy >> ot >> r.t)) {
      ++skipped;
      continue;
    }
    r.odometry = mrpt::poses::CPose2D(ox, oy, ot);
    records.push_back(std::move(r));
  }
  return records;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 5) {
    std::cerr << "usage: rbpf_on_carmen CONFIG.ini LOG.clf OUT.tum SEED\n";
    return 2;
  }
  const std::string config_path = argv[1], log_path = argv[2], out_path = argv[3];
  size_t skipped = 0;
  const std::vector<Record> records = ReadFlaser(log_path, skipped);
  if (records.empty()) {
    std::cerr << log_path << ": no FLASER record with poses\n";
    return 1;
  }

  mrpt::config::CConfigFile config(config_path);
  mrpt::slam::CMetricMapBuilderRBPF::TConstructionOptions options;
  options.loadFromConfigFile(config, "MappingApplication");
  options.mapsInitializers.loadFromConfigFile(config, "MappingApplication");
  options.predictionOptions.loadFromConfigFile(config, "MappingApplication");
  options.verbosity_level = mrpt::system::LVL_ERROR;
  mrpt::random::getRandomGenerator().randomize(static_cast<unsigned>(std::stoul(argv[4])));
  const mrpt::obs::CActionRobotMovement2D::TMotionModelOptions motion;  // MRPT's defaults

  mrpt::slam::CMetricMapBuilderRBPF builder(options);
  builder.mapPDF.setVerbosityLevel(mrpt::system::LVL_ERROR);  // its warnings go to stdout
  builder.initialize();
  // The filter adds a path entry only when it runs (the config's localize distances); a record
  // in between is posed by the entry before it and the odometry since.
  std::vector<size_t> entries_after(records.size());
  mrpt::poses::CPose2D previous = records.front().odometry;
  const std::clock_t cpu_start = std::clock();
  for (size_t i = 0; i < records.size(); ++i) {
    const Record& r = records[i];
    mrpt::obs::CActionRobotMovement2D movement;
    movement.timestamp = mrpt::system::time_tToTimestamp(r.t);
    movement.computeFromOdometry(r.odometry - previous, motion);
    previous = r.odometry;
    mrpt::obs::CActionCollection actions;
    actions.insert(movement);
    auto scan = mrpt::obs::CObservation2DRangeScan::Create();
    scan->timestamp = movement.timestamp;
    scan->aperture = static_cast<float>(M_PI);  // beams from -90 to +90 degrees, pi/179 apart
    scan->rightToLeft = true;
    scan->maxRange = 81.0f;  // 81.83: no return
    scan->resizeScan(r.ranges.size());
    for (size_t k = 0; k < r.ranges.size(); ++k) {
      scan->setScanRange(k, r.ranges[k]);
      scan->setScanRangeValidity(k, r.ranges[k] > 0.0f && r.ranges[k] < 81.0f);
    }
    mrpt::obs::CSensoryFrame frame;
    frame.insert(scan);
    builder.processActionObservation(actions, frame);
    std::deque<mrpt::math::TPose3D> path;
    builder.getCurrentMostLikelyPath(path);
    entries_after[i] = path.size();
    if ((i + 1) % 250 == 0 || i + 1 == records.size()) {
      std::fprintf(stderr, "%s: record %zu/%zu\n", out_path.c_str(), i + 1, records.size());
    }
  }
  const double cpu_s = static_cast<double>(std::clock() - cpu_start) / CLOCKS_PER_SEC;

  std::deque<mrpt::math::TPose3D> path;  // the most likely particle's, smoothed by resampling
  builder.getCurrentMostLikelyPath(path);
  std::vector<size_t> record_of_entry(path.size() + 1, 0);
  for (size_t i = 0; i < records.size(); ++i) {
    if (i == 0 || entries_after[i] != entries_after[i - 1]) record_of_entry[entries_after[i]] = i;
  }
  std::ofstream out(out_path);
  char line[160];
  double last_t = -1e300;  // TUM times strictly increase: records stepping back are left out
  for (size_t i = 0; i < records.size(); ++i) {
    if (entries_after[i] == 0 || !(records[i].t > last_t)) continue;
    last_t = records[i].t;
    const mrpt::math::TPose3D& e = path[entries_after[i] - 1];
    const mrpt::poses::CPose2D pose =
        mrpt::poses::CPose2D(e.x, e.y, e.yaw) +
        (records[i].odometry - records[record_of_entry[entries_after[i]]].odometry);
    std::snprintf(line, sizeof(line), "%.6f %.6f %.6f 0 0 0 %.9f %.9f\n", records[i].t, pose.x(),
                  pose.y(), std::sin(pose.phi() / 2), std::cos(pose.phi() / 2));
    out << line;
  }
  std::ofstream summary(out_path + ".json");
  std::snprintf(line, sizeof(line),
                "{\"records\": %zu, \"skipped\": %zu, \"path_entries\": %zu, \"cpu_s\": %.3f, "
                "\"cpu_ms_per_record\": %.3f}\n",
                records.size(), skipped, path.size(), cpu_s, 1000.0 * cpu_s / records.size());
  summary << line;
  const auto points =
      builder.getCurrentlyBuiltMetricMap()->mapByClass<mrpt::maps::CSimplePointsMap>();
  const bool points_ok = !points || points->save2D_to_text_file(out_path + ".points");
  return out && summary && points_ok ? 0 : 1;
}
