// slamd-load against a real slamd: its report counts what it sent and what slamd did, the
// PATCHes pass with the token, and it says clearly when it cannot start.

#include <string>

#include "tests/command_support.hpp"
#include "tests/slamd_harness.hpp"

namespace slamd_test {
namespace {

using slam::testing::CommandResult;
using slam::testing::RunCommand;

class LoadSlamd : public SlamdSuite {
 protected:
  static void SetUpTestSuite() {
    dir_ = std::make_unique<ScratchDir>("load");
    WriteFile(dir_->path() / "token", "load-t0ken-0123456789\n");
    // A small budget keeps scans coming under the sanitizers too (TSan maps some 40 times
    // slower), so that a 3 s run counts some.
    foxglove_port_ = FreeTcpPort();
    StartShared({"--token-file", (dir_->path() / "token").string(), "--budget", "2000",
                 "--foxglove-port", std::to_string(foxglove_port_)});
  }
  static void TearDownTestSuite() {
    StopShared();
    dir_.reset();
  }
  static inline std::unique_ptr<ScratchDir> dir_;
  static inline int foxglove_port_ = 0;
};

TEST_F(LoadSlamd, ReportCountsEveryRequestViewerAndScan) {
  WaitForTiles(http(), 1);
  const CommandResult run = RunCommand(
      std::string(SLAMD_LOAD_BIN) + " --url " + slamd_->url() +
          " --duration 3 --rate 100 --viewers 2 --connections 2 --json --token-file " +
          (dir_->path() / "token").string() + " --pid " + std::to_string(slamd_->pid()) +
          " --foxglove ws://127.0.0.1:" + std::to_string(foxglove_port_) + " --foxglove-clients 2",
      dir_->path());
  ASSERT_EQ(run.status, 0) << run.err;
  const json report = json::parse(run.out, nullptr, false);
  ASSERT_TRUE(report.is_object()) << run.out;
  // 300 requests due over 3 s, 6 of them PATCHes (every 50th) that need the token.
  EXPECT_EQ(report["requests"].get<int>() + report["requests_unsent"].get<int>(), 300) << run.out;
  EXPECT_GE(report["requests"].get<int>(), 290) << run.out;
  EXPECT_EQ(report["rest_errors"], 0) << run.out;
  EXPECT_EQ(report["statuses"], json({{"200", report["requests"]}})) << run.out;
  EXPECT_EQ(report["viewers_connected"], 2) << run.out;
  EXPECT_GT(report["events_received"].get<int>(), 0) << run.out;
  EXPECT_EQ(report["tile_errors"], 0) << run.out;
  EXPECT_GT(report["scans"].get<double>(), 0.0) << run.out;
  EXPECT_GT(report["rss_mib"]["start"].get<double>(), 0.0) << run.out;
  // Two Foxglove clients (with the token), each with the map and poses.
  const json& foxglove = report["foxglove"];
  EXPECT_EQ(foxglove["connected"], 2) << run.out;
  EXPECT_EQ(foxglove["disconnects"], 0) << run.out;
  EXPECT_GE(foxglove["maps"].get<int>(), 2) << run.out;
  EXPECT_GE(foxglove["poses"].get<int>(), 2) << run.out;
  EXPECT_GE(foxglove["first_map_ms"].get<int>(), 0) << run.out;
  EXPECT_EQ(foxglove["dropped_by_slamd"], 0) << run.out;
  const double p50 = report["latency_ms"]["p50"], p99 = report["latency_ms"]["p99"];
  EXPECT_LE(p50, p99) << run.out;
  // The table for people goes to stderr with --json.
  EXPECT_NE(run.err.find("REST requests"), std::string::npos) << run.err;
}

TEST_F(LoadSlamd, WithoutTheTokenThePatchesAreCountedAsErrors) {
  const CommandResult run = RunCommand(std::string(SLAMD_LOAD_BIN) + " --url " + slamd_->url() +
                                           " --duration 1 --rate 100 --viewers 0 --json",
                                       dir_->path());
  ASSERT_EQ(run.status, 0) << run.err;
  const json report = json::parse(run.out, nullptr, false);
  ASSERT_TRUE(report.is_object()) << run.out;
  EXPECT_EQ(report["statuses"].value("401", 0), 2) << run.out;  // requests 49 and 99
  EXPECT_EQ(report["rest_errors"], 2) << run.out;
}

TEST_F(LoadSlamd, UnreachableOrMalformedTargetsAreClearErrors) {
  const std::string tool = SLAMD_LOAD_BIN;
  const CommandResult bad_url = RunCommand(tool + " --url 127.0.0.1:8080", dir_->path());
  EXPECT_EQ(bad_url.status, 2);
  EXPECT_NE(bad_url.err.find("--url must look like http://HOST:PORT/"), std::string::npos)
      << bad_url.err;
  const CommandResult closed = RunCommand(tool + " --url http://127.0.0.1:1/", dir_->path());
  EXPECT_EQ(closed.status, 1);
  EXPECT_NE(closed.err.find("slamd is not reachable at http://127.0.0.1:1/"), std::string::npos)
      << closed.err;
  const CommandResult no_pid =
      RunCommand(tool + " --url " + slamd_->url() + " --duration 1 --pid 2147483000", dir_->path());
  EXPECT_EQ(no_pid.status, 1);
  EXPECT_NE(no_pid.err.find("cannot read /proc/2147483000/status"), std::string::npos)
      << no_pid.err;
  const CommandResult help = RunCommand(tool + " --help", dir_->path());
  EXPECT_EQ(help.status, 0);
  EXPECT_NE(help.out.find("--viewers"), std::string::npos) << help.out;
}

}  // namespace
}  // namespace slamd_test
