// slamd's state directory against what others may plant in it (issue 46): links, FIFOs, devices
// and oversized files in place of slamd.lock, state.json and the files it names, or of jobs/;
// saved poses beyond the map's bound; tuning jobs that write their outputs there.

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <future>
#include <string>
#include <thread>

#include "engine/cell_encoding.hpp"
#include "engine/grid_geometry.hpp"
#include "engine/io/atomic_file.hpp"
#include "engine/occupancy_grid.hpp"
#include "server/state_store.hpp"
#include "server/tune_jobs.hpp"
#include "tests/experiment_support.hpp"
#include "tests/test_support.hpp"

namespace slam::server {
namespace {

namespace fs = std::filesystem;
using testing::TempDir;

std::string Contents(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

/// A small saved state in `dir` (version 10, one tile, three poses).
void SaveSample(const std::string& dir) {
  OccupancyGrid grid(GridGeometry(0.01), kLogOddsLimit);
  grid.BeginWrite();
  grid.Add({3, 4}, EncodeLogOdds(3.0));
  grid.Add({5, 4}, EncodeLogOdds(-3.0));
  SaveInputs in;
  in.version = 10;
  in.resolution_m = 0.01;
  in.grid = &grid;
  in.trajectory = {{0.5, {0, 0, 0}}, {1.0, {0.1, 0.2, 0.3}}, {1.5, {0.2, 0.3, -0.4}}};
  const Result<SaveReport> saved = SaveState(dir, in);
  ASSERT_TRUE(saved.ok()) << saved.Message();
  ASSERT_TRUE(saved.value().warnings.empty()) << saved.value().warnings.front();
}

/// LoadState(dir) on another thread; a FIFO it blocks on is opened for writing and closed (so
/// that the reader sees its end) after `patience`, and the test fails: loading must not wait.
Result<std::optional<SavedState>> LoadWithoutHanging(const std::string& dir,
                                                     const std::string& fifo) {
  auto loading = std::async(std::launch::async, [&] { return LoadState(dir); });
  if (loading.wait_for(std::chrono::seconds(5)) != std::future_status::ready) {
    ADD_FAILURE() << "LoadState blocked on the FIFO " << fifo;
    const int fd = ::open(fifo.c_str(), O_WRONLY | O_NONBLOCK);
    if (fd >= 0) ::close(fd);
  }
  return loading.get();
}

// --- slamd.lock -------------------------------------------------------------------------------

TEST(StateDirLinks, ALinkAtTheLockFileIsRefusedAndItsTargetKept) {
  TempDir dir("lock_link");
  const std::string state = dir.File("state");
  fs::create_directories(state);
  WriteText(dir.File("precious"), "precious contents\n");
  fs::create_symlink(dir.File("precious"), state + "/slamd.lock");
  const auto locked = StateDirLock::Acquire(state);
  ASSERT_FALSE(locked.ok());
  EXPECT_TRUE(Contains(locked.Message(), "slamd.lock is a symbolic link")) << locked.Message();
  // Was truncated to slamd's pid.
  EXPECT_EQ(Contents(dir.File("precious")), "precious contents\n");

  // A link to a missing path does not create it.
  fs::remove(state + "/slamd.lock");
  fs::create_symlink(dir.File("created"), state + "/slamd.lock");
  EXPECT_FALSE(StateDirLock::Acquire(state).ok());
  EXPECT_FALSE(fs::exists(dir.File("created")));
}

TEST(StateDirLinks, AFifoOrAHardLinkAtTheLockFileIsRefused) {
  TempDir dir("lock_fifo");
  ASSERT_EQ(::mkfifo(dir.File("slamd.lock").c_str(), 0644), 0);
  auto locked = StateDirLock::Acquire(dir.path().string());
  ASSERT_FALSE(locked.ok());
  EXPECT_TRUE(Contains(locked.Message(), "slamd.lock is not a regular file")) << locked.Message();

  fs::remove(dir.File("slamd.lock"));
  WriteText(dir.File("precious"), "precious contents\n");
  ASSERT_EQ(::link(dir.File("precious").c_str(), dir.File("slamd.lock").c_str()), 0);
  locked = StateDirLock::Acquire(dir.path().string());
  ASSERT_FALSE(locked.ok());
  EXPECT_TRUE(Contains(locked.Message(), "slamd.lock has 2 names")) << locked.Message();
  EXPECT_EQ(Contents(dir.File("precious")), "precious contents\n");

  // A plain lock file, left by an earlier slamd, is taken as before.
  fs::remove(dir.File("slamd.lock"));
  WriteText(dir.File("slamd.lock"), "12345\n");
  EXPECT_TRUE(StateDirLock::Acquire(dir.path().string()).ok());
}

// --- state.json and the files it names ---------------------------------------------------------

TEST(StateDirLinks, ATilesFileLinkedToDevZeroIsRefusedNamingIt) {
  TempDir dir("tiles_zero");
  SaveSample(dir.path().string());
  fs::remove(dir.File("map-10.tiles"));
  fs::create_symlink("/dev/zero", dir.File("map-10.tiles"));
  const auto loaded = LoadState(dir.path().string());
  ASSERT_FALSE(loaded.ok());
  EXPECT_TRUE(Contains(loaded.Message(), dir.File("map-10.tiles") + ": is a symbolic link"))
      << loaded.Message();
}

TEST(StateDirLinks, FifosInPlaceOfSavedFilesAreRefusedWithoutWaiting) {
  TempDir dir("fifos");
  for (const char* name : {"map-10.tiles", "trajectory-10.tum", "state.json"}) {
    SaveSample(dir.path().string());
    const std::string path = dir.File(name);
    fs::remove(path);
    ASSERT_EQ(::mkfifo(path.c_str(), 0644), 0);
    const auto loaded = LoadWithoutHanging(dir.path().string(), path);
    ASSERT_FALSE(loaded.ok()) << name;
    EXPECT_TRUE(Contains(loaded.Message(), path + ": is a FIFO, not a regular file"))
        << loaded.Message();
    fs::remove(path);
  }
}

TEST(StateDirLinks, LinkedStateJsonAndTrajectoryAreRefused) {
  TempDir dir("json_link");
  SaveSample(dir.path().string());
  // A link to a good copy elsewhere is refused all the same: nothing here is read through links.
  fs::rename(dir.File("trajectory-10.tum"), dir.File("elsewhere.tum"));
  fs::create_symlink(dir.File("elsewhere.tum"), dir.File("trajectory-10.tum"));
  auto loaded = LoadState(dir.path().string());
  ASSERT_FALSE(loaded.ok());
  EXPECT_TRUE(Contains(loaded.Message(), "trajectory-10.tum: is a symbolic link"))
      << loaded.Message();

  // A dangling link at state.json is not "nothing saved".
  fs::remove(dir.File("state.json"));
  fs::create_symlink(dir.File("missing.json"), dir.File("state.json"));
  loaded = LoadState(dir.path().string());
  ASSERT_FALSE(loaded.ok());
  EXPECT_TRUE(Contains(loaded.Message(), "state.json: is a symbolic link")) << loaded.Message();
}

TEST(StateDirLinks, FilesLargerThanASaveWritesAreRefusedUnread) {
  // Sparse files: a tile file beyond what the map's bound allows (65536 tiles of 8208 bytes,
  // 538 MB), a trajectory beyond 256 MiB, a state.json beyond 64 KiB. Refused by their size,
  // before any of it is read.
  TempDir dir("oversize");
  const struct {
    const char* name;
    off_t size;
  } cases[] = {{"map-10.tiles", off_t{600} << 20},
               {"trajectory-10.tum", off_t{257} << 20},
               {"state.json", off_t{65} << 10}};
  for (const auto& c : cases) {
    SaveSample(dir.path().string());
    ASSERT_EQ(::truncate(dir.File(c.name).c_str(), c.size), 0);
    const auto loaded = LoadState(dir.path().string());
    ASSERT_FALSE(loaded.ok()) << c.name;
    EXPECT_TRUE(Contains(loaded.Message(), dir.File(c.name) + ": " + std::to_string(c.size) +
                                               " bytes, more than the"))
        << loaded.Message();
  }
  // The tile file's bound is what the map's bound allows: 2 x 128 tiles a side, 8208 bytes each,
  // and 44 bytes of header and checksum.
  SaveSample(dir.path().string());
  ASSERT_EQ(::truncate(dir.File("map-10.tiles").c_str(), off_t{600} << 20), 0);
  EXPECT_TRUE(Contains(LoadState(dir.path().string()).Message(), "more than the 537919532 "))
      << LoadState(dir.path().string()).Message();
}

TEST(StateDirLinks, SavedCopiesReplaceLinksRatherThanWriteThroughThem) {
  TempDir dir("copies");
  const std::string state = dir.File("state");
  fs::create_directories(state);
  for (const char* name : {"map.pgm", "map.yaml", "map.png", "trajectory.tum", "state.json"}) {
    WriteText(dir.File(std::string("victim-") + name), "precious\n");
    fs::create_symlink(dir.File(std::string("victim-") + name), state + "/" + name);
  }
  SaveSample(state);
  for (const char* name : {"map.pgm", "map.yaml", "map.png", "trajectory.tum", "state.json"}) {
    EXPECT_EQ(Contents(dir.File(std::string("victim-") + name)), "precious\n") << name;
    EXPECT_TRUE(fs::is_regular_file(fs::symlink_status(state + "/" + name))) << name;
  }
  const auto loaded = LoadState(state);
  ASSERT_TRUE(loaded.ok() && loaded.value()) << loaded.Message();
  EXPECT_EQ(loaded.value()->version, 10u);
}

// --- saved poses -------------------------------------------------------------------------------

TEST(SavedPoses, ATrajectoryBeyondTheMapsBoundIsRefusedNamingTheLine) {
  // At 1 cm cells the map's bound is 128 tiles of 64 cells each way: [-81.92, 81.92) m.
  TempDir dir("poses");
  SaveSample(dir.path().string());
  const std::string q = " 0 0 0 0 1\n";
  WriteText(dir.File("trajectory-10.tum"),
            "# t x y z qx qy qz qw\n0.5 0 0" + q + "1.0 81.91 -81.92" + q + "1.5 1e9 0" + q);
  auto loaded = LoadState(dir.path().string());
  ASSERT_FALSE(loaded.ok());
  EXPECT_TRUE(Contains(loaded.Message(), dir.File("trajectory-10.tum") +
                                             ":4: position (1e+09, 0) is outside the map's bound"))
      << loaded.Message();

  WriteText(dir.File("trajectory-10.tum"), "0.5 0 0" + q + "1.0 3 81.92" + q);
  loaded = LoadState(dir.path().string());
  ASSERT_FALSE(loaded.ok());
  EXPECT_TRUE(Contains(loaded.Message(), "trajectory-10.tum:2: position")) << loaded.Message();

  // Just inside, on both sides: loaded.
  WriteText(dir.File("trajectory-10.tum"), "0.5 -81.92 -81.92" + q + "1.0 81.919 81.919" + q);
  loaded = LoadState(dir.path().string());
  ASSERT_TRUE(loaded.ok() && loaded.value()) << loaded.Message();
  EXPECT_EQ(loaded.value()->trajectory.size(), 2u);
}

// --- tuning jobs' outputs ----------------------------------------------------------------------

class TuneJobOutputs : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    experiments_ = new TempDir("tune_experiments");
    // Four seconds in the box: a job of 2 individuals, 1 generation takes about a second.
    experiment_ok_ =
        testing::GenerateExperiment(experiments_->File("box-1"), "box", 4.0, 1).has_value();
  }
  static void TearDownTestSuite() {
    delete experiments_;
    experiments_ = nullptr;
  }

