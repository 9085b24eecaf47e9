#include "hw_link/experiment_reader.hpp"

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "engine/io/robot_json.hpp"
#include "engine/io/tum.hpp"
#include "hw_link/frame_decoder.hpp"
#include "hw_link/transports.hpp"

namespace slam::hw {
namespace {

using Json = nlohmann::json;

/// The whole file, or an error naming it.
std::optional<std::string> ReadText(const std::string& path, std::string& error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    error = path + ": cannot open (" + std::strerror(errno) + ")";
    return std::nullopt;
  }
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) {
    error = path + ": read error";
    return std::nullopt;
  }
  return text.str();
}

/// meta.json, or an error naming the file and what is wrong.
std::optional<ExperimentMeta> LoadMeta(const std::string& path, std::string& error) {
  const auto text = ReadText(path, error);
  if (!text) return std::nullopt;
  Json json;
  try {
    json = Json::parse(*text);
  } catch (const Json::parse_error& e) {
    // e.byte is 1-based; count the lines up to it.
    const size_t end = std::min(text->size(), static_cast<size_t>(e.byte));
    const auto line = 1 + std::count(text->begin(), text->begin() + static_cast<long>(end), '\n');
    error = path + ":" + std::to_string(line) + ": not valid JSON";
    return std::nullopt;
  } catch (const Json::exception& e) {  // out_of_range: a number too large for a double
    error = path + ": not valid JSON (" + e.what() + ")";
    return std::nullopt;
  }
  if (!json.is_object()) {
    error = path + ": expected a JSON object, got " + json.type_name();
    return std::nullopt;
  }
  ExperimentMeta meta;
  const auto wrong = [&](const char* key, const char* expected) {
    error = path + "#/" + key + ": expected " + expected + ", got " + json[key].type_name();
    return std::nullopt;
  };
  if (!json.contains("name")) {
    error = path + ": missing key \"name\"";
    return std::nullopt;
  }
  if (!json["name"].is_string()) return wrong("name", "a string");
  meta.name = json["name"].get<std::string>();
  if (json.contains("world")) {
    if (!json["world"].is_string()) return wrong("world", "a string");
    meta.world = json["world"].get<std::string>();
  }
  if (json.contains("source")) {
    if (!json["source"].is_string()) return wrong("source", "a string");
    meta.source = json["source"].get<std::string>();
    if (meta.source != "sim" && meta.source != "robot") {
      error = path + "#/source: expected \"sim\" or \"robot\", got \"" + meta.source + "\"";
      return std::nullopt;
    }
  }
  if (json.contains("duration_s")) {
    if (!json["duration_s"].is_number()) return wrong("duration_s", "a number");
    meta.duration_s = json["duration_s"].get<double>();
  }
  if (json.contains("seed")) {
    if (!json["seed"].is_number_unsigned()) return wrong("seed", "a non-negative integer");
    meta.seed = json["seed"].get<uint64_t>();
  }
  return meta;
}

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
  std::string error;
  if (auto meta = LoadMeta(file("meta.json"), error)) {
    experiment.meta = *meta;
  } else {
    errors.push_back(error);
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
