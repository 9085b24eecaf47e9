// slamd's state directory against what others may plant in it (issue 46): links, FIFOs, devices
// and oversized files in place of slamd.lock, state.json and the files it names, or of jobs/;
// saved poses beyond the map's bound; tuning jobs that write their outputs there; whole-map
// exports of a map spread over the whole bound; the map picture's size and scale bar.

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
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
#include "engine/io/canvas.hpp"
#include "engine/io/map_image.hpp"
#include "engine/occupancy_grid.hpp"
#include "server/state_store.hpp"
#include "server/tune_jobs.hpp"
#include "tests/experiment_support.hpp"
#include "tests/map_file_support.hpp"
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

  /// Runs a job (the smallest unless `request_json` says otherwise) to its end, for at most
  /// 60 s; the job's last JSON.
  static nlohmann::json RunSmallJob(
      JobManager& jobs,
      const std::string& request_json = R"({"population": 2, "generations": 1, "budget": 2000})") {
    const Result<TuneRequest> request =
        ParseTuneRequest(nlohmann::json::parse(request_json), jobs.Experiments());
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

/// An experiment folder `dir` of a CARMEN log (FLASER records of 181 readings of 2 m, one every
/// 0.2 s, odometry and laser pose at x = step_m * i) and the same poses as ground truth.
void WriteRunAlongX(const fs::path& dir, int records, double step_m) {
  fs::create_directories(dir);
  std::string log, truth;
  for (int i = 0; i < records; ++i) {
    const double t = 1.0 + 0.2 * i, x = step_m * i;
    log += "FLASER 181";
    for (int b = 0; b < 181; ++b) log += " 2.0";
    char rest[200];
    std::snprintf(rest, sizeof(rest), " %.17g 0 0 %.17g 0 0 %.3f host %.3f\n", x, x, t, t);
    log += rest;
    std::snprintf(rest, sizeof(rest), "%.3f %.17g 0 0 0 0 0 1\n", t, x);
    truth += rest;
  }
  WriteText((dir / "log.clf").string(), log);
  WriteText((dir / "groundtruth.tum").string(), truth);
}

TEST_F(TuneJobOutputs, AJobOverPosesFarBeyondTheMapEndsAndTheNextJobStarts) {
  // The probe's case: a tuning job over a run whose poses leave the map's bound hung the engine
  // for good (DELETE answered 202, the job stayed running, every new job was refused with 409).
  // Two such runs: the probe's own log (odometry and poses of 1e300 m: the reader refuses its
  // records, so the job fails naming them), and one the reader takes (250 km a step, within its
  // 1e7 m, far beyond the map: the engine refuses the scans, the job ends).
  TempDir experiments("tune_far_experiments");
  fs::create_directories(experiments.path() / "probe");
  WriteText((experiments.path() / "probe" / "log.clf").string(),
            "ODOM 1e300 -1e300 1e300 0 0 0 1.0 host 1.0\n"
            "FLASER 3 1.0 1.0 1.0 1e300 -1e300 1e300 1e300 -1e300 1e300 1.1 host 1.1\n"
            "FLASER 3 1.0 1.0 1.0 -1e300 1e300 -1e300 -1e300 1e300 -1e300 1.2 host 1.2\n"
            "FLASER 3 1.0 1.0 1.0 1 1 0 1e6 1e6 1e300 1.3 host 1.3\n");
  WriteText((experiments.path() / "probe" / "groundtruth.tum").string(),
            "1.1 0 0 0 0 0 0 1\n1.2 0 0 0 0 0 0 1\n1.3 0 0 0 0 0 0 1\n");
  WriteRunAlongX(experiments.path() / "far", 40, 2.5e5);

  for (const char* name : {"probe", "far"}) {
    SCOPED_TRACE(name);
    JobManager jobs(experiments.path().string(), "");
    const std::string request = std::string(R"({"population": 2, "generations": 1, "budget": 2000,
                                                 "experiments": [")") +
                                name + "\"]}";
    for (int round = 0; round < 2; ++round) {  // the second job starts: nothing is left running
      SCOPED_TRACE(round);
      const nlohmann::json job = RunSmallJob(jobs, request);
      if (std::string(name) == "probe") {
        EXPECT_EQ(job.value("state", ""), "failed") << job.dump();
        EXPECT_TRUE(Contains(job.value("error", ""), "no laser record")) << job.dump();
        EXPECT_TRUE(Contains(job.value("error", ""), "beyond")) << job.dump();
      } else {
        EXPECT_EQ(job.value("state", ""), "done") << job.dump();
      }
    }
  }
}

// --- whole-map exports ---------------------------------------------------------------------------

/// A 1 cm grid with one tile at each of two opposite corners of the map's bound, each with an
/// occupied cell and a free one.
OccupancyGrid CornerGrid() {
  OccupancyGrid grid(GridGeometry(0.01), kLogOddsLimit);
  grid.BeginWrite();
  const int32_t lo = -kMapTileBound * kTileSize;     // first cell of the bound
  const int32_t hi = kMapTileBound * kTileSize - 1;  // last cell
  grid.Add({lo + 5, lo + 7}, EncodeLogOdds(3.0));
  grid.Add({lo + 20, lo + 7}, EncodeLogOdds(-3.0));
  grid.Add({hi - 9, hi - 2}, EncodeLogOdds(3.0));
  grid.Add({hi - 30, hi - 2}, EncodeLogOdds(-3.0));
  return grid;
}

TEST(WholeMapExport, TwoTilesAtOppositeCornersGiveAnImageWithinTheCap) {
  const OccupancyGrid grid = CornerGrid();
  const io::GridImage image = io::MakeGridImage(grid);
  // The box is 16384 cells a side (268 Mpx): 4 cells a pixel give 4096 x 4096.
  EXPECT_EQ(image.cells_per_pixel, 4);
  EXPECT_EQ(image.width, 4096);
  EXPECT_EQ(image.height, 4096);
  EXPECT_LE(int64_t{image.width} * image.height, io::kMaxGridImagePixels);
  EXPECT_DOUBLE_EQ(image.resolution_m, 0.04);

  // Saved: map.yaml's resolution and origin place each occupied cell's centre on a black pixel
  // and each free cell's on a white one, as map_server would.
  TempDir dir("corners");
  SaveInputs in;
  in.version = 3;
  in.resolution_m = 0.01;
  in.grid = &grid;
  in.trajectory = {{0.5, {0, 0, 0}}};
  const auto start = std::chrono::steady_clock::now();
  const Result<SaveReport> saved = SaveState(dir.path().string(), in);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_TRUE(saved.ok()) << saved.Message();
  EXPECT_TRUE(saved.value().warnings.empty());
  EXPECT_LT(seconds, 5.0);  // 6.9 s and 1.07 GB before; about 0.3 s now (Release)
  const auto yaml = testing::ParseYaml(Contents(dir.File("map.yaml")));
  const double resolution = std::stod(yaml.at("resolution"));
  double ox = 0, oy = 0, oz = 1;
  ASSERT_EQ(std::sscanf(yaml.at("origin").c_str(), "[%lf, %lf, %lf]", &ox, &oy, &oz), 3);
  EXPECT_DOUBLE_EQ(resolution, 0.04);
  EXPECT_DOUBLE_EQ(ox, -81.92);
  EXPECT_DOUBLE_EQ(oy, -81.92);
  const testing::Pgm pgm = testing::ParsePgm(Contents(dir.File("map.pgm")));
  ASSERT_EQ(pgm.width, 4096);
  ASSERT_EQ(pgm.height, 4096);
  ASSERT_EQ(pgm.pixels.size(), size_t{4096} * 4096);
  const auto pixel_at = [&](CellIndex c) {
    const Vec2 centre = grid.geometry().CellCenter(c);
    const auto col = static_cast<int64_t>(std::floor((centre.x() - ox) / resolution));
    const auto row =
        pgm.height - 1 - static_cast<int64_t>(std::floor((centre.y() - oy) / resolution));
    EXPECT_TRUE(col >= 0 && col < pgm.width && row >= 0 && row < pgm.height);
    return static_cast<uint8_t>(pgm.pixels[static_cast<size_t>(row * pgm.width + col)]);
  };
  const int32_t lo = -kMapTileBound * kTileSize, hi = kMapTileBound * kTileSize - 1;
  EXPECT_EQ(pixel_at({lo + 5, lo + 7}), io::kOccupiedGray);
  EXPECT_EQ(pixel_at({lo + 20, lo + 7}), io::kFreeGray);
  EXPECT_EQ(pixel_at({hi - 9, hi - 2}), io::kOccupiedGray);
  EXPECT_EQ(pixel_at({hi - 30, hi - 2}), io::kFreeGray);
  EXPECT_EQ(pixel_at({0, 0}), io::kUnknownGray);
  // Every pixel is one of the three values; 2 occupied and 2 free among them.
  size_t occupied = 0, free = 0;
  for (const char c : pgm.pixels) {
    occupied += static_cast<uint8_t>(c) == io::kOccupiedGray;
    free += static_cast<uint8_t>(c) == io::kFreeGray;
  }
  EXPECT_EQ(occupied, 2u);
  EXPECT_EQ(free, 2u);
  EXPECT_TRUE(fs::file_size(dir.File("map.png")) < (size_t{1} << 20));
}

TEST(WholeMapExport, MergedCellsTakeOccupiedOverFreeOverUnknown) {
  // One tile (64 x 64 cells) under a cap of 32 x 32 pixels: 2 x 2 cells a pixel.
  OccupancyGrid grid(GridGeometry(0.05), kLogOddsLimit);
  grid.BeginWrite();
  grid.Add({0, 0}, EncodeLogOdds(-3.0));  // pixel (0, 31): free and occupied
  grid.Add({1, 1}, EncodeLogOdds(3.0));
  grid.Add({2, 0}, EncodeLogOdds(-3.0));  // pixel (1, 31): free and unknown
  grid.Add({3, 1}, EncodeLogOdds(0.2));
  grid.Add({63, 63}, EncodeLogOdds(3.0));  // pixel (31, 0): occupied alone
  const io::GridImage image = io::MakeGridImage(grid, 32 * 32);
  ASSERT_EQ(image.cells_per_pixel, 2);
  ASSERT_EQ(image.width, 32);
  ASSERT_EQ(image.height, 32);
  EXPECT_DOUBLE_EQ(image.resolution_m, 0.1);
  const auto at = [&](int col, int row) {
    return image.gray[static_cast<size_t>(row * image.width + col)];
  };
  EXPECT_EQ(at(0, 31), io::kOccupiedGray);
  EXPECT_EQ(at(1, 31), io::kFreeGray);
  EXPECT_EQ(at(31, 0), io::kOccupiedGray);
  EXPECT_EQ(at(2, 31), io::kUnknownGray);
  // A cap the box fits in keeps one pixel a cell; odd sizes round up.
  EXPECT_EQ(io::MakeGridImage(grid, 64 * 64).cells_per_pixel, 1);
  const io::GridImage thirds = io::MakeGridImage(grid, 22 * 22);
  EXPECT_EQ(thirds.cells_per_pixel, 3);
  EXPECT_EQ(thirds.width, 22);
}

// --- the map picture (slam-replay's map.png)
// ------------------------------------------------------

int CountRgb(const io::RgbImage& image, int x0, int y0, int x1, int y1, const io::Rgb& c) {
  int n = 0;
  for (int y = std::max(0, y0); y < std::min(y1, image.height); ++y) {
    for (int x = std::max(0, x0); x < std::min(x1, image.width); ++x) {
      const size_t k =
          3 * (static_cast<size_t>(y) * static_cast<size_t>(image.width) + static_cast<size_t>(x));
      n += image.rgb[k] == c[0] && image.rgb[k + 1] == c[1] && image.rgb[k + 2] == c[2];
    }
  }
  return n;
}

TEST(MapPicture, ScaleBarsAreRoundLengths) {
  const io::ScaleBar a = io::ChooseScaleBar(0.01, 41);
  EXPECT_DOUBLE_EQ(a.length_m, 0.2);
  EXPECT_EQ(a.length_px, 20);
  EXPECT_EQ(a.label, "20 cm");
  const io::ScaleBar b = io::ChooseScaleBar(0.01, 1000);
  EXPECT_DOUBLE_EQ(b.length_m, 10.0);
  EXPECT_EQ(b.length_px, 1000);
  EXPECT_EQ(b.label, "10 m");
  const io::ScaleBar c = io::ChooseScaleBar(0.01, 999);
  EXPECT_DOUBLE_EQ(c.length_m, 5.0);
  EXPECT_EQ(c.length_px, 500);
  EXPECT_EQ(c.label, "5 m");
  const io::ScaleBar d = io::ChooseScaleBar(0.05 / 3.0, 600);  // 5 cm cells at 3 px a cell
  EXPECT_DOUBLE_EQ(d.length_m, 10.0);
  EXPECT_EQ(d.length_px, 600);
  EXPECT_EQ(io::ChooseScaleBar(0.001, 45).label, "2 cm");
}

TEST(MapPicture, ALayerThatDoesNotFitIsClippedAndTheMapKeepsItsSizeWithAScaleBar) {
  // One tile of 1 cm cells; dead reckoning wanders 50 m away. The picture used to grow over it
  // (to its 8192-pixel cap, the building a corner of it); now the map sets the size.
  OccupancyGrid grid(GridGeometry(0.01), kLogOddsLimit);
  grid.BeginWrite();
  for (int x = 0; x < 64; ++x) grid.Add({x, 40}, EncodeLogOdds(3.0));
  const io::Rgb grey{150, 150, 150}, red{230, 0, 0};
  io::TrajectoryLayer odometry{"odometry only",
                               {{0.0, {0.1, 0.1, 0.0}}, {1.0, {50.0, 0.1, 0.0}}},
                               grey,
                               /*fit=*/false};
  io::TrajectoryLayer slam{"SLAM", {{0.0, {0.1, 0.2, 0.0}}, {1.0, {0.5, 0.2, 0.0}}}, red};
  const int scale = 3;
  const io::RgbImage picture = io::RenderMapPicture(grid, {odometry, slam}, scale);
  const int map_height = 64 * scale;
  EXPECT_EQ(picture.height, map_height + 2 * 11 + 4);
  EXPECT_LT(picture.width, 400);  // the map's 192 pixels, the legend and the scale bar
  // Dead reckoning drawn to the picture's right edge along y = 0.1 m.
  const int row = map_height - static_cast<int>(0.1 / 0.01 * scale);
  EXPECT_EQ(CountRgb(picture, 0, row - 2, 64 * scale, row + 2, grey), (64 * scale - 30) * 2);
  EXPECT_GT(CountRgb(picture, 0, 0, picture.width, map_height, red), 100);

  // The scale bar: 0.01 / 3 m a pixel, at most max(40, 192 / 5) pixels: 10 cm, 30 pixels, black,
  // on the legend's first line at the right, its label after it.
  const io::ScaleBar bar = io::ChooseScaleBar(0.01 / scale, 40);
  EXPECT_EQ(bar.label, "10 cm");
  EXPECT_EQ(bar.length_px, 30);
  // The strip's layout at font size 1: the bar ends 2 + 30 + 3 pixels (gap, label, margin)
  // short of the right edge, on the text's last row.
  const int bar_x = picture.width - (30 + 2 + 30 + 3);
  const int bar_y = map_height + 2 + 6;
  EXPECT_EQ(CountRgb(picture, bar_x, bar_y, bar_x + 30, bar_y + 1, {0, 0, 0}), 30);
  EXPECT_EQ(CountRgb(picture, bar_x, bar_y - 3, bar_x + 30, bar_y, {0, 0, 0}), 6);  // ticks
}

TEST(MapPicture, LinesFarOutsideCostOnlyWhatIsDrawn) {
  // Ends a million pixels away each side: only the 100 pixels inside are drawn.
  io::Canvas canvas(100, 100, {255, 255, 255});
  const auto start = std::chrono::steady_clock::now();
  for (int i = 0; i < 2000; ++i) canvas.Line(-1'000'000, 50, 1'000'000, 50, 3, {0, 0, 0});
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_LT(seconds, 0.5);  // 4e9 pen squares walked before, about 4 ms now
  EXPECT_EQ(CountRgb(canvas.image(), 0, 0, 100, 100, {0, 0, 0}), 300);
  // A diagonal through the picture from far outside lands on the diagonal's pixels.
  io::Canvas diagonal(50, 50, {255, 255, 255});
  diagonal.Line(-100'000, -100'000, 100'000, 100'000, 1, {0, 0, 0});
  for (int k = 0; k < 50; ++k) EXPECT_EQ(diagonal.Get(k, k), (io::Rgb{0, 0, 0})) << k;
  EXPECT_EQ(CountRgb(diagonal.image(), 0, 0, 50, 50, {0, 0, 0}), 50);
}

}  // namespace
}  // namespace slam::server
