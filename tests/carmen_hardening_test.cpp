// CARMEN logs that claim too much (issue 46, items 2 and 6): poses beyond any robot's run,
// records of more beams than any scanner has, lines longer than any record: each such line is
// counted, skipped and named by its number, the file is read line by line, and a replay of what
// is left ends promptly with a clear outcome.

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <array>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <string>

#include "offline/carmen_log.hpp"
#include "offline/experiment_reader.hpp"
#include "offline/replay.hpp"
#include "test_support.hpp"

namespace slam::offline {
namespace {

namespace fs = std::filesystem;

// The probe's log: odometry 1e300 m away, then laser records (with poses as far, or without).
constexpr const char* kHugePoses =
    "ODOM 1e300 -1e300 1e300 0 0 0 1.0 host 1.0\n"
    "FLASER 3 1.0 1.0 1.0 1e300 -1e300 1e300 1e300 -1e300 1e300 1.1 host 1.1\n"
    "FLASER 3 1.0 1.0 1.0 -1e300 1e300 -1e300 -1e300 1e300 -1e300 1.2 host 1.2\n"
    "FLASER 3 1.0 1.0 1.0 1 1 0 1e6 1e6 1e300 1.3 host 1.3\n";

struct ToolRun {
  int status = -1;
  std::string output;  // stdout and stderr
};

ToolRun RunTool(const std::string& command) {
  ToolRun run;
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (pipe == nullptr) return run;
  std::array<char, 4096> buffer{};
  size_t n = 0;
  while ((n = fread(buffer.data(), 1, buffer.size(), pipe)) > 0)
    run.output.append(buffer.data(), n);
  const int status = pclose(pipe);
  run.status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return run;
}

TEST(CarmenHardening, PosesBeyondAnyRunAreCountedSkippedAndNamedByLine) {
  const auto parsed = ParseCarmenLog(kHugePoses, "huge.clf");
  ASSERT_FALSE(parsed.ok());  // no laser record is left
  const std::string message = parsed.Message();
  EXPECT_NE(message.find("huge.clf: no laser record"), std::string::npos) << message;
  EXPECT_NE(message.find("(4 malformed)"), std::string::npos) << message;
  EXPECT_NE(message.find("huge.clf:1: ODOM: the pose (1e+300, -1e+300) is beyond 1e+07 m"),
            std::string::npos)
      << message;
  EXPECT_NE(message.find("huge.clf:2: FLASER: the laser pose (1e+300, -1e+300) is beyond"),
            std::string::npos)
      << message;
  // The odometry's angle too.
  EXPECT_NE(message.find("huge.clf:4: FLASER: the odometry pose's angle 1e+300 is beyond 1e+06"),
            std::string::npos)
      << message;
  // Within the bound, poses are kept (a log's odometry may be far from its origin).
  const auto near = ParseCarmenLog("FLASER 1 1.0 9e6 -9e6 3 9e6 -9e6 3 1.0 host 1.0\n", "near.clf");
  ASSERT_TRUE(near.ok()) << near.Message();
  EXPECT_DOUBLE_EQ(near.value().lasers[0].robot_odometry->x, 9e6);
}

TEST(CarmenHardening, TheProbesFourLineLogIsRefusedByTheReplayAtOnce) {
  const testing::TempDir dir("carmen_huge");
  const fs::path path = dir.path() / "huge.clf";
  std::ofstream(path) << kHugePoses;
  const auto start = std::chrono::steady_clock::now();
  const ToolRun run = RunTool(std::string(SLAM_REPLAY_BIN) + " --quiet --out " +
                              (dir.path() / "out").string() + " " + path.string());
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(10));
  EXPECT_EQ(run.status, 1) << run.output;
  EXPECT_NE(run.output.find("no laser record"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("huge.clf:1: ODOM: the pose (1e+300, -1e+300) is beyond"),
            std::string::npos)
      << run.output;
}

TEST(CarmenHardening, OdometryFarAndJumpingIsReplayedPromptly) {
  // Poses inside the reader's bound but 1.8e7 m apart, and laser records without poses between
  // odometry that jumps: the reader takes the jumps for restarts, the engine maps what is left.
  const testing::TempDir dir("carmen_far");
  const fs::path path = dir.path() / "far.clf";
  {
    std::ofstream out(path);
    for (int i = 0; i < 12; ++i) {
      const double x = (i % 2 == 0 ? 9e6 : -9e6) + 0.01 * i;
      char line[200];
      std::snprintf(line, sizeof(line), "ODOM %g %g 0.1 0 0 0 %.2f host %.2f\n", x, -x, i * 0.1,
                    i * 0.1);
      out << line;
      // Every other record carries its own odometry, as far off as the ODOM lines.
      if (i % 2 == 0) {
        std::snprintf(line, sizeof(line), "FLASER 3 1.0 2.0 1.5 %g %g 0 %g %g 0 %.2f host %.2f\n",
                      -x, x, -x, x, i * 0.1 + 0.05, i * 0.1 + 0.05);
      } else {
        std::snprintf(line, sizeof(line), "FLASER 3 1.0 2.0 1.5 %.2f host %.2f\n", i * 0.1 + 0.05,
                      i * 0.1 + 0.05);
      }
      out << line;
    }
  }
  const auto start = std::chrono::steady_clock::now();
  const ToolRun run = RunTool(std::string(SLAM_REPLAY_BIN) + " --quiet --budget 8125 --out " +
                              (dir.path() / "out").string() + " " + path.string());
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(20));
  EXPECT_EQ(run.status, 0) << run.output;
  EXPECT_NE(run.output.find("\"scans\""), std::string::npos) << run.output;
}

TEST(CarmenHardening, ARecordOfMoreBeamsThanAnyScannerIsSkippedAndNamed) {
  const auto record = [](size_t beams) {
    std::string line = "FLASER " + std::to_string(beams);
    for (size_t i = 0; i < beams; ++i) line += " 1.5";
    return line + " 1.0 host 1.0\n";
  };
  const auto parsed = ParseCarmenLog(
      record(kCarmenMaxReadings + 1) + record(kCarmenMaxReadings) + "FLASER 9999999 1 2 3 host 3\n",
      "beams.clf");
  ASSERT_TRUE(parsed.ok()) << parsed.Message();
  const CarmenLog& log = parsed.value();
  ASSERT_EQ(log.lasers.size(), 1u);
  EXPECT_EQ(log.lasers[0].ranges.size(), kCarmenMaxReadings);
  EXPECT_EQ(log.lasers[0].line, 2u);
  ASSERT_EQ(log.problems.size(), 2u);
  EXPECT_EQ(log.problems[0],
            "beams.clf:1: FLASER: the number of readings 65537 is more than 65536 (no laser "
            "scanner has so many beams)");
  EXPECT_EQ(log.problems[1].rfind("beams.clf:3: FLASER: the number of readings 9999999 is more", 0),
            0u)
      << log.problems[1];
  // Fewer fields than announced: refused before the readings are stored.
  const auto short_record =
      ParseCarmenLog("FLASER 60000 1 2 3 host 3\nFLASER 1 1 3 host 3\n", "short.clf");
  ASSERT_TRUE(short_record.ok());
  EXPECT_NE(short_record.value().problems[0].find("60000 announced, 5 fields left"),
            std::string::npos)
      << short_record.value().problems[0];
}

TEST(CarmenHardening, ALineLongerThanAnyRecordIsSkippedAndNamedWithoutBeingHeldWhole) {
  const testing::TempDir dir("carmen_long");
  const fs::path path = dir.path() / "long.clf";
  {
    std::ofstream out(path);
    out << "# a log with one line of garbage\n";
    out << "FLASER 3 ";
    const std::string chunk(1 << 20, '1');
    for (size_t i = 0; i < 5; ++i) out << chunk;  // 5 MiB, one field
    out << " 1 2 1.0 host 1.0\n";
    out << "FLASER 3 1.0 2.0 1.5 2.0 host 2.0\n";
    out << "FLASER 3 1.0 2.0 1.5 3.0 host 3.0";  // no newline at the end
  }
  EXPECT_TRUE(LooksLikeCarmenLog(path.string()));
  const auto loaded = LoadCarmenLog(path.string());
  ASSERT_TRUE(loaded.ok()) << loaded.Message();
  const CarmenLog& log = loaded.value();
  EXPECT_EQ(log.counters.lines, 4u);
  EXPECT_EQ(log.counters.bad_lines, 1u);
  ASSERT_EQ(log.lasers.size(), 2u);
  EXPECT_EQ(log.lasers[0].line, 3u);
  EXPECT_EQ(log.lasers[1].line, 4u);
  ASSERT_EQ(log.problems.size(), 1u);
  EXPECT_EQ(log.problems[0],
            path.string() +
                ":2: longer than 4194304 bytes (no record of at most 65536 readings "
                "is): skipped");
  // The same text in memory gives the same answer.
  std::ifstream in(path, std::ios::binary);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto parsed = ParseCarmenLog(text, path.string());
  ASSERT_TRUE(parsed.ok());
  EXPECT_EQ(parsed.value().problems, log.problems);
  EXPECT_EQ(parsed.value().counters.lines, 4u);

  // A file that is one long line holds no laser record: an error that names the line.
  const fs::path garbage = dir.path() / "garbage.clf";
  {
    std::ofstream out(garbage);
    out << "FLASER 100000 " << std::string(5 << 20, '1');
  }
  EXPECT_TRUE(LooksLikeCarmenLog(garbage.string()));
  const auto refused = LoadExperiment(garbage.string());
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.Message().find(garbage.string() + ":1: longer than 4194304 bytes"),
            std::string::npos)
      << refused.Message();
}

TEST(CarmenHardening, TellsALogFromOtherFilesByItsFirstRecordOnly) {
  const testing::TempDir dir("carmen_looks");
  const auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir.path() / name) << text;
    return (dir.path() / name).string();
  };
  EXPECT_TRUE(LooksLikeCarmenLog(write("a.clf", "\n# c\n  \t\nROBOTLASER1 0 0")));
  EXPECT_TRUE(LooksLikeCarmenLog(write("b.clf", "PARAM x 1\n")));
  EXPECT_FALSE(LooksLikeCarmenLog(write("c.clf", "# only comments\n#\n")));
  EXPECT_FALSE(LooksLikeCarmenLog(write("d.clf", "FLASERX 1 2\n")));
  EXPECT_FALSE(LooksLikeCarmenLog(write("e.clf", std::string(100, 'O') + "\n")));
  EXPECT_FALSE(LooksLikeCarmenLog(write("f.clf", "")));
}

}  // namespace
}  // namespace slam::offline
