#include "loadgen/load_run.hpp"

#include <httplib.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>
#include <vector>

#include "loadgen/foxglove_viewer.hpp"
#include "loadgen/rest_mix.hpp"
#include "loadgen/viewer.hpp"

namespace slam::loadgen {
namespace {

using json = nlohmann::json;

json OptionalJson(const std::optional<double>& value) {
  return value ? json(*value) : json(nullptr);
}

/// Scans the assembler abandoned (gaps in the robot's data) are in the status, not /metrics.
std::optional<double> ScansDiscarded(httplib::Client& probe) {
  const auto status = probe.Get("/api/v1/status");
  if (!status || status->status != 200) return std::nullopt;
  const json parsed = json::parse(status->body, nullptr, false);
  const json* value = &parsed;
  for (const char* key : {"slam", "assembler", "scans_discarded"}) {
    if (!value->is_object() || !value->contains(key)) return std::nullopt;
    value = &(*value)[key];
  }
  if (!value->is_number()) return std::nullopt;
  return value->get<double>();
}

/// Samples a process's resident set every second on its own thread until Stop().
class RssSampler {
 public:
  explicit RssSampler(int pid) : pid_(pid) {}
  ~RssSampler() { Stop(); }

  /// Takes the first sample and starts the thread; false if /proc/PID cannot be read.
  bool Start() {
    start_ = ReadRssMib(pid_);
    if (!start_) return false;
    max_ = start_;
    series_.emplace_back(0.0, *start_);
    thread_ = std::thread([this] { Sample(); });
    return true;
  }

  void Stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }

  // Read after Stop().
  std::optional<double> start() const { return start_; }
  std::optional<double> end() const { return end_ ? end_ : start_; }
  std::optional<double> max() const { return max_; }
  const std::vector<std::pair<double, double>>& series() const { return series_; }

 private:
  void Sample() {
    const auto first = Clock::now();
    auto next_sample = first;
    while (!stop_) {
      next_sample += std::chrono::seconds(1);
      while (!stop_ && Clock::now() < next_sample) {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
      }
      const auto rss = ReadRssMib(pid_);
      if (rss) {
        end_ = rss;
        max_ = std::max(*max_, *rss);
        series_.emplace_back(SecondsBetween(first, Clock::now()), *rss);
      }
    }
  }

  int pid_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
  // Written by the thread only while it runs, read after Stop() joined it.
  std::optional<double> start_, end_, max_;
  std::vector<std::pair<double, double>> series_;  // (seconds since the start, MiB)
};

json LatencyJson(const Percentiles& p) {
  return {{"p50", p.p50}, {"p90", p.p90}, {"p99", p.p99}, {"max", p.max}};
}

}  // namespace

