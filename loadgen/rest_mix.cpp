#include "loadgen/rest_mix.hpp"

#include <httplib.h>

#include <algorithm>
#include <thread>

namespace slam::loadgen {

RequestKind KindOf(uint64_t k) {
  if (k % 50 == 49) return RequestKind::kPatchBudget;
  switch (k % 5) {
    case 0:
      return RequestKind::kStatus;
    case 1:
      return RequestKind::kBudget;
    case 2:
      return RequestKind::kMap;
    case 3:
      return RequestKind::kTile;
    default:
      return RequestKind::kMetrics;
  }
}

void RestWorker(const RestConfig& config, std::atomic<uint64_t>& next, TileBook& tiles,
                Record& record, Clock::time_point& last_done) {
  httplib::Client client(config.target.host, config.target.port);
  client.set_keep_alive(true);
  client.set_tcp_nodelay(true);
  client.set_connection_timeout(2);
  client.set_read_timeout(10);
  httplib::Headers patch_headers;
  if (!config.token.empty()) patch_headers.emplace("Authorization", "Bearer " + config.token);
  const double period_s = 1.0 / config.rate_hz;
  while (true) {
    const uint64_t k = next++;
    if (k >= config.total) return;
    const auto due =
        config.start + std::chrono::duration_cast<Clock::duration>(
                           std::chrono::duration<double>(period_s * static_cast<double>(k)));
    std::this_thread::sleep_until(due);
    if (Clock::now() >= config.end) return;
    const auto send = [&]() -> httplib::Result {
      switch (KindOf(k)) {
        case RequestKind::kStatus:
          return client.Get("/api/v1/status");
        case RequestKind::kBudget:
          return client.Get("/api/v1/budget");
        case RequestKind::kMap:
          return client.Get("/api/v1/map");
        case RequestKind::kMetrics:
          return client.Get("/metrics");
        case RequestKind::kTile: {
          const auto tile = tiles.Pick(k / 5);
          if (!tile) return client.Get("/api/v1/map");
          return client.Get("/api/v1/map/tiles/" + std::to_string(tile->first) + "/" +
                            std::to_string(tile->second) + ".png");
        }
        case RequestKind::kPatchBudget:
          return client.Patch("/api/v1/budget", patch_headers, config.patch_body,
                              "application/merge-patch+json");
      }
      return client.Get("/api/v1/status");
    };
    const auto result = send();
    const auto done = Clock::now();
    // Open loop: latency from the due time, so queueing behind a slow answer is counted.
    record.Add(SecondsBetween(due, done) * 1e3, result ? result->status : 0);
    last_done = std::max(last_done, done);
  }
}

}  // namespace slam::loadgen
