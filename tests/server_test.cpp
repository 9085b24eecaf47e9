// slamd's parts in process: the saved state (exact round trip, damage detected, a crash between
// files leaves the previous state), the SLAM service over a recorded experiment (snapshots,
// versions, reset, budget changes), job requests and the security helpers.

#include <gtest/gtest.h>
#include <sys/resource.h>
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <thread>

#include "engine/io/atomic_file.hpp"
#include "engine/random.hpp"
#include "hw_link/transports.hpp"
#include "offline/replay.hpp"
#include "server/access_policy.hpp"
#include "server/api_json.hpp"
#include "server/http_server.hpp"
#include "server/request_guard.hpp"
#include "server/slam_service.hpp"
#include "server/state_store.hpp"
#include "server/tune_jobs.hpp"
#include "tests/experiment_support.hpp"
#include "tests/test_support.hpp"

namespace slam::server {
namespace {

using testing::TempDir;

SavedState SampleState(uint64_t version, uint64_t seed) {
  SavedState s;
  s.version = version;
  s.resolution_m = 0.01;
  Rng rng(seed);
  for (int i = 0; i < 3; ++i) {
    SavedTile tile;
    tile.index = {i - 1, 2 * i};
    tile.version = version - static_cast<uint64_t>(i);
    tile.cells.resize(kTileCells);
    for (LogOdds& c : tile.cells)
      c = static_cast<LogOdds>(static_cast<int>(rng.Next() % 1001) - 500);
    s.tiles.push_back(std::move(tile));
  }
  s.trajectory = {{0.5, {0, 0, 0}}, {1.0, {0.1, 0.2, 0.3}}, {1.5, {0.2, 0.3, -0.4}}};
  return s;
}

OccupancyGrid GridOf(const SavedState& s) {
  OccupancyGrid grid(GridGeometry(s.resolution_m), 2000);
  grid.BeginWrite();
  for (const SavedTile& t : s.tiles) {
    std::copy(t.cells.begin(), t.cells.end(), grid.MutableTile(t.index).cells.begin());
  }
  return grid;
}

void Save(const std::string& dir, const SavedState& s) {
  const OccupancyGrid grid = GridOf(s);
  SaveInputs in;
  in.version = s.version;
  in.resolution_m = s.resolution_m;
  in.grid = &grid;
  in.version_base = 100;
  in.trajectory = s.trajectory;
  const Result<SaveReport> saved = SaveState(dir, in);
  ASSERT_TRUE(saved.ok()) << saved.Message();
  EXPECT_TRUE(saved.value().warnings.empty());
}

// DecodeTiles' verdict, with its message (empty when it decodes) in `error`.
bool Decodes(const std::string& bytes, std::string& error) {
  const Result<SavedState> decoded = DecodeTiles(bytes);
  error = decoded.Message();
  return decoded.ok();
}

TEST(StateStore, TilesRoundTripExactly) {
  const SavedState s = SampleState(42, 1);
  Result<SavedState> decoded = DecodeTiles(EncodeTiles(s));
  ASSERT_TRUE(decoded.ok()) << decoded.Message();
  const SavedState back = std::move(decoded).value();
  EXPECT_EQ(back.version, 42u);
  EXPECT_EQ(back.resolution_m, 0.01);
  ASSERT_EQ(back.tiles.size(), s.tiles.size());
  for (size_t i = 0; i < s.tiles.size(); ++i) {
    EXPECT_EQ(back.tiles[i].index, s.tiles[i].index);
    EXPECT_EQ(back.tiles[i].version, s.tiles[i].version);
    EXPECT_EQ(back.tiles[i].cells, s.tiles[i].cells);
  }
}

TEST(StateStore, DamageIsDetected) {
  const std::string bytes = EncodeTiles(SampleState(7, 2));
  std::string flipped = bytes;
  flipped[bytes.size() / 2] = static_cast<char>(flipped[bytes.size() / 2] ^ 0x10);
  const std::string checksum = DecodeTiles(flipped).Message();
  EXPECT_NE(checksum.find("checksum"), std::string::npos) << checksum;
  EXPECT_FALSE(DecodeTiles(bytes.substr(0, bytes.size() - 100)).ok());
  EXPECT_FALSE(DecodeTiles("").ok());
  const std::string magic = DecodeTiles("SLMTILE0" + bytes.substr(8)).Message();
  EXPECT_NE(magic.find("magic"), std::string::npos) << magic;
}

TEST(StateStore, SaveThenLoadGivesTheMapAndTrajectory) {
  TempDir dir("state_roundtrip");
  const SavedState s = SampleState(10, 3);
  Save(dir.path().string(), s);
  const Result<std::optional<SavedState>> loaded = LoadState(dir.path().string());
  ASSERT_TRUE(loaded.ok()) << loaded.Message();
  ASSERT_TRUE(loaded.ok() && loaded.value());
  EXPECT_EQ(loaded.value()->version, 10u);
  ASSERT_EQ(loaded.value()->tiles.size(), 3u);
  // Tiles come back in the grid's row-major order; match them by index.
  for (const SavedTile& t : s.tiles) {
    const auto it = std::find_if(loaded.value()->tiles.begin(), loaded.value()->tiles.end(),
                                 [&](const SavedTile& u) { return u.index == t.index; });
    ASSERT_NE(it, loaded.value()->tiles.end());
    EXPECT_EQ(it->cells, t.cells);
    EXPECT_GT(it->version, 100u);  // the base is added to the grid's own versions
  }
  ASSERT_EQ(loaded.value()->trajectory.size(), 3u);
  EXPECT_NEAR(loaded.value()->trajectory.back().pose.theta, -0.4, 1e-6);
  for (const char* name : {"map.pgm", "map.yaml", "map.png", "trajectory.tum", "state.json"}) {
    EXPECT_TRUE(std::filesystem::exists(dir.path() / name)) << name;
  }
}

TEST(StateStore, NothingSavedIsNotAnError) {
  TempDir dir("state_empty");
  const Result<std::optional<SavedState>> loaded = LoadState(dir.path().string());
  EXPECT_TRUE(loaded.ok());
  EXPECT_FALSE(loaded.ok() && loaded.value());
}

TEST(StateStore, ANewSaveReplacesTheOldFiles) {
  TempDir dir("state_replace");
  Save(dir.path().string(), SampleState(10, 4));
  Save(dir.path().string(), SampleState(20, 5));
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "map-10.tiles"));
  EXPECT_TRUE(std::filesystem::exists(dir.path() / "map-20.tiles"));
  EXPECT_EQ(LoadState(dir.path().string()).value()->version, 20u);
}