Result<json> RunLoad(const LoadOptions& options) {
  // Reachable? And the budget's current value, which the PATCHes set back.
  httplib::Client probe(options.target.host, options.target.port);
  probe.set_connection_timeout(2);
  probe.set_read_timeout(5);
  const auto health = probe.Get("/api/v1/health");
  if (!health || health->status != 200) {
    return Error("slamd is not reachable at " + options.url + ": " +
                 (health ? "HTTP " + std::to_string(health->status)
                         : httplib::to_string(health.error())));
  }
  const auto budget = probe.Get("/api/v1/budget");
  const json budget_json = budget ? json::parse(budget->body, nullptr, false) : json();
  if (!budget || budget->status != 200 || !budget_json.is_object() ||
      !budget_json.contains("rays_per_scan")) {
    return Error("GET /api/v1/budget failed");
  }
  const auto metrics_before = probe.Get("/metrics");
  if (!metrics_before || metrics_before->status != 200) return Error("GET /metrics failed");
  const std::optional<double> discarded_before = ScansDiscarded(probe);

  RssSampler rss(options.pid);
  if (options.pid > 0 && !rss.Start()) {
    return Error("cannot read /proc/" + std::to_string(options.pid) + "/status");
  }

  // Viewers first, so that the REST load meets a server already serving streams.
  std::atomic<bool> stop{false};
  ViewerStats viewer_stats;
  TileBook tiles;
  std::vector<std::unique_ptr<Viewer>> viewers;
  std::vector<std::thread> viewer_threads;
  for (int i = 0; i < options.viewers; ++i) {
    viewers.push_back(std::make_unique<Viewer>(options.target, stop, viewer_stats, tiles));
  }
  for (auto& viewer : viewers) viewer_threads.emplace_back([&viewer] { viewer->Run(); });
  FoxgloveStats foxglove_stats;
  for (int i = 0; i < options.foxglove_clients; ++i) {
    viewer_threads.emplace_back([&] {
      RunFoxgloveViewer(options.foxglove, options.token, stop, foxglove_stats);
    });
  }

  RestConfig config;
  config.target = options.target;
  config.rate_hz = options.rate_hz;
  config.total = static_cast<uint64_t>(std::llround(options.rate_hz * options.duration_s));
  config.start = Clock::now();
  config.end = config.start + std::chrono::duration_cast<Clock::duration>(
                                  std::chrono::duration<double>(options.duration_s));
  config.patch_body = json({{"rays_per_scan", budget_json["rays_per_scan"]}}).dump();
  config.token = options.token;
  std::atomic<uint64_t> next{0};
  const auto connections = static_cast<size_t>(std::max(1, options.connections));
  std::vector<Record> records(connections);
  std::vector<Clock::time_point> last_done(connections, config.start);
  std::vector<std::thread> workers;
  for (size_t i = 0; i < connections; ++i) {
    records[i].latencies_ms.reserve(config.total / connections + 16);
    workers.emplace_back([&, i] { RestWorker(config, next, tiles, records[i], last_done[i]); });
  }
  // With a rate of 0 only the viewers load slamd: wait out the duration.
  std::this_thread::sleep_until(config.end);
  for (auto& worker : workers) worker.join();
  const auto rest_end =
      std::max(Clock::now(), *std::max_element(last_done.begin(), last_done.end()));
  const int viewers_connected = viewer_stats.connected.load();
  const int foxglove_connected = foxglove_stats.connected.load();
  // The memory is sampled under load only: once the clients leave, slamd returns the pages
  // their buffers held, and a last sample then would hide growth over the second half.
  rss.Stop();
  stop = true;
  for (auto& thread : viewer_threads) thread.join();

  const auto metrics_after = probe.Get("/metrics");
  if (!metrics_after || metrics_after->status != 200) {
    return Error("GET /metrics after the run failed");
  }
  const auto delta = [&](const std::string& name) -> std::optional<double> {
    const auto before = MetricValue(metrics_before->body, name);
    const auto after = MetricValue(metrics_after->body, name);
    if (!before || !after) return std::nullopt;
    return *after - *before;
  };
  const std::optional<double> discarded_after = ScansDiscarded(probe);
  std::optional<double> missed_scans;
  if (discarded_before && discarded_after) missed_scans = *discarded_after - *discarded_before;
  const RssTrend trend = Trend(rss.series());

  Record rest;
  for (const auto& record : records) rest.Merge(record);
  Record tile_fetches;
  for (const auto& viewer : viewers) tile_fetches.Merge(viewer->tile_record());
  const Percentiles tile_latency = Summarise(tile_fetches.latencies_ms);
  const double elapsed_s = SecondsBetween(config.start, rest_end);
  const auto requests = static_cast<int64_t>(rest.latencies_ms.size());
  // Requests that were due but still waiting for a connection when the time was up.
  const int64_t unsent = static_cast<int64_t>(config.total) - requests;
  const double achieved_rate = elapsed_s > 0 ? static_cast<double>(requests) / elapsed_s : 0.0;

  json statuses = json::object();
  for (const auto& [status, count] : rest.statuses) statuses[std::to_string(status)] = count;
  return json{
      {"url", options.url},
      {"duration_s", options.duration_s},
      {"rate_target", options.rate_hz},
      {"requests", requests},
      {"requests_unsent", unsent},
      {"errors", rest.errors + tile_fetches.errors},
      {"rest_errors", rest.errors},
      {"statuses", statuses},
      {"latency_ms", LatencyJson(Summarise(rest.latencies_ms))},
      {"achieved_rate", achieved_rate},
      {"viewers", options.viewers},
      {"viewers_connected", viewers_connected},
      {"viewer_connects", viewer_stats.connects.load()},
      {"viewer_rejections", viewer_stats.rejected.load()},
      {"viewer_disconnects", viewer_stats.disconnects.load()},
      {"events_received", viewer_stats.events.load()},
      {"tile_fetches", static_cast<int64_t>(tile_fetches.latencies_ms.size())},
      {"tile_errors", tile_fetches.errors},
      {"tile_latency_ms",
       {{"p50", tile_latency.p50}, {"p99", tile_latency.p99}, {"max", tile_latency.max}}},
      {"foxglove",
       {{"clients", options.foxglove_clients},
        {"connected", foxglove_connected},
        {"connects", foxglove_stats.connects.load()},
        {"refused", foxglove_stats.refused.load()},
        {"disconnects", foxglove_stats.disconnects.load()},
        {"messages", foxglove_stats.messages.load()},
        {"bytes", foxglove_stats.bytes.load()},
        {"maps", foxglove_stats.maps.load()},
        {"poses", foxglove_stats.poses.load()},
        {"status_messages", foxglove_stats.statuses.load()},
        {"first_map_ms", foxglove_stats.first_map_ms.load()},
        {"first_pose_ms", foxglove_stats.first_pose_ms.load()},
        {"dropped_by_slamd", OptionalJson(delta("slamd_foxglove_messages_dropped_total"))}}},
      {"scans", OptionalJson(delta("slamd_scans_total"))},
      {"late_scans", OptionalJson(delta("slamd_late_scans_total"))},
      {"link_queue_drops", OptionalJson(delta("slamd_link_queue_drops_total"))},
      {"missed_scans", OptionalJson(missed_scans)},
      {"rss_mib",
       {{"start", OptionalJson(rss.start())},
        {"end", OptionalJson(rss.end())},
        {"max", OptionalJson(rss.max())},
        {"second_half_growth", OptionalJson(trend.second_half_growth_mib)},
        {"second_half_slope_mib_per_min", OptionalJson(trend.second_half_slope_mib_per_min)},
        {"every_10_s", trend.every_10_s}}},
  };
}

