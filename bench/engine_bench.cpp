// Engine benchmarks: ray casting (the unit of cost of the ray budget), grid updates, matching one
// scan, whole scans at the paper's budgets, copy-on-write resampling, and a whole replay.
// Items are rays unless the label says otherwise; parallel benchmarks take the oneTBB thread
// count as their last argument and report wall time.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "bench/bench_support.hpp"
#include "engine/cell_encoding.hpp"
#include "engine/global_matcher.hpp"
#include "engine/loss_detector.hpp"
#include "engine/match_window.hpp"
#include "engine/matching_rays.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/random.hpp"
#include "engine/sensor_model.hpp"
#include "engine/slam.hpp"
#include "engine/update_ray.hpp"
#include "offline/replay.hpp"
#include "scheduler/fixed_plan.hpp"

namespace slam::bench {
namespace {

constexpr int64_t kPaperBudgets[] = {8125, 16250, 32500, 65000};

// ---------------------------------------------------------------------------------------------
// Maps and rays.

/// What the rays run through: nothing written (unknown), a drawn room, or the engine's own map.
enum Fill : int64_t { kUnknown = 0, kRoom = 1, kMapped = 2 };

const char* FillName(int64_t fill) {
  switch (fill) {
    case kUnknown:
      return "unknown";
    case kRoom:
      return "room";
    default:
      return "mapped";
  }
}

/// A 3 m x 3 m room at 1 cm, walls occupied, inside free (as after mapping it well).
OccupancyGrid MakeRoom() {
  OccupancyGrid grid(GridGeometry(0.01), 5000);
  grid.BeginWrite();
  for (int i = -150; i < 150; ++i) {
    for (int j = -150; j < 150; ++j) {
      const bool wall = i == -150 || i == 149 || j == -150 || j == 149;
      grid.Add({i, j}, wall ? 3000 : -2000);
    }
  }
  grid.RefreshSummaries();  // as the engine does after each update phase
  return grid;
}

/// The engine's map after 120 s of the rooms run at 16250 rays/scan (walls, free space,
/// unexplored parts), with the poses of its trajectory as ray origins.
struct MappedWorld {
  OccupancyGrid map;
  std::vector<TimedPose> trajectory;
};

const MappedWorld& Mapped() {
  static const MappedWorld world = [] {
    const Slam engine = MappedEngine(RoomsRun(120.0), 1'000'000, 16250, 1);
    MappedWorld mapped{engine.Best().map, engine.Trajectory()};
    // The engine leaves the clearance of tiles it matched through a window stale until a scan
    // casts through them; refreshed here, as a particle without a window sees its tiles.
    mapped.map.RefreshSummaries();
    return mapped;
  }();
  return world;
}

/// A fresh copy of the grid of `fill` (shares tiles with the cached one until written).
OccupancyGrid GridOf(int64_t fill) {
  static const OccupancyGrid room = MakeRoom();
  switch (fill) {
    case kUnknown:
      return OccupancyGrid(GridGeometry(0.01), 5000);
    case kRoom:
      return room;
    default:
      return Mapped().map;
  }
}

struct Ray {
  Vec2 origin;
  double angle = 0.0;
  Vec2 direction;  // (cos, sin) of angle: the engine turns its directions without trigonometry
};

/// 4096 seeded rays: from random points of the room, or from the mapped run's own poses (inside
/// the explored space, as the engine casts them).
std::vector<Ray> RaysFor(int64_t fill, uint64_t seed) {
  Rng rng(seed);
  std::vector<Ray> rays(4096);
  const auto& trajectory = Mapped().trajectory;
  for (Ray& ray : rays) {
    if (fill == kMapped) {
      const Pose2& p =
          trajectory[static_cast<size_t>(rng.Uniform() * static_cast<double>(trajectory.size()))]
              .pose;
      ray.origin = Vec2(p.x, p.y);
    } else {
      ray.origin = Vec2(rng.Uniform() * 2.8 - 1.4, rng.Uniform() * 2.8 - 1.4);
    }
    ray.angle = rng.Uniform() * 2 * kPi;
    ray.direction = Vec2(std::cos(ray.angle), std::sin(ray.angle));
  }
  return rays;
}

/// The engine's update profile of the long-range sensor for a reading at `distance_m` (its
/// use window widened to its datasheet range so that every benchmarked length has one).
UpdateProfile LongSensorProfile(double distance_m) {
  SensorTypeDescription type = ShippedRobot().sensor_types.at("long");
  type.use_min_m = type.range_min_m;
  type.use_max_m = type.range_max_m;
  const SensorModel model(type, UpdateModelConfig{}, 0.01);
  const auto raw = static_cast<uint16_t>(CalibratedRaw(type.calibration, distance_m));
  const std::optional<UpdateProfile> profile = model.Update(raw);
  if (profile) return *profile;
  UpdateProfile free;
  free.step_m = 0.005;
  free.free_bins = static_cast<int32_t>(distance_m / 0.005);
  free.free_delta = -850;
  return free;
}

// ---------------------------------------------------------------------------------------------
// Ray casting.

// What the matching-ray benchmarks share: the map of fill range(0), rays of at most range(1)
// cm with the default threshold, and the work they report per ray.
struct MatchingRays {
  explicit MatchingRays(const benchmark::State& state)
      : fill(state.range(0)),
        grid(GridOf(fill)),
        max_range(static_cast<double>(state.range(1)) / 100.0),
        rays(RaysFor(fill, 1)) {}

