// slamd benchmarks: tile PNG encoding, and request handling of the real HTTP server in process
// (SlamService + HttpServer on a free loopback port, after mapping 20 s of the virtual marXbot
// at 8125 rays/scan), measured from httplib clients on keep-alive connections.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "bench/bench_support.hpp"
#include "engine/cell_encoding.hpp"
#include "engine/grid_geometry.hpp"
#include "engine/io/map_image.hpp"
#include "hw_link/link.hpp"
#include "server/http_server.hpp"
#include "server/slam_service.hpp"
#include "server/tune_jobs.hpp"
#include "sim/virtual_marxbot.hpp"

// After Eigen (through the engine's headers): <resolv.h>, which httplib includes, defines a
// `_res` macro that breaks Eigen's templates when it comes first.
// clang-format off
#include <httplib.h>
// clang-format on

namespace slam::bench {
namespace {

// Every tile of the engine's map of 120 s of the rooms run, encoded as slamd's 64 x 64 grey PNG
// (conversion included). Items are tiles.
void BM_TilePng(benchmark::State& state) {
  static const std::vector<TileRef> tiles =
      MappedEngine(RoomsRun(120.0), 1'000'000, 16250, 1).Best().map.Tiles();
  size_t i = 0;
  int64_t bytes = 0;
  for (auto _ : state) {
    const Result<io::PngBytes> png =
        io::EncodeGrayPng(kTileSize, kTileSize, io::TileGray(*tiles[i++ % tiles.size()].tile));
    if (!png.ok()) {
      state.SkipWithError(png.Message().c_str());
      break;
    }
    bytes += static_cast<int64_t>(png.value().size());
  }
  Items(state, state.iterations(), "tiles");
  state.counters["png_bytes"] =
      static_cast<double>(bytes) / static_cast<double>(std::max<int64_t>(1, state.iterations()));
}
BENCHMARK(BM_TilePng);

/// slamd in process: the virtual marXbot (unpaced, 20 s) -> link -> SLAM service -> HTTP server
/// on a free loopback port. Built by the first request benchmark, stopped by main.
class Slamd {
 public:
  Slamd() {
    sim::ScenarioConfig scenario;
    scenario.seed = 7;
    sim::VirtualMarxbotOptions virtual_options;
    virtual_options.paced = false;
    virtual_options.duration_s = 20.0;
    auto source = std::make_unique<sim::VirtualMarxbotSource>(
        *sim::BuiltinWorld("rooms"), "rooms", ShippedRobot(), scenario, virtual_options);
    sim::VirtualMarxbotSource* truth = source.get();
    hw::LinkOptions link_options;
    link_options.queue_capacity = 1 << 16;  // the unpaced source must not lose events
    link_ = std::make_unique<hw::Link>(std::move(source), ShippedRobot(), link_options);
    server::ServiceOptions service_options;
    service_options.robot = ShippedRobot();
    service_options.budget.rays_per_scan = 8125;
    service_ = std::make_unique<server::SlamService>(*link_, truth, service_options);
    jobs_ = std::make_unique<server::JobManager>("", "");
    link_->Start();
    service_->Start();
    // Wait (bounded) until the whole run is mapped, so that the map no longer changes.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    auto snapshot = service_->Snapshot();
    while (std::chrono::steady_clock::now() < deadline) {
      const int64_t before = service_->Counters().scans;
      snapshot = service_->WaitNewer(snapshot->sequence, std::chrono::milliseconds(500));
      if (link_->Drained() && service_->Counters().scans == before) break;
    }
    snapshot = service_->Snapshot();
    if (!snapshot->tiles.empty()) {
      const TileIndex t = snapshot->tiles[snapshot->tiles.size() / 2].index;
      tile_path_ = "/api/v1/map/tiles/" + std::to_string(t.x) + "/" + std::to_string(t.y) + ".png";
    }
    server::HttpOptions http;
    http.port = 0;
    server_ = std::make_unique<server::HttpServer>(*service_, *link_, *jobs_, http);
    const Result<int> bound = server_->Bind();
    if (!bound.ok()) {
      std::fprintf(stderr, "server_bench: %s\n", bound.Message().c_str());
      port_ = -1;
      return;
    }
    port_ = bound.value();
    thread_ = std::thread([this] { server_->Run(); });
  }
  ~Slamd() {
    if (thread_.joinable()) {
      server_->Stop();
      thread_.join();
    }
    service_->Stop();
    link_->Stop();
  }
  Slamd(const Slamd&) = delete;
  Slamd& operator=(const Slamd&) = delete;

  int port() const { return port_; }
  int64_t scans() const { return service_->Counters().scans; }
  const std::string& tile_path() const { return tile_path_; }

 private:
  std::unique_ptr<hw::Link> link_;
  std::unique_ptr<server::SlamService> service_;
  std::unique_ptr<server::JobManager> jobs_;
  std::unique_ptr<server::HttpServer> server_;
  int port_ = -1;
  std::string tile_path_;
  std::thread thread_;
};

std::mutex slamd_mutex;
std::unique_ptr<Slamd> slamd;

Slamd& SharedSlamd() {
  const std::lock_guard lock(slamd_mutex);
  if (!slamd) slamd = std::make_unique<Slamd>();
  return *slamd;
}

enum Route : int64_t { kHealth, kStatus, kBudget, kMapIndex, kTile, kMetrics };

std::string PathOf(int64_t route, const Slamd& server) {
  switch (route) {
    case kHealth:
      return "/api/v1/health";
    case kStatus:
      return "/api/v1/status";
    case kBudget:
      return "/api/v1/budget";
    case kMapIndex:
      return "/api/v1/map";
    case kTile:
      return server.tile_path();
    default:
      return "/metrics";
  }
}

// GET of route range(0) (0 health, 1 status, 2 budget, 3 map index, 4 a tile PNG, 5 /metrics)
// from each benchmark thread's own keep-alive connection. Items are requests.
void BM_SlamdRequest(benchmark::State& state) {
  Slamd& server = SharedSlamd();
  if (server.port() < 0 || server.tile_path().empty()) {
    state.SkipWithError("slamd did not start or mapped nothing");
    for (auto _ : state) {
    }
    return;
  }
  const std::string path = PathOf(state.range(0), server);
  httplib::Client client("127.0.0.1", server.port());
  client.set_keep_alive(true);
  client.set_tcp_nodelay(true);
  int64_t bytes = 0;
  for (auto _ : state) {
    const httplib::Result res = client.Get(path);
    if (!res || res->status != 200) {
      state.SkipWithError(("GET " + path + " failed").c_str());
      break;
    }
    bytes += static_cast<int64_t>(res->body.size());
  }
  Items(state, state.iterations(), "requests");
  state.SetBytesProcessed(bytes);
  if (state.thread_index() == 0)
    state.counters["scans_mapped"] = static_cast<double>(server.scans());
}
BENCHMARK(BM_SlamdRequest)
    ->ArgName("route")
    ->DenseRange(kHealth, kMetrics)
    ->Threads(1)
    ->Threads(2)
    ->UseRealTime();

}  // namespace
}  // namespace slam::bench

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  slam::bench::slamd.reset();  // stops the server, the SLAM thread and the link before exit
  return 0;
}