void PrintTable(const json& report, std::ostream& out) {
  const auto number = [](const json& value, int digits) {
    if (!value.is_number()) return std::string("n/a");
    char text[64];
    std::snprintf(text, sizeof text, "%.*f", digits, value.get<double>());
    return std::string(text);
  };
  const json& latency = report["latency_ms"];
  const json& rss = report["rss_mib"];
  out << "slamd-load against " << report["url"].get<std::string>() << " for "
      << report["duration_s"] << " s\n"
      << "  REST requests      " << report["requests"] << " at "
      << number(report["achieved_rate"], 1) << "/s (target " << report["rate_target"]
      << "/s), errors " << report["rest_errors"] << ", unsent " << report["requests_unsent"]
      << "\n"
      << "  latency ms         p50 " << number(latency["p50"], 2) << "  p90 "
      << number(latency["p90"], 2) << "  p99 " << number(latency["p99"], 2) << "  max "
      << number(latency["max"], 2) << "\n"
      << "  viewers            " << report["viewers_connected"] << "/" << report["viewers"]
      << " connected, " << report["events_received"] << " events, "
      << report["viewer_rejections"] << " rejected, " << report["viewer_disconnects"]
      << " disconnects\n"
      << "  tile fetches       " << report["tile_fetches"] << ", errors " << report["tile_errors"]
      << ", p99 " << number(report["tile_latency_ms"]["p99"], 2) << " ms\n"
      << "  Foxglove clients   " << report["foxglove"]["connected"] << "/"
      << report["foxglove"]["clients"] << " connected, " << report["foxglove"]["messages"]
      << " messages (" << report["foxglove"]["maps"] << " maps, " << report["foxglove"]["poses"]
      << " poses), first map after " << report["foxglove"]["first_map_ms"] << " ms, "
      << report["foxglove"]["disconnects"] << " disconnects, "
      << number(report["foxglove"]["dropped_by_slamd"], 0) << " dropped by slamd\n"
      << "  scans              " << number(report["scans"], 0) << ", late "
      << number(report["late_scans"], 0) << ", missed " << number(report["missed_scans"], 0)
      << ", link queue drops " << number(report["link_queue_drops"], 0) << "\n"
      << "  RSS MiB            start " << number(rss["start"], 1) << "  end "
      << number(rss["end"], 1) << "  max " << number(rss["max"], 1)
      << "  second half: " << number(rss["second_half_growth"], 2) << " MiB, "
      << number(rss["second_half_slope_mib_per_min"], 3) << " MiB/min\n";
  if (!rss["every_10_s"].empty()) {
    out << "  RSS every 10 s    ";
    for (const auto& value : rss["every_10_s"]) out << " " << number(value, 1);
    out << "\n";
  }
  out << "  statuses          ";
  for (const auto& [status, count] : report["statuses"].items()) {
    out << " " << (status == "0" ? std::string("transport-failure") : status) << ":" << count;
  }
  out << "\n";
}

}  // namespace slam::loadgen
