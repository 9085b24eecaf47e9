#pragma once
// What a load run measures and how it summarises it: request latencies and statuses, their
// percentiles, Prometheus samples, and the trend of a process's resident set.

#include <chrono>
#include <cstdint>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace slam::loadgen {

using Clock = std::chrono::steady_clock;

/// Seconds from `from` to `to`.
double SecondsBetween(Clock::time_point from, Clock::time_point to);

/// Where slamd listens.
struct Target {
  std::string host;
  int port = 0;
};

/// "http://HOST[:PORT][/...]" -> host and port (80 by default); nullopt for anything else.
/// Another `scheme` ("ws://") likewise.
std::optional<Target> ParseUrl(const std::string& url, const std::string& scheme = "http://");

/// Every request's latency and outcome; one per thread, merged at the end (no contention).
struct Record {
  std::vector<double> latencies_ms;
  std::map<int, int64_t> statuses;  // HTTP status, or 0 for transport failures
  int64_t errors = 0;               // anything but 2xx and 304

  void Add(double latency_ms, int status);
  void Merge(const Record& other);
};

struct Percentiles {
  double p50 = 0, p90 = 0, p99 = 0, max = 0;
};

/// Nearest-rank percentiles of `values`; zeros when empty.
Percentiles Summarise(std::vector<double> values);

/// How the resident set moved: over the run's second half (after the map's first growth) its
/// change and least-squares slope, and one sample every 10 s for the record.
struct RssTrend {
  std::optional<double> second_half_growth_mib;
  std::optional<double> second_half_slope_mib_per_min;
  nlohmann::json every_10_s = nlohmann::json::array();
};

/// The trend of (seconds since the start, MiB) samples in time order.
RssTrend Trend(const std::vector<std::pair<double, double>>& series);

/// Sum of the samples named `name` (any labels) in Prometheus text; nullopt if absent.
std::optional<double> MetricValue(const std::string& text, const std::string& name);

/// The resident set of `pid` in MiB (VmRSS), nullopt if it cannot be read.
std::optional<double> ReadRssMib(int pid);

}  // namespace slam::loadgen