TEST(StateStore, ACrashBeforeTheCommitLeavesThePreviousState) {
  // A save killed after writing its tile file but before state.json: the half-finished save
  // (here a torn tile file) is ignored, the previous one loads.
  TempDir dir("state_crash");
  Save(dir.path().string(), SampleState(10, 6));
  const std::string next = EncodeTiles(SampleState(20, 7));
  std::ofstream(dir.File("map-20.tiles"), std::ios::binary) << next.substr(0, next.size() / 3);
  std::ofstream(dir.File(".state.json.tmp-123")) << "{\"format\": 1, \"ver";
  const Result<std::optional<SavedState>> loaded = LoadState(dir.path().string());
  ASSERT_TRUE(loaded.ok()) << loaded.Message();
  EXPECT_EQ(loaded.value()->version, 10u);
}

TEST(StateStore, TilesBeyondTheMapsBoundAndWrappingVersionsAreRefused) {
  // A crafted tiles file (valid checksum) with a tile near INT32_MIN made the resumed grid's
  // tile table cover it and the origin: std::bad_alloc at start, naming no file. A version of
  // 2^64 - 1 wrapped the resumed map's versions.
  SavedState far = SampleState(42, 3);
  far.tiles[1].index = {std::numeric_limits<int32_t>::min() + 5, 0};
  std::string error;
  EXPECT_FALSE(Decodes(EncodeTiles(far), error));
  EXPECT_NE(error.find("tile 1 at (-2147483643, 0) is outside the map's bound"), std::string::npos)
      << error;
  far.tiles[1].index = {0, kMapTileBound};
  EXPECT_FALSE(Decodes(EncodeTiles(far), error));
  far.tiles[1].index = {kMapTileBound - 1, -kMapTileBound};  // the bound's last tiles are fine
  EXPECT_TRUE(Decodes(EncodeTiles(far), error)) << error;

  SavedState wrapping = SampleState(std::numeric_limits<uint64_t>::max(), 4);
  EXPECT_FALSE(Decodes(EncodeTiles(wrapping), error));
  EXPECT_NE(error.find("map version 18446744073709551615 is out of range"), std::string::npos)
      << error;

  // Through LoadState, the error names the file.
  TempDir dir("state_far");
  Save(dir.path().string(), SampleState(10, 8));
  ASSERT_TRUE(io::WriteFileAtomic(dir.File("map-10.tiles"), EncodeTiles(wrapping)).ok());
  const Result<std::optional<SavedState>> loaded = LoadState(dir.path().string());
  EXPECT_FALSE(loaded.ok() && loaded.value());
  EXPECT_NE(loaded.Message().find("map-10.tiles: map version"), std::string::npos)
      << loaded.Message();
}

TEST(StateStore, DuplicateTilesAndCellsBeyondTheLimitAreRefused) {
  // Neither is something SaveState writes: a file holding them was made or damaged elsewhere.
  SavedState twice = SampleState(42, 5);
  twice.tiles[2].index = twice.tiles[0].index;
  std::string error;
  EXPECT_FALSE(Decodes(EncodeTiles(twice), error));
  EXPECT_NE(error.find("tile 2 at (" + std::to_string(twice.tiles[0].index.x)), std::string::npos)
      << error;
  EXPECT_NE(error.find("appears twice"), std::string::npos) << error;

  SavedState hot = SampleState(42, 6);
  hot.tiles[1].cells[7] = static_cast<LogOdds>(kLogOddsLimit + 1);
  EXPECT_FALSE(Decodes(EncodeTiles(hot), error));
  EXPECT_NE(error.find("tile 1 has a cell of 16001"), std::string::npos) << error;
  hot.tiles[1].cells[7] = static_cast<LogOdds>(-kLogOddsLimit);  // the limit itself is fine
  EXPECT_TRUE(Decodes(EncodeTiles(hot), error)) << error;
}

/// Files larger than `bytes` cannot be written while this lives (RLIMIT_FSIZE: write fails with
/// EFBIG, as on a full disk), as long as the files stay under it.
class FileSizeLimit {
 public:
  explicit FileSizeLimit(rlim_t bytes) {
    ::getrlimit(RLIMIT_FSIZE, &saved_);
    previous_handler_ = std::signal(SIGXFSZ, SIG_IGN);
    rlimit limit = saved_;
    limit.rlim_cur = bytes;
    EXPECT_EQ(::setrlimit(RLIMIT_FSIZE, &limit), 0);
  }
  ~FileSizeLimit() {
    ::setrlimit(RLIMIT_FSIZE, &saved_);
    std::signal(SIGXFSZ, previous_handler_);
  }
  FileSizeLimit(const FileSizeLimit&) = delete;
  FileSizeLimit& operator=(const FileSizeLimit&) = delete;

 private:
  rlimit saved_{};
  void (*previous_handler_)(int) = SIG_DFL;
};

std::set<std::string> FilesIn(const std::filesystem::path& dir) {
  std::set<std::string> names;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    names.insert(entry.path().filename().string());
  }
  return names;
}

