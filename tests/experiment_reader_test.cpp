#include "offline/experiment_reader.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "sim/experiment_writer.hpp"
#include "sim/scenario.hpp"
#include "tests/test_support.hpp"

namespace slam::offline {
namespace {

std::string ReadFile(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

void WriteFile(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
}

/// Replaces the first occurrence of `from` in the file by `to`.
void Edit(const std::filesystem::path& path, const std::string& from, const std::string& to) {
  std::string text = ReadFile(path);
  const size_t at = text.find(from);
  ASSERT_NE(at, std::string::npos) << from << " not in " << path;
  text.replace(at, from.size(), to);
  WriteFile(path, text);
}

/// 1-based line of the first occurrence of `needle` in the file.
int LineOf(const std::filesystem::path& path, const std::string& needle) {
  const std::string text = ReadFile(path);
  const size_t at = text.find(needle);
  if (at == std::string::npos) return 0;
  return 1 + static_cast<int>(std::count(text.begin(), text.begin() + static_cast<long>(at), '\n'));
}

class ExperimentReaderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("slam_experiment_reader_test_" + std::to_string(::getpid()));
    std::filesystem::remove_all(dir_);
    config_.duration_s = 20.0;
    config_.seed = 3;
    ASSERT_TRUE(WriteSimulatedExperiment(dir_.string(), world_, "rooms", robot_, config_).ok());
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  Result<Experiment> Load() const { return LoadExperiment(dir_.string()); }

  /// The error of loading the experiment, which must fail.
  std::string LoadError() const {
    const Result<Experiment> load = Load();
    EXPECT_FALSE(load.ok());
    return load.Message();
  }

  std::filesystem::path dir_;
  RobotDescription robot_ = testing::ShippedRobot();
  sim::World world_ = *sim::BuiltinWorld("rooms");
  sim::ScenarioConfig config_;
};

TEST_F(ExperimentReaderTest, ReadsTheSimulatorsScansGroundTruthAndWorld) {
  const Result<Experiment> load = Load();
  ASSERT_TRUE(load.ok()) << load.Message();
  const Experiment& e = load.value();
  const sim::ScenarioOutput made = sim::RunScenario(world_, robot_, config_);
  const std::vector<Scan> expected = sim::BuildScans(robot_, made.odometry, made.scanner);
  // The bus delays the frames by about 0.1 ms, which may leave the log's last scan unfinished.
  ASSERT_GE(e.scans.size() + 1, expected.size());
  ASSERT_LE(e.scans.size(), expected.size());
  ASSERT_GT(e.scans.size(), 20u);
  for (size_t k = 0; k < e.scans.size(); ++k) {
    ASSERT_EQ(e.scans[k].samples.size(), expected[k].samples.size()) << "scan " << k;
    for (size_t i = 0; i < e.scans[k].samples.size(); ++i) {
      EXPECT_EQ(e.scans[k].samples[i].raw, expected[k].samples[i].raw);
    }
  }
  EXPECT_EQ(e.meta.name, "rooms-seed3");
  EXPECT_EQ(e.meta.world, "rooms");
  EXPECT_EQ(e.meta.source, "sim");
  EXPECT_EQ(e.meta.seed, 3u);
  EXPECT_EQ(e.ground_truth.size(), made.ground_truth.size());
  ASSERT_TRUE(e.world.has_value());
  EXPECT_EQ(e.world->segments.size(), world_.segments.size());
  EXPECT_NEAR(e.duration_s(), 20.0, 0.1);
  EXPECT_GT(e.counters.frames, 4000u);
  EXPECT_EQ(e.counters.FramesRejected(), 0u);
  EXPECT_EQ(e.counters.assembler.scans, e.scans.size());
}

TEST_F(ExperimentReaderTest, OptionalFilesMayBeAbsent) {
  std::filesystem::remove(dir_ / "groundtruth.tum");
  std::filesystem::remove(dir_ / "world.json");
  const Result<Experiment> load = Load();
  ASSERT_TRUE(load.ok()) << load.Message();
  EXPECT_TRUE(load.value().ground_truth.empty());
  EXPECT_FALSE(load.value().world.has_value());
}

TEST_F(ExperimentReaderTest, MissingDirectoryAndRequiredFilesAreNamed) {
  EXPECT_NE(LoadExperiment((dir_ / "nowhere").string()).Message().find("does not exist"),
            std::string::npos);
  for (const char* name : {"robot.json", "can.log", "meta.json"}) {
    SetUp();
    std::filesystem::remove(dir_ / name);
    const std::string error = LoadError();
    EXPECT_NE(error.find((dir_ / name).string()), std::string::npos) << error;
    EXPECT_NE(error.find("cannot open"), std::string::npos) << error;
  }
}

TEST_F(ExperimentReaderTest, GarbledMetaJsonNamesFileAndLine) {
  WriteFile(dir_ / "meta.json", "{\n  \"name\": \"x\",\n  \"seed\": 3,,\n}\n");
  const std::string error = LoadError();
  EXPECT_NE(error.find("meta.json: parse error at line 3"), std::string::npos) << error;

  WriteFile(dir_ / "meta.json", "{\n\"name\": 42}");
  EXPECT_NE(LoadError().find("meta.json:2: /name: expected a string, got number"),
            std::string::npos);
  WriteFile(dir_ / "meta.json", "{\"name\": \"x\", \"source\": \"tape\"}");
  EXPECT_NE(LoadError().find(":1: /source: expected \"sim\" or \"robot\""), std::string::npos);
  WriteFile(dir_ / "meta.json", "{\"name\": \"x\", \"seed\": -1}");
  EXPECT_NE(LoadError().find("/seed: expected a non-negative integer"), std::string::npos);
  WriteFile(dir_ / "meta.json", "{\"name\": \"x\", \"duration_s\": 1e400}");  // beyond a double
  EXPECT_NE(LoadError().find("meta.json: number overflow"), std::string::npos) << LoadError();
  WriteFile(dir_ / "meta.json", "{\"world\": \"x\"}");
  EXPECT_NE(LoadError().find("/name: missing required key"), std::string::npos);
  // Unknown keys are allowed in meta.json (a record, not configuration).
  WriteFile(dir_ / "meta.json", "{\"name\": \"x\", \"operator\": \"ana\"}");
  EXPECT_TRUE(Load().ok());
}

TEST_F(ExperimentReaderTest, UnknownRobotKeyAndWrongTypeNameFileLineAndPointer) {
  const std::filesystem::path robot = dir_ / "robot.json";
  Edit(robot, "\"track_width_m\"", "\"track_width_mm\": 150, \"track_width_m\"");
  const int line = LineOf(robot, "track_width_mm");
  std::string error = LoadError();
  EXPECT_NE(error.find(robot.string()), std::string::npos) << error;
  EXPECT_NE(error.find("/base/track_width_mm"), std::string::npos) << error;
  EXPECT_NE(error.find(":" + std::to_string(line) + ":"), std::string::npos) << error;

  SetUp();
  Edit(robot, "\"sample_rate_hz\": 60.0", "\"sample_rate_hz\": \"60\"");
  error = LoadError();
  EXPECT_NE(error.find("/scanner/sample_rate_hz"), std::string::npos) << error;
  EXPECT_NE(error.find("expected a number, got string"), std::string::npos) << error;
}

TEST_F(ExperimentReaderTest, NonMonotonicGroundTruthNamesTheLine) {
  std::string text = ReadFile(dir_ / "groundtruth.tum");
  // Swap lines 10 and 11.
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  ASSERT_GT(lines.size(), 20u);
  std::swap(lines[9], lines[10]);
  std::string swapped;
  for (const std::string& line : lines) swapped += line + "\n";
  WriteFile(dir_ / "groundtruth.tum", swapped);
  const std::string error = LoadError();
  EXPECT_NE(error.find("groundtruth.tum:11:"), std::string::npos) << error;
}

TEST_F(ExperimentReaderTest, TruncatedLogIsReadUpToTheCutAndCounted) {
  const std::string full = ReadFile(dir_ / "can.log");
  const Result<Experiment> whole = Load();
  ASSERT_TRUE(whole.ok());
  // Cut in the middle of a line, about halfway.
  const size_t half = full.find('\n', full.size() / 2) + 12;
  WriteFile(dir_ / "can.log", full.substr(0, half));
  const Result<Experiment> cut = Load();
  ASSERT_TRUE(cut.ok()) << cut.Message();
  EXPECT_EQ(cut.value().counters.bad_lines, 1u);
  EXPECT_EQ(cut.value().counters.FramesRejected(), 1u);
  EXPECT_LT(cut.value().scans.size(), whole.value().scans.size());
  EXPECT_GT(cut.value().scans.size(), whole.value().scans.size() / 3);
}

TEST_F(ExperimentReaderTest, GarbageInsideTheLogIsCountedAndSkipped) {
  std::string text = ReadFile(dir_ / "can.log");
  const size_t at = text.find('\n', text.size() / 3) + 1;
  text.insert(at, "(garbage line\n(1700000005.000000) can0 1G2#00\n(\x01\x02\xff\n");
  WriteFile(dir_ / "can.log", text);
  const Result<Experiment> load = Load();
  ASSERT_TRUE(load.ok()) << load.Message();
  EXPECT_EQ(load.value().counters.bad_lines, 3u);
  EXPECT_GT(load.value().scans.size(), 20u);
}

TEST_F(ExperimentReaderTest, ALogWithoutScansIsAnErrorThatExplains) {
  WriteFile(dir_ / "can.log", "(nothing\n(useful here\n");
  const std::string error = LoadError();
  EXPECT_NE(error.find("can.log: no complete scan in 0 frames (2 garbled lines"), std::string::npos)
      << error;
}

TEST_F(ExperimentReaderTest, GarbledWorldIsAnError) {
  WriteFile(dir_ / "world.json", "{\"name\": \"w\", \"bounds\": [0, 0, 1]}");
  const std::string error = LoadError();
  EXPECT_NE(error.find("world.json"), std::string::npos) << error;
  EXPECT_NE(error.find("/bounds"), std::string::npos) << error;
}

}  // namespace
}  // namespace slam::offline