  /// Items (rays) and cells and jumps per ray.
  void Report(benchmark::State& state, int64_t cast, int64_t cells, int64_t jumps) const {
    Items(state, cast, FillName(fill));
    const double n = static_cast<double>(std::max<int64_t>(1, cast));
    state.counters["cells_per_ray"] = static_cast<double>(cells) / n;
    state.counters["jumps_per_ray"] = static_cast<double>(jumps) / n;
  }

  int64_t fill;
  OccupancyGrid grid;
  double max_range;
  std::vector<Ray> rays;
  LogOdds threshold = EncodeLogOdds(SlamConfig{}.occupied_above_logodds);
};

// Matching rays of at most range(1) cm through a map of fill range(0), one at a time.
void BM_MatchingRay(benchmark::State& state) {
  const MatchingRays m(state);
  size_t i = 0;
  int64_t cells = 0, jumps = 0;
  for (auto _ : state) {
    const Ray& r = m.rays[i++ & 4095];
    const RayHit hit = CastToObstacle(m.grid, r.origin, r.direction, m.max_range, m.threshold);
    cells += hit.cells;
    jumps += hit.jumps;
    benchmark::DoNotOptimize(hit);
  }
  m.Report(state, state.iterations(), cells, jumps);
}
BENCHMARK(BM_MatchingRay)
    ->ArgNames({"fill", "length_cm"})
    ->ArgsProduct({{kUnknown, kRoom, kMapped}, {30, 75, 150}});

// The same rays cast 64 at a time with CastToObstacles (several rays in flight, as the engine
// casts a candidate's measurements).
void BM_MatchingRayBatch(benchmark::State& state) {
  const MatchingRays m(state);
  constexpr size_t kBatch = 64;
  std::vector<std::vector<RayQuery>> batches;
  for (size_t b = 0; b < m.rays.size(); b += kBatch) {
    std::vector<RayQuery>& batch = batches.emplace_back();
    for (size_t i = b; i < b + kBatch; ++i)
      batch.push_back({m.rays[i].origin, m.rays[i].direction, m.max_range});
  }
  std::vector<RayHit> hits;
  size_t i = 0;
  int64_t cells = 0, jumps = 0;
  for (auto _ : state) {
    CastToObstacles(m.grid, batches[i++ % batches.size()], m.threshold, hits);
    for (const RayHit& hit : hits) {
      cells += hit.cells;
      jumps += hit.jumps;
    }
    benchmark::DoNotOptimize(hits.data());
  }
  m.Report(state, state.iterations() * static_cast<int64_t>(kBatch), cells, jumps);
}
BENCHMARK(BM_MatchingRayBatch)
    ->ArgNames({"fill", "length_cm"})
    ->ArgsProduct({{kUnknown, kRoom, kMapped}, {30, 75, 150}});

// The same rays through the cell-by-cell traversal (the fast path's oracle): the before/after
// ratio of the empty-space skipping, measured in one run.
void BM_MatchingRayPlain(benchmark::State& state) {
  const MatchingRays m(state);
  size_t i = 0;
  int64_t cells = 0;
  for (auto _ : state) {
    const Ray& r = m.rays[i++ & 4095];
    const RayHit hit = CastToObstaclePlain(m.grid, r.origin, r.direction, m.max_range, m.threshold);
    cells += hit.cells;
    benchmark::DoNotOptimize(hit);
  }
  m.Report(state, state.iterations(), cells, 0);
}
BENCHMARK(BM_MatchingRayPlain)
    ->ArgNames({"fill", "length_cm"})
    ->ArgsProduct({{kRoom, kMapped}, {30, 150}});

// What the engine's MatchWindow benchmarks share: 64 windows of 3.4 m x 3.4 m of the map of
// fill range(0) (as the engine builds one per particle and scan), each around one ray origin of
// RaysFor (a pose of the mapped run), and for each window 64 candidates' batches of 64 rays of at
// most range(1) cm: the window's rays (from within 5 cm of its centre, in random directions)
// moved and turned as one by the candidate's offset (2 cm and 5 degrees, the engine's minimum
// pose uncertainties), as the engine casts a particle's candidates through its window.
struct WindowRays {
  static constexpr int32_t kHalf = 170;  // cells
  static constexpr size_t kWindows = 64, kCandidates = 64, kBatch = 64;