SaveInputs InputsOf(const SavedState& s, const OccupancyGrid& grid) {
  SaveInputs in;
  in.version = s.version;
  in.resolution_m = s.resolution_m;
  in.grid = &grid;
  in.trajectory = s.trajectory;
  return in;
}

TEST(StateStore, ASaveThatCannotCommitLeavesNothingBehindAndTheNextOneWorks) {
  // A full disk while the trajectory is written, after the tile file: the previous state stands,
  // and neither the new tile file nor what earlier failed or killed saves left stays behind
  // (they did, and with them less space for the next save).
  TempDir dir("state_full_before");
  Save(dir.path().string(), SampleState(10, 1));
  const std::set<std::string> before = FilesIn(dir.path());
  std::ofstream(dir.File("map-15.tiles")) << "left by a failed save";
  std::ofstream(dir.File("trajectory-15.tum")) << "left by a failed save";
  std::ofstream(dir.File("map-15.tiles.tmp-1-2")) << "left by a killed save";
  SavedState s = SampleState(20, 2);  // a 24 kB tile file
  s.trajectory.clear();
  for (int i = 0; i < 3000; ++i) s.trajectory.push_back({0.1 * i, {0.001 * i, 0.5, 0.25}});
  const OccupancyGrid grid = GridOf(s);
  {
    const FileSizeLimit limit(64 * 1024);  // the trajectory is about 180 kB
    const Result<SaveReport> saved = SaveState(dir.path().string(), InputsOf(s, grid));
    ASSERT_FALSE(saved.ok());
    EXPECT_NE(saved.Message().find("trajectory-20.tum"), std::string::npos) << saved.Message();
  }
  EXPECT_EQ(FilesIn(dir.path()), before);
  EXPECT_EQ(LoadState(dir.path().string()).value()->version, 10u);

  const Result<SaveReport> again = SaveState(dir.path().string(), InputsOf(s, grid));
  ASSERT_TRUE(again.ok()) << again.Message();
  EXPECT_TRUE(again.value().warnings.empty());
  EXPECT_EQ(LoadState(dir.path().string()).value()->version, 20u);
  EXPECT_EQ(FilesIn(dir.path()),
            (std::set<std::string>{"map-20.tiles", "trajectory-20.tum", "state.json", "map.pgm",
                                   "map.yaml", "map.png", "trajectory.tum"}));
}

TEST(StateStore, ASaveCommittedWhoseCopiesCannotBeWrittenSucceedsWithWarnings) {
  // The copies for people failing after state.json was committed used to answer 500 and keep
  // the superseded files, so a full disk failed the next save too.
  TempDir dir("state_full_after");
  Save(dir.path().string(), SampleState(10, 1));
  // Two tiles far apart: a 16 kB tile file, a map picture of 31 x 31 tiles (3.9 MB as PGM).
  SavedState sparse = SampleState(20, 3);
  sparse.tiles.resize(2);
  sparse.tiles[0].index = {-15, -15};
  sparse.tiles[1].index = {15, 15};
  const OccupancyGrid grid = GridOf(sparse);
  Result<SaveReport> saved = SaveReport{};
  {
    const FileSizeLimit limit(256 * 1024);
    saved = SaveState(dir.path().string(), InputsOf(sparse, grid));
  }
  ASSERT_TRUE(saved.ok()) << saved.Message();
  ASSERT_FALSE(saved.value().warnings.empty());
  EXPECT_NE(saved.value().warnings[0].find("map.pgm"), std::string::npos)
      << saved.value().warnings[0];
  const Result<std::optional<SavedState>> loaded = LoadState(dir.path().string());
  ASSERT_TRUE(loaded.ok() && loaded.value());
  EXPECT_EQ(loaded.value()->version, 20u);
  const std::set<std::string> files = FilesIn(dir.path());
  EXPECT_FALSE(files.contains("map-10.tiles"));
  EXPECT_FALSE(files.contains("trajectory-10.tum"));
  for (const std::string& name : files) {
    EXPECT_EQ(name.find(".tmp-"), std::string::npos) << "left behind: " << name;
  }
}

TEST(StateStore, OneProcessHoldsAStateDirectory) {
  TempDir dir("state_lock");
  const std::string nested = (dir.path() / "not" / "yet").string();
  auto first = StateDirLock::Acquire(nested);
  ASSERT_TRUE(first.ok()) << first.Message();
  // flock conflicts between two opens even in one process, as between two slamd.
  const auto second = StateDirLock::Acquire(nested);
  ASSERT_FALSE(second.ok());
  EXPECT_NE(second.Message().find("--state-dir " + nested + ": in use by another slamd (pid " +
                                  std::to_string(::getpid()) + ")"),
            std::string::npos)
      << second.Message();
  { const StateDirLock released = std::move(first).value(); }
  EXPECT_TRUE(StateDirLock::Acquire(nested).ok());
}

