// Engine benchmarks: ray casting, the unit of cost of the ray budget.
#include <benchmark/benchmark.h>

#include <cmath>
#include <vector>

#include "engine/random.hpp"
#include "engine/ray_cast.hpp"

namespace slam {
namespace {

// A 3 m x 3 m room at 1 cm, walls occupied, inside free (as after mapping).
OccupancyGrid MakeRoom() {
  OccupancyGrid grid(GridGeometry(0.01), 5000);
  for (int i = -150; i < 150; ++i) {
    for (int j = -150; j < 150; ++j) {
      const bool wall = i == -150 || i == 149 || j == -150 || j == 149;
      grid.Add({i, j}, wall ? 3000 : -2000);
    }
  }
  return grid;
}

// Matching rays of at most range(0) cm from random poses inside the room.
void BM_CastToObstacle(benchmark::State& state) {
  const OccupancyGrid grid = MakeRoom();
  const double max_range = static_cast<double>(state.range(0)) / 100.0;
  Rng rng(1);
  std::vector<std::pair<Vec2, double>> rays(4096);
  for (auto& r : rays) r = {Vec2(rng.Uniform() * 2.8 - 1.4, rng.Uniform() * 2.8 - 1.4), rng.Uniform() * 2 * kPi};
  size_t i = 0;
  for (auto _ : state) {
    const auto& r = rays[i++ & 4095];
    benchmark::DoNotOptimize(CastToObstacle(grid, r.first, r.second, max_range, 0));
  }
  state.SetItemsProcessed(state.iterations());
  state.SetLabel("rays");
}
BENCHMARK(BM_CastToObstacle)->Arg(30)->Arg(100)->Arg(150);

// Update rays of range(0) cm.
void BM_ApplyUpdateRay(benchmark::State& state) {
  OccupancyGrid grid = MakeRoom();
  UpdateProfile profile;
  profile.step_m = 0.005;
  profile.delta.assign(static_cast<size_t>(2 * state.range(0)), -400);
  profile.delta.back() = 850;
  Rng rng(2);
  for (auto _ : state) {
    const Vec2 origin(rng.Uniform() - 0.5, rng.Uniform() - 0.5);
    benchmark::DoNotOptimize(ApplyUpdateRay(grid, origin, rng.Uniform() * 2 * kPi, profile));
  }
  state.SetItemsProcessed(state.iterations());
  state.SetLabel("rays");
}
BENCHMARK(BM_ApplyUpdateRay)->Arg(30)->Arg(100);

}  // namespace
}  // namespace slam

BENCHMARK_MAIN();