  explicit WindowRays(const benchmark::State& state, bool build = true) : m(state) {
    Rng rng(8);
    for (size_t w = 0; w < kWindows; ++w) {
      const Vec2 centre = m.rays[w].origin;
      const CellIndex c = m.grid.geometry().CellOf(centre);
      bounds.push_back(
          {CellIndex{c.x - kHalf, c.y - kHalf}, CellIndex{c.x + kHalf - 1, c.y + kHalf - 1}});
      if (build)
        windows.emplace_back(m.grid, m.threshold, bounds.back().first, bounds.back().second);
      std::vector<RayQuery> base;
      for (size_t i = 0; i < kBatch; ++i) {
        const Ray& r = m.rays[(w * kBatch + i) % m.rays.size()];
        base.push_back(
            {centre + Vec2(rng.Gaussian(0.05), rng.Gaussian(0.05)), r.direction, m.max_range});
      }
      for (size_t k = 0; k < kCandidates; ++k) {
        const Vec2 shift(rng.Gaussian(0.02), rng.Gaussian(0.02));
        const double turn = rng.Gaussian(DegToRad(5.0));
        const double cos_turn = std::cos(turn), sin_turn = std::sin(turn);
        const auto rotate = [&](const Vec2& v) {
          return Vec2(cos_turn * v.x() - sin_turn * v.y(), sin_turn * v.x() + cos_turn * v.y());
        };
        std::vector<RayQuery>& batch = batches.emplace_back();
        for (const RayQuery& q : base) {
          batch.push_back(
              {centre + rotate(q.origin - centre) + shift, rotate(q.direction), q.max_range_m});
        }
      }
    }
  }

  /// The window and the batch of the i-th batch cast: consecutive batches in different windows
  /// (`engine_order` false: each window cold in the caches, the worst case), or each window's
  /// candidates in a row, as the engine casts them.
  std::pair<size_t, size_t> Pick(size_t i, bool engine_order) const {
    i %= kWindows * kCandidates;
    const size_t window = engine_order ? i / kCandidates : i % kWindows;
    const size_t candidate = engine_order ? i % kCandidates : i / kWindows;
    return {window, window * kCandidates + candidate};
  }