TEST(StateStore, DamagedStateIsAnErrorNamingTheFile) {
  TempDir dir("state_damaged");
  Save(dir.path().string(), SampleState(10, 8));
  {
    std::fstream f(dir.File("map-10.tiles"), std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(100);
    f.put('\x7f');
  }
  Result<std::optional<SavedState>> loaded = LoadState(dir.path().string());
  EXPECT_FALSE(loaded.ok() && loaded.value());
  EXPECT_NE(loaded.Message().find("map-10.tiles"), std::string::npos) << loaded.Message();

  ASSERT_TRUE(io::WriteFileAtomic(
                  dir.File("state.json"),
                  R"({"format": 1, "tiles_file": "../etc/passwd", "trajectory_file": "t.tum"})")
                  .ok());
  loaded = LoadState(dir.path().string());
  EXPECT_FALSE(loaded.ok() && loaded.value());
  EXPECT_NE(loaded.Message().find("tiles_file"), std::string::npos) << loaded.Message();

  ASSERT_TRUE(io::WriteFileAtomic(dir.File("state.json"), "{not json").ok());
  EXPECT_FALSE(LoadState(dir.path().string()).ok());
}

TEST(Security, ConstantTimeEqualsComparesWholeStrings) {
  EXPECT_TRUE(ConstantTimeEquals("secret-token-123", "secret-token-123"));
  EXPECT_FALSE(ConstantTimeEquals("secret-token-123", "secret-token-124"));
  EXPECT_FALSE(ConstantTimeEquals("secret-token-123", "secret-token-12"));
  EXPECT_FALSE(ConstantTimeEquals("secret", std::string("secret\0x", 8)));
  EXPECT_FALSE(ConstantTimeEquals("", "a"));
  EXPECT_TRUE(ConstantTimeEquals("", ""));
}

TEST(Security, TheAccessPolicyIsTheSameForEveryFrontEnd) {
  const AccessPolicy open("", {"slam.example"});
  EXPECT_FALSE(open.CheckHost("localhost:8080"));
  EXPECT_FALSE(open.CheckHost("[::1]:8080"));
  EXPECT_FALSE(open.CheckHost("192.168.1.5"));
  EXPECT_FALSE(open.CheckHost("SLAM.example:80"));  // names compare case-insensitively
  const auto rebound = open.CheckHost("attacker.example:8080");
  ASSERT_TRUE(rebound);
  EXPECT_EQ(rebound->status, 403);
  EXPECT_NE(rebound->detail.find("attacker.example"), std::string::npos);
  EXPECT_FALSE(open.has_token());
  EXPECT_FALSE(open.CheckToken(""));  // no token configured: nothing to present

  const AccessPolicy secured("s3cret-token", {});
  EXPECT_TRUE(secured.has_token());
  EXPECT_FALSE(secured.CheckToken("Bearer s3cret-token"));
  EXPECT_FALSE(secured.CheckToken("bearer s3cret-token"));  // the scheme is case-insensitive
  const auto missing = secured.CheckToken("");
  ASSERT_TRUE(missing);
  EXPECT_EQ(missing->status, 401);
  EXPECT_EQ(missing->challenge, "Bearer realm=\"slamd\"");
  for (const char* wrong : {"Bearer s3cret-toke", "Bearer S3CRET-TOKEN", "Basic s3cret-token",
                            "s3cret-token", "Bearer"}) {
    const auto refused = secured.CheckToken(wrong);
    ASSERT_TRUE(refused) << wrong;
    EXPECT_NE(refused->challenge.find("invalid_token"), std::string::npos) << wrong;
  }

  EXPECT_TRUE(AccessPolicy::SameOrigin("http://127.0.0.1:8080", "127.0.0.1:8080"));
  EXPECT_TRUE(AccessPolicy::SameOrigin("http://LOCALHOST:8080", "localhost:8080"));
  EXPECT_FALSE(AccessPolicy::SameOrigin("http://evil.example", "127.0.0.1:8080"));
  EXPECT_FALSE(AccessPolicy::SameOrigin("http://127.0.0.1:9090", "127.0.0.1:8080"));
}

TEST(Security, LoopbackAddresses) {
  EXPECT_TRUE(IsLoopback("127.0.0.1"));
  EXPECT_TRUE(IsLoopback("127.1.2.3"));
  EXPECT_TRUE(IsLoopback("::1"));
  EXPECT_TRUE(IsLoopback("localhost"));
  EXPECT_FALSE(IsLoopback("0.0.0.0"));
  EXPECT_FALSE(IsLoopback("192.168.1.10"));
  EXPECT_FALSE(IsLoopback("::"));
  EXPECT_FALSE(IsLoopback("128.0.0.1"));
  EXPECT_FALSE(IsLoopback("127.0.0.1.evil.example"));
  EXPECT_FALSE(IsLoopback("localhost.evil.example"));
}

TEST(Security, CheckFramingOfARequestHead) {
  const std::string line = "GET / HTTP/1.1\r\n";
  EXPECT_TRUE(CheckFraming(line + "Host: a\r\nContent-Length: 3\r\n\r\n").ok());
  EXPECT_TRUE(CheckFraming("GET / HTTP/1.0\r\n\r\n").ok());
  EXPECT_TRUE(CheckFraming(line + "hOsT: a\r\nX-A_b.c~1: \t v \r\n\r\n").ok());
  EXPECT_TRUE(CheckFraming("incomplete").ok());  // the parser's to refuse
  const auto problem = [](const std::string& head) { return CheckFraming(head).Message(); };
  EXPECT_EQ(problem(line + "Host: a\r\ncontent-length: 1\r\nContent-Length: 1\r\n\r\n"),
            "more than one Content-Length");
  EXPECT_NE(problem(line + "Host: a\r\nTransfer-Encoding : chunked\r\n\r\n").find("not a token"),
            std::string::npos);
  EXPECT_NE(problem(line + "Host: a\r\nX: 1\r\n\t2\r\n\r\n").find("folded"), std::string::npos);
  EXPECT_NE(problem(line + "Host: a\r\nX-A b: 1\r\n\r\n").find("not a token"), std::string::npos);
  EXPECT_NE(problem(line + "Host: a\r\n: 1\r\n\r\n").find("not a token"), std::string::npos);
  EXPECT_EQ(problem(line + "Host: a\r\nno colon\r\n\r\n"), "a header line without a colon");
  EXPECT_EQ(problem(line + "\r\n"), "a request of HTTP version 1.1 needs a Host header");
  EXPECT_EQ(problem(line + "Host: a\r\nHost: b\r\n\r\n"), "more than one Host header");
  // Content-Length is 1*DIGIT between optional whitespace; control characters but HTAB nowhere.
  EXPECT_TRUE(CheckFraming(line + "Host: a\r\nContent-Length: \t12 \r\n\r\n").ok());
  for (const char* length : {"+2", "-0", "0x2", "2, 2", "2 2", "", " "}) {
    SCOPED_TRACE(length);
    EXPECT_NE(problem(line + "Host: a\r\nContent-Length:" + length + "\r\n\r\n")
                  .find("not a decimal number"),
              std::string::npos);
  }
  EXPECT_EQ(problem(line + "Host: a\r\nX-A: 1\r2\r\n\r\n"), "a bare CR in the header line 'X-A'");
  EXPECT_EQ(problem(line + "Host: a\r\nX-A: 1\n2\r\n\r\n"), "a bare LF in the header line 'X-A'");
  EXPECT_EQ(problem(line + "Host: a\r\n" + "X-A: 1" + std::string(1, '\0') + "2\r\n\r\n"),
            "a NUL in the header line 'X-A'");
  EXPECT_EQ(problem(line + "Host: a\r\nX-A: \x7f\r\n\r\n"),
            "the control character 0x7F in the header line 'X-A'");
  EXPECT_EQ(problem("GET /\r HTTP/1.1\r\nHost: a\r\n\r\n"), "a bare CR in the request line");
}

TEST(Security, EntityTagLists) {
  // If-None-Match: weak comparison, lists, "*".
  EXPECT_TRUE(EntityTagListMatches("\"7\"", "\"7\"", true));
  EXPECT_TRUE(EntityTagListMatches("W/\"7\"", "\"7\"", true));
  EXPECT_TRUE(EntityTagListMatches("\"1\", W/\"7\" ,\"9\"", "\"7\"", true));
  EXPECT_TRUE(EntityTagListMatches("*", "\"7\"", true));
  EXPECT_FALSE(EntityTagListMatches("\"17\"", "\"7\"", true));
  EXPECT_FALSE(EntityTagListMatches("", "\"7\"", true));
  // If-Match: strong comparison; an empty value matches nothing.
  EXPECT_TRUE(EntityTagListMatches("\"b1\", \"b2\"", "\"b2\"", false));
  EXPECT_TRUE(EntityTagListMatches("*", "\"b2\"", false));
  EXPECT_FALSE(EntityTagListMatches("W/\"b2\"", "\"b2\"", false));
  EXPECT_FALSE(EntityTagListMatches("", "\"b2\"", false));
  EXPECT_FALSE(EntityTagListMatches(" , ", "\"b2\"", false));
}

TEST(Security, PublicWebPathsAndIpAddresses) {
  EXPECT_TRUE(IsPublicWebPath("/"));
  EXPECT_TRUE(IsPublicWebPath("/app.js"));
  EXPECT_TRUE(IsPublicWebPath("/vendor/uplot/uPlot.iife.js"));
  EXPECT_FALSE(IsPublicWebPath("/node_modules/uplot/package.json"));
  EXPECT_FALSE(IsPublicWebPath("/a/node_modules/b"));
  EXPECT_FALSE(IsPublicWebPath("/package.json"));
  EXPECT_FALSE(IsPublicWebPath("/.git/config"));
  EXPECT_FALSE(IsPublicWebPath("//package-lock.json"));
  EXPECT_TRUE(IsIpAddress("192.168.1.5"));
  EXPECT_TRUE(IsIpAddress("fe80::1"));
  EXPECT_FALSE(IsIpAddress("robot.local"));
  EXPECT_FALSE(IsIpAddress("192.168.1.5.evil.example"));
  EXPECT_FALSE(IsIpAddress(""));
}

TEST(Security, HostNameOfAHostHeader) {
  EXPECT_EQ(HostName("localhost:8080"), "localhost");
  EXPECT_EQ(HostName("127.0.0.1"), "127.0.0.1");
  EXPECT_EQ(HostName("[::1]:8080"), "::1");
  EXPECT_EQ(HostName("[::1]"), "::1");
  EXPECT_EQ(HostName("::1"), "::1");
  EXPECT_EQ(HostName("evil.example:80"), "evil.example");
  EXPECT_EQ(HostName(""), "");
  EXPECT_EQ(HostName("[unclosed"), "[unclosed");
}

TEST(BudgetRequest, IntegersBeyondInt64AreNamedAsSentNotWrapped) {
  // 2^64 - 1 is an unsigned JSON number: read as int64 it was -1 ("-1 is outside [1, 1000]").
  const auto errors_of = [](const std::string& text) {
    nlohmann::json body = {{"mode", "rays"},
                           {"rays_per_scan", 65000},
                           {"cpu_share", 0.25},
                           {"policy", "adaptive"},
                           {"max_particles", 16}};
    const nlohmann::json patch = nlohmann::json::parse(text);
    body.update(patch);
    const Result<BudgetSettings> b = BudgetFromJson(body);
    return b.ok() ? ConfigErrors{} : b.errors();
  };
  ConfigErrors e = errors_of(R"({"max_particles": 18446744073709551615})");
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].pointer, "/max_particles");
  EXPECT_EQ(e[0].detail, "18446744073709551615 is outside [1, 1000]");
  e = errors_of(R"({"max_particles": -9223372036854775808})");
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].detail, "-9223372036854775808 is outside [1, 1000]");
  e = errors_of(R"({"max_particles": 4294967297})");  // 2^32 + 1: was 1 << 30 after a clamp
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].detail, "4294967297 is outside [1, 1000]");
  e = errors_of(R"({"rays_per_scan": 18446744073709551615})");
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].pointer, "/rays_per_scan");
  EXPECT_EQ(e[0].detail, "18446744073709551615 is outside [1, 100000000]");
  EXPECT_TRUE(errors_of(R"({"max_particles": 1000, "rays_per_scan": 100000000})").empty());
}