  /// Runs the smallest job to its end; the job's last JSON.
  static nlohmann::json RunSmallJob(JobManager& jobs) {
    const Result<TuneRequest> request = ParseTuneRequest(
        nlohmann::json::parse(R"({"population": 2, "generations": 1, "budget": 2000})"),
        jobs.Experiments());
    EXPECT_TRUE(request.ok()) << request.Message();
    const Result<nlohmann::json> started = jobs.Start(request.value());
    EXPECT_TRUE(started.ok()) << started.Message();
    if (!started.ok()) return {};
    const std::string id = started.value().value("id", "");
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    nlohmann::json job;
    do {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
      job = *jobs.Get(id);
    } while (job.value("state", "") == "running" && std::chrono::steady_clock::now() < deadline);
    return job;
  }

  static inline TempDir* experiments_ = nullptr;
  static inline bool experiment_ok_ = false;
};

TEST_F(TuneJobOutputs, AJobOfASlamdWithAStateDirectoryEndsDoneWithItsFiles) {
  // Every such job ended failed: its outputs went into jobs/<id>/ before that existed.
  ASSERT_TRUE(experiment_ok_);
  TempDir state("tune_state");
  JobManager jobs(experiments_->path().string(), state.path().string());
  const nlohmann::json job = RunSmallJob(jobs);
  ASSERT_EQ(job.value("state", ""), "done") << job.dump();
  EXPECT_EQ(job.value("error", "?"), "");
  const fs::path out = state.path() / "jobs" / job.value("id", "");
  for (const char* name :
       {"results.json", "table2.md", "table3.md", "fig10.svg", "fig10.png", "params/2000.json"}) {
    EXPECT_TRUE(fs::is_regular_file(out / name)) << (out / name);
    EXPECT_GT(fs::file_size(out / name), 0u) << (out / name);
  }
  const auto results = nlohmann::json::parse(Contents((out / "results.json").string()));
  EXPECT_TRUE(results.is_object());

  // A second manager on the same folder (slamd restarted) goes on from the ids there.
  JobManager again(experiments_->path().string(), state.path().string());
  const nlohmann::json next = RunSmallJob(again);
  EXPECT_EQ(next.value("state", ""), "done") << next.dump();
  EXPECT_EQ(std::stoi(next.value("id", "0")), std::stoi(job.value("id", "0")) + 1);
}

TEST_F(TuneJobOutputs, ALinkedJobsFolderIsRefusedNotWrittenThrough) {
  ASSERT_TRUE(experiment_ok_);
  TempDir state("tune_link_state");
  TempDir elsewhere("tune_link_elsewhere");
  fs::create_symlink(elsewhere.path(), state.path() / "jobs");
  JobManager jobs(experiments_->path().string(), state.path().string());
  const nlohmann::json job = RunSmallJob(jobs);
  EXPECT_EQ(job.value("state", ""), "failed") << job.dump();
  EXPECT_TRUE(
      Contains(job.value("error", ""), (state.path() / "jobs").string() + ": is a symbolic link"))
      << job.dump();
  EXPECT_TRUE(fs::is_empty(elsewhere.path()));

  // The same for a link planted at jobs/<id>/ once slamd has started.
  fs::remove(state.path() / "jobs");
  JobManager second(experiments_->path().string(), state.path().string());
  fs::create_directories(state.path() / "jobs");
  fs::create_symlink(elsewhere.path(), state.path() / "jobs" / "1");
  const nlohmann::json linked = RunSmallJob(second);
  EXPECT_EQ(linked.value("id", ""), "1");
  EXPECT_EQ(linked.value("state", ""), "failed") << linked.dump();
  EXPECT_TRUE(Contains(linked.value("error", ""), "jobs/1: is a symbolic link")) << linked.dump();
  EXPECT_TRUE(fs::is_empty(elsewhere.path()));
}

}  // namespace
}  // namespace slam::server