  MatchingRays m;
  std::vector<std::pair<CellIndex, CellIndex>> bounds;
  std::vector<MatchWindow> windows;
  std::vector<std::vector<RayQuery>> batches;  // kCandidates per window, window-major
};

// Building a MatchWindow (reading the window's cells, its free squares). Items are cells.
void BM_MatchWindowBuild(benchmark::State& state) {
  const WindowRays w(state, false);
  size_t i = 0;
  int64_t cells = 0;
  for (auto _ : state) {
    const auto& [lo, hi] = w.bounds[i++ % w.bounds.size()];
    const MatchWindow window(w.m.grid, w.m.threshold, lo, hi);
    cells += window.cells();
    benchmark::DoNotOptimize(window.FreeSquareAt(lo, false, false));
  }
  Items(state, cells, (std::string("cells ") + FillName(w.m.fill)).c_str());
}
BENCHMARK(BM_MatchWindowBuild)
    ->ArgNames({"fill", "length_cm"})
    ->Args({kRoom, 150})
    ->Args({kMapped, 150});

// What BM_MatchingRayWindow casts through.
enum RayPath : int64_t { kTiles = 0, kWindowPortable = 1, kWindowAvx512 = 2, kWindowAvx2 = 3 };

// Matching rays cast 64 at a time through the grid's tiles (CastToObstacles on the grid, path 0)
// or through a built MatchWindow around their origins with the portable kernel (path 1), the
// AVX-512 one (path 2) or the AVX2 one (path 3; where the processor lacks a kernel it runs the
// portable one and says so in its label): the ratios in one run. engine 1: as the engine casts
// them, each window's 64 candidates in a row right after the window was built (built again,
// untimed, before its first batch: the window is warm in the caches, as the engine's is); engine 0:
// every batch in another window, built long before (cold in the caches, the worst case).
void BM_MatchingRayWindow(benchmark::State& state) {
  WindowRays w(state);
  const int64_t path = state.range(2);
  const bool engine_order = state.range(3) != 0;
  const WindowKernel kernel = path == kWindowAvx512 ? WindowKernel::kAvx512
                              : path == kWindowAvx2 ? WindowKernel::kAvx2
                                                    : WindowKernel::kPortable;
  std::vector<RayHit> hits;
  size_t i = 0;
  int64_t cells = 0, jumps = 0;
  for (auto _ : state) {
    const auto [window, batch] = w.Pick(i++, engine_order);
    if (engine_order && path != kTiles && batch % WindowRays::kCandidates == 0) {
      state.PauseTiming();
      const auto& [lo, hi] = w.bounds[window];
      w.windows[window] = MatchWindow(w.m.grid, w.m.threshold, lo, hi);
      state.ResumeTiming();
    }
    if (path == kTiles) {
      CastToObstacles(w.m.grid, w.batches[batch], w.m.threshold, hits);
    } else {
      CastToObstacles(w.windows[window], w.batches[batch], hits, kernel);
    }
    for (const RayHit& hit : hits) {
      cells += hit.cells;
      jumps += hit.jumps;
    }
    benchmark::DoNotOptimize(hits.data());
  }
  w.m.Report(state, state.iterations() * static_cast<int64_t>(WindowRays::kBatch), cells, jumps);
  if (path != kTiles && !WindowKernelAvailable(kernel)) {
    state.SetLabel(std::string(FillName(w.m.fill)) +
                   (path == kWindowAvx2 ? ", no AVX2" : ", no AVX-512") + " here: portable kernel");
  }
}
BENCHMARK(BM_MatchingRayWindow)
    ->ArgNames({"fill", "length_cm", "path", "engine"})
    ->ArgsProduct({{kRoom, kMapped},
                   {30, 75, 150},
                   {kTiles, kWindowPortable, kWindowAvx512, kWindowAvx2},
                   {0, 1}});

// Update rays with the long sensor's profile for a reading at range(1) cm, on a map of fill
// range(0) (the map keeps changing: cells saturate at the clamp, as in a long run).
void BM_UpdateRay(benchmark::State& state) {
  const int64_t fill = state.range(0);
  OccupancyGrid grid = GridOf(fill);
  const UpdateProfile profile = LongSensorProfile(static_cast<double>(state.range(1)) / 100.0);
  const std::vector<Ray> rays = RaysFor(fill, 2);
  grid.BeginWrite();
  size_t i = 0;
  for (auto _ : state) {
    const Ray& r = rays[i++ & 4095];
    benchmark::DoNotOptimize(ApplyUpdateRay(grid, r.origin, r.angle, profile));
  }
  Items(state, state.iterations(), FillName(fill));
}
BENCHMARK(BM_UpdateRay)
    ->ArgNames({"fill", "length_cm"})
    ->ArgsProduct({{kUnknown, kRoom, kMapped}, {30, 75, 150}});

// ---------------------------------------------------------------------------------------------
// Grid.

// Single-cell updates at random cells of the mapped area (the tiles exist and are owned).
void BM_GridAdd(benchmark::State& state) {
  OccupancyGrid grid = GridOf(kMapped);
  grid.BeginWrite();
  const std::vector<Ray> rays = RaysFor(kMapped, 3);
  std::vector<CellIndex> cells;
  for (const Ray& r : rays)
    cells.push_back(
        grid.geometry().CellOf(r.origin + Vec2(std::cos(r.angle), std::sin(r.angle)) * 0.3));
  for (const CellIndex& c : cells) grid.Add(c, 0);  // own every tile before timing
  size_t i = 0;
  for (auto _ : state) {
    grid.Add(cells[i & 4095], (i & 1) != 0 ? 850 : -850);
    ++i;
  }
  benchmark::DoNotOptimize(grid.At(cells[0]));
  Items(state, state.iterations(), "cells");
}
BENCHMARK(BM_GridAdd);

// Copy-on-write: a copy of the mapped grid writes one cell in every tile, so every tile is
// copied once (what a resampled particle pays on its first update of each tile).
void BM_GridCopyOnWrite(benchmark::State& state) {
  const OccupancyGrid source = GridOf(kMapped);
  std::vector<TileIndex> tiles;
  for (const TileRef& t : source.Tiles()) tiles.push_back(t.index);
  for (auto _ : state) {
    OccupancyGrid copy = source;
    copy.BeginWrite();
    for (const TileIndex& t : tiles) benchmark::DoNotOptimize(copy.MutableTile(t).cells[0]);
  }
  Items(state, state.iterations() * static_cast<int64_t>(tiles.size()), "tiles");
  state.counters["tiles"] = static_cast<double>(tiles.size());
}
BENCHMARK(BM_GridCopyOnWrite);

// ---------------------------------------------------------------------------------------------
// Filter.

constexpr size_t kWarmScans = 60;

/// The engine warmed up on the first 60 scans of the 300 s rooms run at 16250 rays/scan with
/// `particles` particles, parallel path on (cached; benchmarks work on copies, which share its
/// tiles and keep its config: the thread count is set by the benchmark's ThreadLimit).
const Slam& WarmEngine(int particles) {
  static std::mutex mutex;
  static std::map<int, std::unique_ptr<Slam>> cache;
  const std::lock_guard lock(mutex);
  auto& slot = cache[particles];
  if (!slot) {
    slot =
        std::make_unique<Slam>(MappedEngine(RoomsRun(300.0), kWarmScans, 16250, particles, true));
  }
  return *slot;
}

// Normal draws as phase B draws its candidates' poses: range(0) 0 by Box-Muller
// (Rng::Gaussian, the simulator's), 1 by the ziggurat (Rng::Normal, the engine's). Items are
// draws.
void BM_NormalDraw(benchmark::State& state) {
  Rng rng(11);
  const bool ziggurat = state.range(0) == 1;
  double sum = 0.0;
  for (auto _ : state) {
    for (int i = 0; i < 64; ++i) sum += ziggurat ? rng.Normal(0.02) : rng.Gaussian(0.02);
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(state.iterations() * 64);
}
BENCHMARK(BM_NormalDraw)->ArgName("ziggurat")->Arg(0)->Arg(1);

// Copy-on-write resampling: range(0) particles drawn systematically from a weighted set of as
// many (all sharing the mapped tiles), then each drawn copy's first update ray, which copies
// the tile it writes. Items are particles.
void BM_ResampleCopyOnWrite(benchmark::State& state) {
  const auto n = static_cast<size_t>(state.range(0));
  std::vector<Particle> particles(n, Particle{Pose2{}, 0.0, GridOf(kMapped), nullptr});
  Rng rng(4);
  for (Particle& p : particles) p.log_weight = rng.Gaussian();
  const UpdateProfile profile = LongSensorProfile(0.75);
  const std::vector<Ray> rays = RaysFor(kMapped, 5);
  size_t ray = 0;
  for (auto _ : state) {
    // Systematic draw in proportion to exp(log_weight), as phase D does.
    double max_log = particles[0].log_weight;
    for (const Particle& p : particles) max_log = std::max(max_log, p.log_weight);
    std::vector<double> cumulative(n);
    double total = 0.0;
    for (size_t i = 0; i < n; ++i)
      cumulative[i] = total += std::exp(particles[i].log_weight - max_log);
    const double step = total / static_cast<double>(n);
    double u = rng.Uniform() * step;
    std::vector<Particle> drawn;
    drawn.reserve(n);
    size_t j = 0;
    for (size_t i = 0; i < n; ++i, u += step) {
      while (j + 1 < n && cumulative[j] < u) ++j;
      drawn.push_back(particles[j]);
      drawn.back().log_weight = 0.0;
    }
    for (Particle& p : drawn) {
      p.map.BeginWrite();
      const Ray& r = rays[ray++ & 4095];
      benchmark::DoNotOptimize(ApplyUpdateRay(p.map, r.origin, r.angle, profile));
    }
    benchmark::DoNotOptimize(drawn.data());
  }
  Items(state, state.iterations() * state.range(0), "particles");
}
BENCHMARK(BM_ResampleCopyOnWrite)->ArgName("particles")->Arg(1)->Arg(5)->Arg(16)->Arg(64);

// Matching one scan (phase B, no update) with one particle and range(0) candidates, on
// range(1) oneTBB threads. Items are matching rays.
void BM_MatchScan(benchmark::State& state) {
  const ThreadLimit limit(state.range(1));
  const Slam& warm = WarmEngine(1);
  const Scan& scan = RoomsRun(300.0).scans[kWarmScans];
  ScanPlan plan;
  plan.candidates = static_cast<int>(state.range(0));
  plan.update_rays = 0;
  int64_t rays = 0;
  for (auto _ : state) {
    state.PauseTiming();
    Slam engine = warm;
    state.ResumeTiming();
    rays += engine.ProcessScan(scan, plan).rays.matching;
  }
  Items(state, rays, "matching rays");
}
BENCHMARK(BM_MatchScan)
    ->ArgNames({"candidates", "threads"})
    ->ArgsProduct({{8, 64, 512}, {1, 2}})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

// Whole scans (phases A-D) of the rooms run at the paper budget range(0) with range(1)
// particles on range(2) threads, one scan per iteration in order from the warmed-up engine.
// Items are rays (matching + update); the time per iteration is the time per scan.
void BM_Scan(benchmark::State& state) {
  const ThreadLimit limit(state.range(2));
  const int particles = static_cast<int>(state.range(1));
  const int64_t budget = state.range(0);
  const std::vector<Scan>& scans = RoomsRun(300.0).scans;
  std::optional<Slam> engine;
  size_t next = scans.size();
  int64_t rays = 0;
  int64_t done = 0;
  for (auto _ : state) {
    if (next == scans.size()) {
      state.PauseTiming();
      engine.emplace(WarmEngine(particles));
      next = kWarmScans;
      state.ResumeTiming();
    }
    const PreparedScan prepared = engine->Prepare(scans[next++]);
    rays += engine->ProcessScan(prepared, FixedPlan(prepared.summary, budget, engine->params()))
                .rays.total();
    ++done;
  }
  Items(state, rays, "rays");
  state.counters["rays_per_scan"] =
      static_cast<double>(rays) / static_cast<double>(std::max<int64_t>(1, done));
}
BENCHMARK(BM_Scan)
    ->ArgNames({"budget", "particles", "threads"})
    ->ArgsProduct({{std::begin(kPaperBudgets), std::end(kPaperBudgets)}, {1, 5}, {1, 2}})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

// The relocaliser's unit of cost: a whole-map global search (global_matcher.hpp) of a
// multiscan (the usable readings of the 15 scans after the warm-up, placed by the odometry in
// the last one's frame, at most 400) on the warmed-up engine's map, on a field of range(0) mm
// cells. Items are point lookups: their time against a quota ray's (BM_Scan) is the rate at
// which a scan's quota pays for the search.
void BM_GlobalSearch(benchmark::State& state) {
  const Slam& warm = WarmEngine(1);
  const std::vector<Scan>& scans = RoomsRun(300.0).scans;
  MatchFieldConfig field_config;
  field_config.resolution_m = static_cast<double>(state.range(0)) / 1000.0;
  field_config.sigma_m = field_config.resolution_m;
  auto field =
      std::make_shared<const MatchField>(MatchField::FromGrid(warm.Best().map, field_config));
  const Pose2 newest = scans[kWarmScans + 14].odom_end;
  std::vector<Vec2> all;
  for (size_t i = kWarmScans; i < kWarmScans + 15; ++i) {
    const Pose2 to_newest = Between(newest, scans[i].odom_end);
    for (const Vec2& p : warm.ReadingPoints(warm.Prepare(scans[i]))) {
      all.push_back(to_newest.Transform(p));
    }
  }
  std::vector<Vec2> query;
  for (size_t i = 0; i < all.size(); i += std::max<size_t>(1, all.size() / 400)) {
    query.push_back(all[i]);
  }
  GlobalSearchConfig config;
  config.unique_ratio = 0.7;
  config.candidates = 4;
  int64_t lookups = 0;
  for (auto _ : state) {
    GlobalSearch search(field, query, GlobalRegion{}, config);
    search.Finish();
    lookups += search.lookups();
    benchmark::DoNotOptimize(search.best());
  }
  Items(state, lookups, "lookups");
  state.counters["points"] = static_cast<double>(query.size());
}
BENCHMARK(BM_GlobalSearch)->ArgName("cell_mm")->Arg(30)->Arg(100)->Unit(benchmark::kMillisecond);

// The relocaliser's other cost: building the warmed-up engine's map's field of range(0) mm
// cells (as Relocalizer::Start's builds, six levels on the coarse field, four on the fine
// one). Items are the lookups it is charged (MatchFieldBuild::lookups): their time against a
// search's lookup (BM_GlobalSearch) says whether kCellOpsPerLookup errs high.
void BM_MatchFieldBuild(benchmark::State& state) {
  const Slam& warm = WarmEngine(1);
  MatchFieldConfig config;
  config.resolution_m = static_cast<double>(state.range(0)) / 1000.0;
  config.sigma_m = config.resolution_m;
  config.levels = state.range(0) >= 100 ? 6 : 4;
  int64_t lookups = 0;
  for (auto _ : state) {
    MatchFieldBuild build(warm.Best().map, config);
    build.Finish();
    lookups += build.lookups();
    benchmark::DoNotOptimize(build.field());
  }
  Items(state, lookups, "lookups");
  state.counters["tiles"] = static_cast<double>(warm.Best().map.TileCount());
}
BENCHMARK(BM_MatchFieldBuild)->ArgName("cell_mm")->Arg(30)->Arg(100)->Unit(benchmark::kMillisecond);

// The loss detector's check (LossDetector::Check) of one scan's readings on the warmed-up
// engine's map: placed at the tracked pose (range(0) 0: readings next to walls, a few cells
// each) or 1 m and 150 degrees off (1: a kidnapped tracker's, many traversed to a wall they
// were seen through). Items are the lookups it is charged (LossCheck::lookups): their time
// against a ray's (BM_Scan's) says whether kLookupsPerRay fits the check too.
void BM_LossCheck(benchmark::State& state) {
  const Slam& warm = WarmEngine(1);
  const std::vector<Scan>& scans = RoomsRun(300.0).scans;
  // The last scan the engine took, in the frame of its end: where the best pose is.
  const std::vector<Vec2> readings = warm.ReadingPoints(warm.Prepare(scans[kWarmScans - 1]));
  LossDetector detector;
  Pose2 pose = warm.Best().pose;
  if (state.range(0) != 0) {
    // Of eight poses 1 m away (turned by 150 degrees), the one that sees most readings through
    // a wall: a kidnapped tracker's worst case.
    int most = -1;
    for (int k = 0; k < 8; ++k) {
      const double a = k * kPi / 4;
      const Pose2 off = Compose(warm.Best().pose, Pose2{std::cos(a), std::sin(a), DegToRad(150)});
      const int through = LossDetector().Check(warm.Best().map, off, readings).through;
      if (through > most) {
        most = through;
        pose = off;
      }
    }
  }
  int64_t lookups = 0, through = 0;
  for (auto _ : state) {
    const LossCheck check = detector.Check(warm.Best().map, pose, readings);
    lookups += check.lookups;
    through += check.through;
    benchmark::DoNotOptimize(check);
  }
  Items(state, lookups, "lookups");
  state.counters["through_per_check"] =
      static_cast<double>(through) / static_cast<double>(std::max<int64_t>(state.iterations(), 1));
}
BENCHMARK(BM_LossCheck)->ArgName("off")->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

// A whole replay (Replay(): scheduler + engine, as slam-replay) of the rooms run of range(0)
// seconds at 65000 rays/scan on range(1) threads, once. Counter realtime_factor = run
// duration / wall time. Items are scans.
void BM_Replay(benchmark::State& state) {
  const ThreadLimit limit(state.range(1));
  const SimulatedRun& run = RoomsRun(static_cast<double>(state.range(0)));
  offline::ReplayOptions options;
  options.config = BenchConfig(true);
  options.budget.rays_per_scan = 65000;
  double wall_s = 0.0;
  int64_t scans = 0;
  int64_t rays = 0;
  for (auto _ : state) {
    const auto start = std::chrono::steady_clock::now();
    const offline::ReplayResult result =
        offline::Replay(ShippedRobot(), run.scans, run.ground_truth, options);
    wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    scans += result.scans;
    rays += result.rays_total;
  }
  Items(state, scans, "scans");
  const double iterations = static_cast<double>(state.iterations());
  state.counters["realtime_factor"] = run.duration_s * iterations / wall_s;
  state.counters["rays_per_scan"] =
      static_cast<double>(rays) / static_cast<double>(std::max<int64_t>(1, scans));
  state.counters["duration_s"] = run.duration_s;
}
BENCHMARK(BM_Replay)
    ->ArgNames({"seconds", "threads"})
    ->ArgsProduct({{30, 300}, {1, 2}})
    ->Iterations(1)
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace slam::bench

BENCHMARK_MAIN();