TEST(TuneRequest, DefaultsAndErrorsWithPointers) {
  const Result<TuneRequest> defaults = ParseTuneRequest(nlohmann::json::object(), {"a"});
  ASSERT_TRUE(defaults.ok()) << defaults.Message();
  EXPECT_EQ(defaults.value().budget, 8125);
  EXPECT_TRUE(defaults.value().experiments.empty());

  const auto body = nlohmann::json::parse(
      R"({"budget": 0, "population": "many", "generations": 2.5, "policy": "greedy",
          "experiments": ["a", "zz", 3], "colour": "red"})");
  const ConfigErrors errors = ParseTuneRequest(body, {"a", "b"}).errors();
  std::vector<std::string> pointers;
  for (const auto& e : errors) pointers.push_back(e.pointer);
  EXPECT_EQ(pointers, (std::vector<std::string>{"/colour", "/budget", "/population", "/generations",
                                                "/policy", "/experiments/1", "/experiments/2"}));
  EXPECT_FALSE(ParseTuneRequest(nlohmann::json::array(), {}).ok());
}

class SlamServiceTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir("slam_service");
    experiment_ = new std::optional<offline::Experiment>(
        testing::GenerateExperiment(dir_->File("exp"), "box", 20.0, 11));
  }
  static void TearDownTestSuite() {
    delete experiment_;
    delete dir_;
  }

  /// A link replaying the experiment's log as fast as it is read, losing nothing.
  std::unique_ptr<hw::Link> MakeLink() {
    auto opened = hw::OpenCandumpReplay(dir_->File("exp/can.log"));
    auto source = std::move(opened).value();
    hw::LinkOptions options;
    options.queue_capacity = 1 << 16;
    return std::make_unique<hw::Link>(std::move(source), testing::ShippedRobot(), options);
  }

  static ServiceOptions Options() {
    ServiceOptions o;
    o.robot = testing::ShippedRobot();
    o.budget.rays_per_scan = 8125;
    return o;
  }

  /// Waits (bounded) until the service has processed every scan of the log.
  static std::shared_ptr<const SlamSnapshot> WaitForScans(const SlamService& service,
                                                          int64_t scans) {
    auto snapshot = service.Snapshot();
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (service.Counters().scans < scans && std::chrono::steady_clock::now() < deadline) {
      snapshot = service.WaitNewer(snapshot->sequence, std::chrono::milliseconds(200));
    }
    return service.Snapshot();
  }

  static TempDir* dir_;
  static std::optional<offline::Experiment>* experiment_;
};

