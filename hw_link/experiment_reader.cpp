#include "hw_link/experiment_reader.hpp"

#include <filesystem>

#include "engine/io/experiment_meta.hpp"
#include "engine/io/robot_json.hpp"
#include "engine/io/tum.hpp"
#include "hw_link/frame_decoder.hpp"
#include "hw_link/transports.hpp"

namespace slam::hw {
namespace {

uint64_t Counter(const SourceCounters& counters, const std::string& name) {
  for (const auto& [key, value] : counters) {
    if (key == name) return value;
  }
  return 0;
}

}  // namespace

ExperimentLoad LoadExperiment(const std::string& dir, const ScanAssemblerConfig& assembler_config) {
  ExperimentLoad load;
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) {
    load.error = dir + ": not an experiment directory (" +
                 (std::filesystem::exists(dir, ec) ? "not a directory" : "does not exist") + ")";
    return load;
  }
  const std::filesystem::path base(dir);
  const auto file = [&](const char* name) { return (base / name).string(); };

  Experiment experiment;
  experiment.dir = dir;
  std::vector<std::string> errors;

  auto robot = io::LoadRobot(file("robot.json"));
  if (!robot.ok()) {
    errors.push_back(robot.Message());
  } else {
    experiment.robot = robot.value();
  }
  auto meta = io::LoadExperimentMeta(file("meta.json"));
  if (!meta.ok()) {
    errors.push_back(meta.Message());
  } else {
    experiment.meta = std::move(meta).value();
  }
  if (std::filesystem::exists(file("groundtruth.tum"), ec)) {
    auto truth = io::LoadTum(file("groundtruth.tum"));
    if (!truth.ok()) {
      errors.push_back(truth.Message());
    } else {
      experiment.ground_truth = std::move(truth).value();
    }
  }
  if (std::filesystem::exists(file("world.json"), ec)) {
    sim::WorldLoadResult world = sim::LoadWorld(file("world.json"));
    if (!world.ok()) {
      for (const std::string& e : world.errors) errors.push_back(e);
    } else {
      experiment.world = std::move(world.world);
    }
  }
  if (!std::filesystem::exists(file("can.log"), ec)) {
    errors.push_back(file("can.log") + ": cannot open (No such file or directory)");
  }
  if (!errors.empty()) {
    for (const std::string& e : errors) load.error += (load.error.empty() ? "" : "\n") + e;
    return load;
  }

  OpenResult opened = OpenCandumpReplay(file("can.log"));
  if (auto* message = std::get_if<std::string>(&opened)) {
    load.error = *message;
    return load;
  }
  FrameSource& source = *std::get<std::unique_ptr<FrameSource>>(opened);
  FrameDecoder decoder(experiment.robot);
  ScanAssembler assembler(experiment.robot, assembler_config);
  const auto failure = DecodeToEnd(source, decoder, [&](const RobotEvent& event) {
    assembler.Add(event, experiment.scans);
  });
  if (failure) {
    load.error = file("can.log") + ": " + *failure;
    return load;
  }

  ExperimentCounters& counters = experiment.counters;
  counters.frames = decoder.frames();
  const SourceCounters source_counters = source.Counters();
  counters.bad_lines = Counter(source_counters, "bad_lines");
  counters.ignored_lines = Counter(source_counters, "ignored_lines");
  counters.reassembly = decoder.reassembly();
  counters.decoder = decoder.decoder();
  counters.assembler = assembler.counters();
  experiment.t_first = decoder.first_time();
  experiment.t_last = decoder.last_time();
  if (experiment.scans.empty()) {
    load.error = file("can.log") + ": no complete scan in " + std::to_string(counters.frames) +
                 " frames (" + std::to_string(counters.bad_lines) + " garbled lines, " +
                 std::to_string(counters.reassembly.Rejected()) + " rejected fragments, " +
                 std::to_string(counters.decoder.odometry) + " odometry and " +
                 std::to_string(counters.decoder.scanner) + " scanner events, " +
                 std::to_string(counters.decoder.Rejected()) + " unknown messages)";
    return load;
  }
  load.experiment = std::move(experiment);
  return load;
}

}  // namespace slam::hw