TempDir* SlamServiceTest::dir_ = nullptr;
std::optional<offline::Experiment>* SlamServiceTest::experiment_ = nullptr;

TEST_F(SlamServiceTest, MapsTheLogAndPublishesSnapshots) {
  ASSERT_TRUE(*experiment_);
  const int64_t scans = static_cast<int64_t>((*experiment_)->scans.size());
  auto link = MakeLink();
  ServiceOptions options = Options();
  options.detect_loss = false;  // as the replay it is compared with (the check takes rays)
  SlamService service(*link, nullptr, options);
  const auto first = service.Snapshot();
  EXPECT_TRUE(first->tiles.empty());
  EXPECT_EQ(service.Counters().state, SlamState::kWaiting);
  link->Start();
  service.Start();
  const auto last = WaitForScans(service, scans);
  service.Stop();
  link->Stop();

  const ServiceCounters c = service.Counters();
  EXPECT_EQ(c.scans, scans);
  EXPECT_EQ(c.state, SlamState::kRunning);
  EXPECT_LE(c.rays_used, c.rays_planned);
  EXPECT_GT(c.rays_used, scans * 8125 * 9 / 10 / 2);  // most scans fill most of the quota
  ASSERT_TRUE(last->last);
  EXPECT_EQ(last->last->quota, 8125);
  EXPECT_LE(last->last->rays_used, 8125);
  EXPECT_GT(last->tiles.size(), 4u);
  EXPECT_GT(last->map_version, first->map_version);
  EXPECT_GT(last->sequence, static_cast<uint64_t>(scans));
  // One pose per scan end plus the start, time-ordered, ending at the snapshot's pose.
  const std::vector<TimedPose> trajectory = ScanEndTrajectory(*last);
  EXPECT_EQ(static_cast<int64_t>(trajectory.size()), scans + 1);
  for (size_t i = 1; i < trajectory.size(); ++i) EXPECT_GT(trajectory[i].t, trajectory[i - 1].t);
  EXPECT_EQ(trajectory.back().pose.x, last->pose.pose.x);
  // The live path (log -> link -> assembler -> scheduler -> engine) builds exactly the map that
  // Replay builds from the experiment read from disk, at the same budget and seed.
  offline::ReplayOptions replay;
  replay.params = ParamsChoice{};  // the shipped set of the budget, as slamd without --params
  replay.budget = Options().budget;
  replay.config.parallel = false;
  const offline::ReplayResult expected =
      offline::Replay((*experiment_)->robot, (*experiment_)->scans, {}, replay);
  const OccupancyGrid grid = SnapshotGrid(*last, service.encoded_logodds_limit());
  ASSERT_EQ(grid.TileCount(), expected.map.TileCount());
  for (const TileRef& t : expected.map.Tiles()) {
    ASSERT_NE(grid.FindTile(t.index), nullptr);
    EXPECT_EQ(grid.FindTile(t.index)->cells, t.tile->cells) << t.index.x << ", " << t.index.y;
  }
  EXPECT_EQ(last->pose.pose.x, expected.trajectory.back().pose.x);
  // The last scan's readings, for Foxglove's /scan: a few per sensor sample.
  ASSERT_TRUE(last->scan_points);
  EXPECT_GT(last->scan_points->size(), 20u);
}

TEST_F(SlamServiceTest, WithoutScanPointsTheSnapshotsCarryNoneAndTheMapIsTheSame) {
  ASSERT_TRUE(*experiment_);
  const int64_t scans = static_cast<int64_t>((*experiment_)->scans.size());
  std::shared_ptr<const SlamSnapshot> with, without;
  for (const bool keep : {true, false}) {
    auto link = MakeLink();
    ServiceOptions options = Options();
    options.scan_points = keep;
    SlamService service(*link, nullptr, options);
    link->Start();
    service.Start();
    (keep ? with : without) = WaitForScans(service, scans);
    service.Stop();
    link->Stop();
    EXPECT_EQ(service.Counters().scans, scans);
  }
  ASSERT_TRUE(with->scan_points);
  EXPECT_FALSE(without->scan_points);
  EXPECT_EQ(without->pose.pose.x, with->pose.pose.x);
  EXPECT_EQ(without->tiles.size(), with->tiles.size());
}

TEST_F(SlamServiceTest, TheBudgetsRevisionMovesWithEveryChangeAndOnlyThen) {
  auto link = MakeLink();
  SlamService service(*link, nullptr, Options());
  const SlamService::RevisedBudget start = service.BudgetRevised();
  const auto always = [](uint64_t) { return true; };
  const auto to = [](int64_t rays) {
    return [rays](const BudgetSettings& current) -> Result<BudgetSettings> {
      BudgetSettings next = current;
      next.rays_per_scan = rays;
      return next;
    };
  };
  // The same budget again: nothing changes, not even the revision.
  SlamService::BudgetChange same = service.ChangeBudget(always, to(start.budget.rays_per_scan));
  EXPECT_FALSE(same.precondition_failed);
  EXPECT_EQ(same.revision, start.revision);
  // A change bumps it; a stale precondition changes nothing.
  const SlamService::BudgetChange changed =
      service.ChangeBudget([&](uint64_t revision) { return revision == start.revision; }, to(9000));
  EXPECT_EQ(changed.revision, start.revision + 1);
  EXPECT_EQ(service.Budget().rays_per_scan, 9000);
  const SlamService::BudgetChange stale = service.ChangeBudget(
      [&](uint64_t revision) { return revision == start.revision; }, to(12000));
  EXPECT_TRUE(stale.precondition_failed);
  EXPECT_EQ(stale.revision, changed.revision);
  EXPECT_EQ(service.Budget().rays_per_scan, 9000);
  // What the change finds wrong is reported, and nothing changes.
  const SlamService::BudgetChange wrong = service.ChangeBudget(
      always, [](const BudgetSettings&) -> Result<BudgetSettings> { return Error("no"); });
  EXPECT_FALSE(wrong.errors.empty());
  EXPECT_EQ(service.BudgetRevised().revision, changed.revision);
  service.SetBudget(start.budget);
  EXPECT_EQ(service.BudgetRevised().revision, changed.revision + 1);
}

TEST_F(SlamServiceTest, ParamsChangesAreConditionalNamedAndRevisedByTheService) {
  auto link = MakeLink();
  SlamService service(*link, nullptr, Options());
  const SlamService::RevisedParams start = service.ParamsRevised();
  const auto with_particles = [](int particles) {
    return [particles](const SlamParams& current, const SlamParams&) -> Result<SlamParams> {
      SlamParams next = current;
      next.particles = particles;
      return next;
    };
  };
  const auto at = [](uint64_t expected) {
    return [expected](uint64_t revision) { return revision == expected; };
  };
  const SlamService::ParamsChange changed =
      service.ChangeParams(at(start.revision), with_particles(start.set.params.particles + 1));
  ASSERT_TRUE(changed.errors.empty());
  EXPECT_EQ(changed.revision, start.revision + 1);
  EXPECT_EQ(service.ParamsRevised().set.name, start.set.name + ", patched");
  EXPECT_FALSE(service.ParamsFollowQuota());
  // A stale revision changes nothing; nor does a change that finds something wrong.
  EXPECT_TRUE(service.ChangeParams(at(start.revision), with_particles(7)).precondition_failed);
  const SlamService::ParamsChange wrong = service.ChangeParams(
      at(changed.revision),
      [](const SlamParams&, const SlamParams&) -> Result<SlamParams> { return Error("no"); });
  EXPECT_FALSE(wrong.errors.empty());
  EXPECT_EQ(service.ParamsRevised().revision, changed.revision);
  EXPECT_EQ(service.Params().params.particles, start.set.params.particles + 1);
  // Patched back to the shipped set: the sets follow the budget again.
  const SlamService::ParamsChange back = service.ChangeParams(
      at(changed.revision),
      [](const SlamParams&, const SlamParams& shipped) -> Result<SlamParams> { return shipped; });
  EXPECT_EQ(back.revision, changed.revision + 1);
  EXPECT_TRUE(service.ParamsFollowQuota());
  EXPECT_EQ(service.ResetParams().revision, back.revision);  // already there: no new revision
}

TEST_F(SlamServiceTest, BudgetChangesApplyFromTheNextScanAndResetKeepsVersionsGrowing) {
  ASSERT_TRUE(*experiment_);
  auto link = MakeLink();
  SlamService service(*link, nullptr, Options());
  link->Start();
  service.Start();
  auto mid = WaitForScans(service, 5);
  BudgetSettings budget = service.Budget();
  budget.rays_per_scan = 3000;
  service.SetBudget(budget);
  const uint64_t before_reset = service.Snapshot()->map_version;
  service.RequestReset();
  auto snapshot = service.Snapshot();
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while (snapshot->epoch == 0 && std::chrono::steady_clock::now() < deadline) {
    snapshot = service.WaitNewer(snapshot->sequence, std::chrono::milliseconds(200));
  }
  ASSERT_EQ(snapshot->epoch, 1u);
  EXPECT_GT(snapshot->map_version, before_reset);
  EXPECT_GE(snapshot->version_base, before_reset);
  const auto after = WaitForScans(service, service.Counters().scans + 3);
  service.Stop();
  link->Stop();
  ASSERT_TRUE(after->last);
  EXPECT_EQ(after->last->quota, 3000);
  EXPECT_LE(after->last->rays_used, 3000);
  EXPECT_EQ(service.Counters().resets, 1);
  for (const TileRef& t : after->tiles) EXPECT_GT(after->ReportedVersion(*t.tile), before_reset);
  // The trajectory restarted with the reset: only this epoch's scans.
  EXPECT_LT(ScanEndTrajectory(*after).size(), static_cast<size_t>(after->last->scan) + 2);
}

TEST_F(SlamServiceTest, ResumesASavedMap) {
  ASSERT_TRUE(*experiment_);
  TempDir state("slam_service_state");
  std::shared_ptr<const SlamSnapshot> saved;
  {
    auto link = MakeLink();
    SlamService service(*link, nullptr, Options());
    link->Start();
    service.Start();
    saved = WaitForScans(service, 10);
    service.Stop();
    link->Stop();
    const OccupancyGrid grid = SnapshotGrid(*saved, service.encoded_logodds_limit());
    SaveInputs in;
    in.version = saved->map_version;
    in.grid = &grid;
    in.version_base = saved->version_base;
    in.trajectory = ScanEndTrajectory(*saved);
    ASSERT_TRUE(SaveState(state.path().string(), in).ok());
  }
  Result<std::optional<SavedState>> loaded = LoadState(state.path().string());
  ASSERT_TRUE(loaded.ok() && loaded.value()) << loaded.Message();
  ServiceOptions options = Options();
  options.resume = loaded.value();
  options.resume_pose = Pose2{};  // the log starts over where the map's origin is
  auto link = MakeLink();
  SlamService service(*link, nullptr, options);
  const auto resumed = service.Snapshot();
  EXPECT_EQ(resumed->tiles.size(), saved->tiles.size());
  EXPECT_GT(resumed->map_version, saved->map_version);
  ASSERT_TRUE(resumed->has_pose);
  EXPECT_NEAR(resumed->pose.pose.x, saved->pose.pose.x, 1e-5);  // TUM keeps 6 decimals
  // Cells are restored exactly.
  const OccupancyGrid a = SnapshotGrid(*saved, service.encoded_logodds_limit());
  const OccupancyGrid b = SnapshotGrid(*resumed, service.encoded_logodds_limit());
  for (const TileRef& t : a.Tiles()) {
    ASSERT_NE(b.FindTile(t.index), nullptr);
    EXPECT_EQ(b.FindTile(t.index)->cells, t.tile->cells);
  }
  // The trajectory continues after the saved one.
  link->Start();
  service.Start();
  const auto later = WaitForScans(service, 3);
  service.Stop();
  link->Stop();
  const std::vector<TimedPose> trajectory = ScanEndTrajectory(*later);
  EXPECT_GT(trajectory.size(), loaded.value()->trajectory.size());
  for (size_t i = 1; i < trajectory.size(); ++i) EXPECT_GT(trajectory[i].t, trajectory[i - 1].t);
}

TEST_F(SlamServiceTest, InMemoryRequestsTakeTheWholeServerPath) {
  // HttpServer::HandleInMemory (the fuzzer's way in) goes through the parser, the guard, routing
  // and the handlers, as a request on a connection does.
  ASSERT_TRUE(experiment_->has_value());
  auto link = MakeLink();
  SlamService service(*link, nullptr, Options());
  JobManager jobs("", "");
  HttpOptions options;
  options.token = "in-memory-token-0123";
  HttpServer server(service, *link, jobs, options);
  const auto status_of = [](const std::string& response) {
    return response.rfind("HTTP/1.1 ", 0) == 0 ? std::stoi(response.substr(9, 3)) : -1;
  };
  const std::string health =
      server.HandleInMemory("GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
  EXPECT_EQ(status_of(health), 200) << health;
  EXPECT_NE(health.find("{\"status\":\"ok\"}"), std::string::npos) << health;
  const std::string json_body = R"({"rays_per_scan": 9000})";
  const std::string patch =
      "PATCH /api/v1/budget HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: "
      "application/merge-patch+json\r\n"
      "Content-Length: " +
      std::to_string(json_body.size()) + "\r\n";
  const std::string body = "\r\n" + json_body;
  // The guard: no token, 401; then the handler: applied.
  EXPECT_EQ(status_of(server.HandleInMemory(patch + body)), 401);
  EXPECT_EQ(service.Budget().rays_per_scan, 8125);
  const std::string applied =
      server.HandleInMemory(patch + "Authorization: Bearer in-memory-token-0123\r\n" + body);
  EXPECT_EQ(status_of(applied), 200) << applied;
  EXPECT_EQ(service.Budget().rays_per_scan, 9000);
  // The parser's limits: an oversize URI is 414, garbage is 400, and unknown routes are problems.
  EXPECT_EQ(
      status_of(server.HandleInMemory("GET /" + std::string(10000, 'a') + " HTTP/1.1\r\n\r\n")),
      414);
  EXPECT_EQ(status_of(server.HandleInMemory("\x01\x02 garbage\r\n\r\n")), 400);
  const std::string unknown =
      server.HandleInMemory("GET /api/v1/nope HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
  EXPECT_EQ(status_of(unknown), 404);
  EXPECT_NE(unknown.find("application/problem+json"), std::string::npos) << unknown;
  // The response is cut at the cap.
  EXPECT_LE(server.HandleInMemory("GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n", 100).size(),
            100u);
}

}  // namespace
}  // namespace slam::server
