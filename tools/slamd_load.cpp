// slamd-load: a load generator for slamd (docs/http-api.md).
//
// N viewers behave like the web page: each holds one event stream, reads it continuously and
// fetches every tile PNG a `tiles` event announces (over its own keep-alive connection, like a
// browser's second connection). Meanwhile REST requests go out on an open-loop schedule at a
// fixed rate (request k is due at start + k / rate whatever happened before, and its latency is
// counted from that due time, so a slow server cannot slow the load down and hide its own
// queueing; what is still waiting when the time is up is reported as unsent). The mix cycles
// through GET status, budget, map, a tile and /metrics, with a PATCH of the budget to its own value
// every 50th request. /metrics is read before and after (scans, late scans, link queue drops), the
// status too (scans the assembler had to abandon: missed scans), and the RSS of --pid is sampled
// every second (its growth and slope over the run's second half say whether memory is flat).
//
//   slamd-load --url http://127.0.0.1:8080/ [--viewers 8] [--rate 500] [--duration 60]
//              [--token-file F] [--pid PID] [--json]
//
// The table goes to stdout, or to stderr with --json, which prints one JSON object on stdout.

#include <arpa/inet.h>
#include <httplib.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace {

using json = nlohmann::json;
using Clock = std::chrono::steady_clock;

struct Target {
  std::string host;
  int port = 0;
};

/// "http://HOST:PORT[/...]" -> host and port; nullopt for anything else.
std::optional<Target> ParseUrl(const std::string& url) {
  const std::string scheme = "http://";
  if (url.compare(0, scheme.size(), scheme) != 0) return std::nullopt;
  const std::string rest = url.substr(scheme.size());
  const size_t slash = rest.find('/');
  const std::string authority = rest.substr(0, slash);
  const size_t colon = authority.rfind(':');
  Target target;
  if (colon == std::string::npos) {
    target.host = authority;
    target.port = 80;
  } else {
    target.host = authority.substr(0, colon);
    char* end = nullptr;
    const long port = std::strtol(authority.c_str() + colon + 1, &end, 10);
    if (end == nullptr || *end != '\0' || port <= 0 || port > 65535) return std::nullopt;
    target.port = static_cast<int>(port);
  }
  if (target.host.empty()) return std::nullopt;
  return target;
}

double SecondsBetween(Clock::time_point from, Clock::time_point to) {
  return std::chrono::duration<double>(to - from).count();
}

// --- latency records ------------------------------------------------------------------------

/// Every request's latency and outcome; one per thread, merged at the end (no contention).
struct Record {
  std::vector<double> latencies_ms;
  std::map<int, int64_t> statuses;  // HTTP status, or 0 for transport failures
  int64_t errors = 0;

  void Add(double latency_ms, int status) {
    latencies_ms.push_back(latency_ms);
    ++statuses[status];
    const bool ok = (status >= 200 && status < 300) || status == 304;
    if (!ok) ++errors;
  }
  void Merge(const Record& other) {
    latencies_ms.insert(latencies_ms.end(), other.latencies_ms.begin(), other.latencies_ms.end());
    for (const auto& [status, count] : other.statuses) statuses[status] += count;
    errors += other.errors;
  }
};

struct Percentiles {
  double p50 = 0, p90 = 0, p99 = 0, max = 0;
};

Percentiles Summarise(std::vector<double> values) {
  Percentiles result;
  if (values.empty()) return result;
  std::sort(values.begin(), values.end());
  const auto at = [&](double q) {
    const auto rank = static_cast<size_t>(std::ceil(q * static_cast<double>(values.size())));
    return values[std::min(values.size() - 1, rank == 0 ? 0 : rank - 1)];
  };
  result.p50 = at(0.50);
  result.p90 = at(0.90);
  result.p99 = at(0.99);
  result.max = values.back();
  return result;
}

// --- /metrics and /proc ---------------------------------------------------------------------

/// Sum of the samples named `name` (any labels) in Prometheus text; nullopt if absent.
/// How the resident set moved: over the run's second half (after the map's first growth) its
/// change and least-squares slope, and one sample every 10 s for the record.
struct RssTrend {
  std::optional<double> second_half_growth_mib;
  std::optional<double> second_half_slope_mib_per_min;
  json every_10_s = json::array();
};

RssTrend Trend(const std::vector<std::pair<double, double>>& series) {
  RssTrend trend;
  double next_mark = 0.0;
  for (const auto& [t, mib] : series) {
    if (t + 0.5 >= next_mark) {
      trend.every_10_s.push_back(std::round(mib * 10.0) / 10.0);
      next_mark += 10.0;
    }
  }
  if (series.size() < 4) return trend;
  const double half = series.back().first / 2.0;
  std::vector<std::pair<double, double>> tail;
  for (const auto& sample : series) {
    if (sample.first >= half) tail.push_back(sample);
  }
  if (tail.size() < 2) return trend;
  trend.second_half_growth_mib = tail.back().second - tail.front().second;
  double mt = 0.0, mm = 0.0;
  for (const auto& [t, mib] : tail) {
    mt += t;
    mm += mib;
  }
  mt /= static_cast<double>(tail.size());
  mm /= static_cast<double>(tail.size());
  double stt = 0.0, stm = 0.0;
  for (const auto& [t, mib] : tail) {
    stt += (t - mt) * (t - mt);
    stm += (t - mt) * (mib - mm);
  }
  if (stt > 0.0) trend.second_half_slope_mib_per_min = stm / stt * 60.0;
  return trend;
}

std::optional<double> MetricValue(const std::string& text, const std::string& name) {
  std::istringstream lines(text);
  std::string line;
  std::optional<double> sum;
  while (std::getline(lines, line)) {
    if (line.empty() || line.front() == '#') continue;
    if (line.compare(0, name.size(), name) != 0) continue;
    if (line.size() <= name.size() || (line[name.size()] != ' ' && line[name.size()] != '{')) {
      continue;
    }
    const size_t value_at = line.rfind(' ');
    sum = sum.value_or(0.0) + std::strtod(line.c_str() + value_at + 1, nullptr);
  }
  return sum;
}

/// The resident set of `pid` in MiB (VmRSS), nullopt if it cannot be read.
std::optional<double> ReadRssMib(int pid) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.compare(0, 6, "VmRSS:") == 0) {
      return std::strtod(line.c_str() + 6, nullptr) / 1024.0;  // kB -> MiB
    }
  }
  return std::nullopt;
}

// --- event-stream viewers -----------------------------------------------------------------

int ConnectTo(const Target& target) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  if (::getaddrinfo(target.host.c_str(), std::to_string(target.port).c_str(), &hints, &found) !=
      0) {
    return -1;
  }
  int fd = -1;
  for (addrinfo* a = found; a != nullptr && fd < 0; a = a->ai_next) {
    fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
    if (fd >= 0 && ::connect(fd, a->ai_addr, a->ai_addrlen) != 0) {
      ::close(fd);
      fd = -1;
    }
  }
  ::freeaddrinfo(found);
  return fd;
}

struct ViewerStats {
  std::atomic<int64_t> events{0};
  std::atomic<int64_t> tiles_announced{0};
  std::atomic<int> connected{0};
  std::atomic<int64_t> connects{0};
  std::atomic<int64_t> rejected{0};     // non-200 answers to the stream request (503 at the cap)
  std::atomic<int64_t> disconnects{0};  // streams that ended while the run went on
};

/// Shared knowledge of which tiles exist, for the REST mix's tile requests.
class TileBook {
 public:
  void Note(int64_t x, int64_t y) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (tiles_.size() < 4096) tiles_[{x, y}] = true;
  }
  std::optional<std::pair<int64_t, int64_t>> Pick(uint64_t k) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (tiles_.empty()) return std::nullopt;
    auto it = tiles_.begin();
    std::advance(it, static_cast<std::ptrdiff_t>(k % tiles_.size()));
    return it->first;
  }

 private:
  std::mutex mutex_;
  std::map<std::pair<int64_t, int64_t>, bool> tiles_;
};

/// One viewer: a text/event-stream read continuously, tiles fetched as announced. Reconnects
/// with Last-Event-ID when the stream ends, as a browser's EventSource does.
class Viewer {
 public:
  Viewer(const Target& target, const std::atomic<bool>& stop, ViewerStats& stats, TileBook& tiles)
      : target_(target),
        stop_(stop),
        stats_(stats),
        tiles_(tiles),
        tile_client_(target.host, target.port) {
    tile_client_.set_keep_alive(true);
    tile_client_.set_tcp_nodelay(true);
    tile_client_.set_connection_timeout(2);
    tile_client_.set_read_timeout(10);
  }

  void Run() {
    while (!stop_) {
      if (!Connect()) {
        // Refused or unreachable: try again a little later (a browser would wait Retry-After).
        for (int i = 0; i < 10 && !stop_; ++i)
          std::this_thread::sleep_for(std::chrono::milliseconds(100));
        continue;
      }
      ++stats_.connected;
      ++stats_.connects;
      ReadUntilEnd();
      --stats_.connected;
      ::close(fd_);
      fd_ = -1;
      if (!stop_) ++stats_.disconnects;
    }
  }

  const Record& tile_record() const { return tile_record_; }

 private:
  bool Connect() {
    fd_ = ConnectTo(target_);
    if (fd_ < 0) return false;
    std::string request = "GET /api/v1/events HTTP/1.1\r\nHost: " + target_.host + ":" +
                          std::to_string(target_.port) +
                          "\r\nAccept: text/event-stream\r\nCache-Control: no-cache\r\n";
    if (!last_event_id_.empty()) request += "Last-Event-ID: " + last_event_id_ + "\r\n";
    request += "\r\n";
    if (::send(fd_, request.data(), request.size(), MSG_NOSIGNAL) !=
        static_cast<ssize_t>(request.size())) {
      return Fail();
    }
    wire_.clear();
    text_.clear();
    // Response head.
    const auto deadline = Clock::now() + std::chrono::seconds(5);
    size_t head_end = std::string::npos;
    while ((head_end = wire_.find("\r\n\r\n")) == std::string::npos) {
      if (Clock::now() > deadline || !ReadSome(200)) return Fail();
    }
    const std::string head = wire_.substr(0, head_end);
    wire_.erase(0, head_end + 4);
    const int status = head.size() > 12 ? std::atoi(head.c_str() + 9) : -1;
    if (status != 200) {
      ++stats_.rejected;
      return Fail();
    }
    std::string lower_head = head;
    std::transform(lower_head.begin(), lower_head.end(), lower_head.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    chunked_ = lower_head.find("transfer-encoding: chunked") != std::string::npos;
    return true;
  }

  bool Fail() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    return false;
  }

  /// Reads what arrives within `timeout_ms`; false on end of stream or error.
  bool ReadSome(int timeout_ms) {
    pollfd waiter{fd_, POLLIN, 0};
    const int ready = ::poll(&waiter, 1, timeout_ms);
    if (ready == 0) return true;
    if (ready < 0) return errno == EINTR;
    char buffer[16384];
    const ssize_t n = ::recv(fd_, buffer, sizeof buffer, 0);
    if (n <= 0) return false;
    wire_.append(buffer, static_cast<size_t>(n));
    return true;
  }

  void ReadUntilEnd() {
    while (!stop_) {
      if (!ReadSome(200)) return;
      if (!Decode()) return;
      HandleEvents();
    }
  }

  /// Moves stream bytes to `text_`, undoing chunked framing; false at the final chunk.
  bool Decode() {
    if (!chunked_) {
      text_ += wire_;
      wire_.clear();
      return true;
    }
    while (true) {
      const size_t line_end = wire_.find("\r\n");
      if (line_end == std::string::npos) return true;
      const size_t size = std::strtoul(wire_.substr(0, line_end).c_str(), nullptr, 16);
      if (size == 0) return false;
      if (wire_.size() < line_end + 2 + size + 2) return true;
      text_ += wire_.substr(line_end + 2, size);
      wire_.erase(0, line_end + 2 + size + 2);
    }
  }

  void HandleEvents() {
    size_t end;
    while ((end = text_.find("\n\n")) != std::string::npos) {
      const std::string block = text_.substr(0, end);
      text_.erase(0, end + 2);
      std::string name = "message", id, data;
      bool has_field = false;
      std::istringstream lines(block);
      std::string line;
      while (std::getline(lines, line)) {
        if (!line.empty() && line.back() == '\r') line.pop_back();
        if (line.empty() || line.front() == ':') continue;  // comments are pings
        const size_t colon = line.find(':');
        const std::string field = line.substr(0, colon);
        std::string value = colon == std::string::npos ? "" : line.substr(colon + 1);
        if (!value.empty() && value.front() == ' ') value.erase(0, 1);
        has_field = true;
        if (field == "event") name = value;
        if (field == "id") id = value;
        if (field == "data") data += value;
      }
      if (!has_field) continue;
      ++stats_.events;
      if (!id.empty()) last_event_id_ = id;
      if (name == "tiles") FetchTiles(data);
    }
  }

  void FetchTiles(const std::string& data) {
    const json parsed = json::parse(data, nullptr, false);
    if (!parsed.is_object() || !parsed.contains("tiles") || !parsed["tiles"].is_array()) return;
    for (const auto& tile : parsed["tiles"]) {
      if (stop_) return;
      if (!tile.contains("x") || !tile.contains("y") || !tile["x"].is_number_integer() ||
          !tile["y"].is_number_integer()) {
        continue;
      }
      const int64_t x = tile["x"].get<int64_t>();
      const int64_t y = tile["y"].get<int64_t>();
      tiles_.Note(x, y);
      ++stats_.tiles_announced;
      std::string path =
          "/api/v1/map/tiles/" + std::to_string(x) + "/" + std::to_string(y) + ".png";
      if (tile.contains("version")) path += "?v=" + tile["version"].dump();
      const auto start = Clock::now();
      const auto result = tile_client_.Get(path);
      const double ms = SecondsBetween(start, Clock::now()) * 1e3;
      // A tile can vanish between the announcement and the fetch only through a reset: 404 is
      // then what the page sees too, not a server error.
      const int status = result ? result->status : 0;
      tile_record_.Add(ms, status == 404 ? 200 : status);
    }
  }

  Target target_;
  const std::atomic<bool>& stop_;
  ViewerStats& stats_;
  TileBook& tiles_;
  httplib::Client tile_client_;
  Record tile_record_;
  int fd_ = -1;
  bool chunked_ = false;
  std::string wire_;
  std::string text_;
  std::string last_event_id_;
};

// --- the REST mix ---------------------------------------------------------------------------

enum class Kind { kStatus, kBudget, kMap, kTile, kMetrics, kPatchBudget };

/// Request k of the mix: a PATCH every 50th, otherwise the five GETs in turn.
Kind KindOf(uint64_t k) {
  if (k % 50 == 49) return Kind::kPatchBudget;
  switch (k % 5) {
    case 0:
      return Kind::kStatus;
    case 1:
      return Kind::kBudget;
    case 2:
      return Kind::kMap;
    case 3:
      return Kind::kTile;
    default:
      return Kind::kMetrics;
  }
}

struct RestConfig {
  Target target;
  double rate_hz = 500;
  uint64_t total = 0;
  Clock::time_point start;
  Clock::time_point end;   // nothing is sent after it: a backlog is left unsent, not drained
  std::string patch_body;  // the budget's own rays_per_scan
  std::string token;
};

/// A REST worker: takes the next due request, waits for its due time, sends it.
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
        case Kind::kStatus:
          return client.Get("/api/v1/status");
        case Kind::kBudget:
          return client.Get("/api/v1/budget");
        case Kind::kMap:
          return client.Get("/api/v1/map");
        case Kind::kMetrics:
          return client.Get("/metrics");
        case Kind::kTile: {
          const auto tile = tiles.Pick(k / 5);
          if (!tile) return client.Get("/api/v1/map");
          return client.Get("/api/v1/map/tiles/" + std::to_string(tile->first) + "/" +
                            std::to_string(tile->second) + ".png");
        }
        case Kind::kPatchBudget:
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

std::string Trim(std::string text) {
  const auto not_space = [](unsigned char c) { return !std::isspace(c); };
  text.erase(text.begin(), std::find_if(text.begin(), text.end(), not_space));
  text.erase(std::find_if(text.rbegin(), text.rend(), not_space).base(), text.end());
  return text;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"slamd-load: event-stream viewers plus REST requests at a fixed rate against slamd"};
  std::string url;
  int viewers = 8;
  double rate_hz = 500;
  double duration_s = 60;
  std::string token_file;
  int pid = 0;
  int connections = 4;
  bool as_json = false;
  app.add_option("--url", url, "slamd's base URL, e.g. http://127.0.0.1:8080/")->required();
  app.add_option("--viewers", viewers, "event-stream viewers (each fetches announced tiles)")
      ->capture_default_str()
      ->check(CLI::Range(0, 1000));
  app.add_option("--rate", rate_hz, "REST requests per second (open loop)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100000.0));
  app.add_option("--duration", duration_s, "seconds of load")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 86400.0));
  app.add_option("--token-file", token_file, "bearer token for the PATCH requests")
      ->check(CLI::ExistingFile);
  app.add_option("--pid", pid, "slamd's process id: its RSS is sampled every second")
      ->check(CLI::PositiveNumber);
  app.add_option("--connections", connections, "keep-alive connections for the REST requests")
      ->capture_default_str()
      ->check(CLI::Range(1, 256));
  app.add_flag("--json", as_json, "print one JSON object on stdout (the table goes to stderr)");
  CLI11_PARSE(app, argc, argv);

  const auto target = ParseUrl(url);
  if (!target) {
    std::cerr << "slamd-load: --url must look like http://HOST:PORT/, got '" << url << "'\n";
    return 2;
  }
  std::string token;
  if (!token_file.empty()) {
    std::ifstream in(token_file);
    std::stringstream text;
    text << in.rdbuf();
    token = Trim(text.str());
    if (token.empty()) {
      std::cerr << "slamd-load: the token file " << token_file << " is empty\n";
      return 2;
    }
  }

  // Reachable? And the budget's current value, which the PATCHes set back.
  httplib::Client probe(target->host, target->port);
  probe.set_connection_timeout(2);
  probe.set_read_timeout(5);
  const auto health = probe.Get("/api/v1/health");
  if (!health || health->status != 200) {
    std::cerr << "slamd-load: slamd is not reachable at " << url << ": "
              << (health ? "HTTP " + std::to_string(health->status)
                         : httplib::to_string(health.error()))
              << "\n";
    return 1;
  }
  const auto budget = probe.Get("/api/v1/budget");
  const json budget_json = budget ? json::parse(budget->body, nullptr, false) : json();
  if (!budget || budget->status != 200 || !budget_json.is_object() ||
      !budget_json.contains("rays_per_scan")) {
    std::cerr << "slamd-load: GET /api/v1/budget failed\n";
    return 1;
  }
  const std::string patch_body = json({{"rays_per_scan", budget_json["rays_per_scan"]}}).dump();
  const auto metrics_before = probe.Get("/metrics");
  if (!metrics_before || metrics_before->status != 200) {
    std::cerr << "slamd-load: GET /metrics failed\n";
    return 1;
  }
  // Scans the assembler abandoned (gaps in the robot's data) are in the status, not /metrics.
  const auto scans_discarded = [&probe]() -> std::optional<double> {
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
  };
  const std::optional<double> discarded_before = scans_discarded();

  // RSS sampling.
  std::atomic<bool> stop{false};
  std::optional<double> rss_start, rss_end, rss_max;
  std::vector<std::pair<double, double>> rss_series;  // (seconds since the start, MiB)
  std::mutex rss_mutex;
  std::thread rss_thread;
  if (pid > 0) {
    rss_start = ReadRssMib(pid);
    if (!rss_start) {
      std::cerr << "slamd-load: cannot read /proc/" << pid << "/status\n";
      return 1;
    }
    rss_max = rss_start;
    rss_series.emplace_back(0.0, *rss_start);
    rss_thread = std::thread([&] {
      const auto first = Clock::now();
      auto next_sample = first;
      while (!stop) {
        next_sample += std::chrono::seconds(1);
        while (!stop && Clock::now() < next_sample) {
          std::this_thread::sleep_for(std::chrono::milliseconds(50));
        }
        const auto rss = ReadRssMib(pid);
        std::lock_guard<std::mutex> lock(rss_mutex);
        if (rss) {
          rss_end = rss;
          rss_max = std::max(*rss_max, *rss);
          rss_series.emplace_back(SecondsBetween(first, Clock::now()), *rss);
        }
      }
    });
  }

  // Viewers first, so that the REST load meets a server already serving streams.
  ViewerStats viewer_stats;
  TileBook tiles;
  std::vector<std::unique_ptr<Viewer>> viewer_objects;
  std::vector<std::thread> viewer_threads;
  for (int i = 0; i < viewers; ++i) {
    viewer_objects.push_back(std::make_unique<Viewer>(*target, stop, viewer_stats, tiles));
  }
  for (auto& viewer : viewer_objects) {
    viewer_threads.emplace_back([&viewer] { viewer->Run(); });
  }

  RestConfig config;
  config.target = *target;
  config.rate_hz = rate_hz;
  config.total = static_cast<uint64_t>(std::llround(rate_hz * duration_s));
  config.start = Clock::now();
  config.end = config.start + std::chrono::duration_cast<Clock::duration>(
                                  std::chrono::duration<double>(duration_s));
  config.patch_body = patch_body;
  config.token = token;
  std::atomic<uint64_t> next{0};
  std::vector<Record> records(static_cast<size_t>(connections));
  std::vector<Clock::time_point> last_done(static_cast<size_t>(connections), config.start);
  std::vector<std::thread> workers;
  for (size_t i = 0; i < records.size(); ++i) {
    records[i].latencies_ms.reserve(config.total / records.size() + 16);
    workers.emplace_back([&, i] { RestWorker(config, next, tiles, records[i], last_done[i]); });
  }
  // With --rate 0 only the viewers load slamd: wait out the duration.
  std::this_thread::sleep_until(config.end);
  for (auto& worker : workers) worker.join();
  const auto rest_end =
      std::max(Clock::now(), *std::max_element(last_done.begin(), last_done.end()));
  const int viewers_connected = viewer_stats.connected.load();
  stop = true;
  for (auto& thread : viewer_threads) thread.join();
  if (rss_thread.joinable()) rss_thread.join();

  const auto metrics_after = probe.Get("/metrics");
  if (!metrics_after || metrics_after->status != 200) {
    std::cerr << "slamd-load: GET /metrics after the run failed\n";
    return 1;
  }
  const auto delta = [&](const std::string& name) -> std::optional<double> {
    const auto before = MetricValue(metrics_before->body, name);
    const auto after = MetricValue(metrics_after->body, name);
    if (!before || !after) return std::nullopt;
    return *after - *before;
  };

  const std::optional<double> discarded_after = scans_discarded();
  std::optional<double> missed_scans;
  if (discarded_before && discarded_after) missed_scans = *discarded_after - *discarded_before;
  const RssTrend trend = Trend(rss_series);

  Record rest;
  for (const auto& record : records) rest.Merge(record);
  Record tile_fetches;
  for (const auto& viewer : viewer_objects) tile_fetches.Merge(viewer->tile_record());
  const Percentiles rest_latency = Summarise(rest.latencies_ms);
  const Percentiles tile_latency = Summarise(tile_fetches.latencies_ms);
  const double elapsed_s = SecondsBetween(config.start, rest_end);
  const auto requests = static_cast<int64_t>(rest.latencies_ms.size());
  // Requests that were due but still waiting for a connection when the time was up.
  const int64_t unsent = static_cast<int64_t>(config.total) - requests;
  const double achieved_rate = elapsed_s > 0 ? static_cast<double>(requests) / elapsed_s : 0.0;

  const auto optional_json = [](const std::optional<double>& value) {
    return value ? json(*value) : json(nullptr);
  };
  json statuses = json::object();
  for (const auto& [status, count] : rest.statuses) statuses[std::to_string(status)] = count;
  json report = {
      {"url", url},
      {"duration_s", duration_s},
      {"rate_target", rate_hz},
      {"requests", requests},
      {"requests_unsent", unsent},
      {"errors", rest.errors + tile_fetches.errors},
      {"rest_errors", rest.errors},
      {"statuses", statuses},
      {"latency_ms",
       {{"p50", rest_latency.p50},
        {"p90", rest_latency.p90},
        {"p99", rest_latency.p99},
        {"max", rest_latency.max}}},
      {"achieved_rate", achieved_rate},
      {"viewers", viewers},
      {"viewers_connected", viewers_connected},
      {"viewer_connects", viewer_stats.connects.load()},
      {"viewer_rejections", viewer_stats.rejected.load()},
      {"viewer_disconnects", viewer_stats.disconnects.load()},
      {"events_received", viewer_stats.events.load()},
      {"tile_fetches", static_cast<int64_t>(tile_fetches.latencies_ms.size())},
      {"tile_errors", tile_fetches.errors},
      {"tile_latency_ms",
       {{"p50", tile_latency.p50}, {"p99", tile_latency.p99}, {"max", tile_latency.max}}},
      {"scans", optional_json(delta("slamd_scans_total"))},
      {"late_scans", optional_json(delta("slamd_late_scans_total"))},
      {"link_queue_drops", optional_json(delta("slamd_link_queue_drops_total"))},
      {"missed_scans", optional_json(missed_scans)},
      {"rss_mib",
       {{"start", optional_json(rss_start)},
        {"end", optional_json(rss_end ? rss_end : rss_start)},
        {"max", optional_json(rss_max)},
        {"second_half_growth", optional_json(trend.second_half_growth_mib)},
        {"second_half_slope_mib_per_min", optional_json(trend.second_half_slope_mib_per_min)},
        {"every_10_s", trend.every_10_s}}},
  };

  std::ostream& table = as_json ? std::cerr : std::cout;
  const auto number = [](const json& value, int digits) {
    if (value.is_null()) return std::string("n/a");
    char text[64];
    std::snprintf(text, sizeof text, "%.*f", digits, value.get<double>());
    return std::string(text);
  };
  table << "slamd-load against " << url << " for " << duration_s << " s\n"
        << "  REST requests      " << requests << " at " << number(achieved_rate, 1)
        << "/s (target " << rate_hz << "/s), errors " << rest.errors << ", unsent " << unsent
        << "\n"
        << "  latency ms         p50 " << number(rest_latency.p50, 2) << "  p90 "
        << number(rest_latency.p90, 2) << "  p99 " << number(rest_latency.p99, 2) << "  max "
        << number(rest_latency.max, 2) << "\n"
        << "  viewers            " << viewers_connected << "/" << viewers << " connected, "
        << viewer_stats.events.load() << " events, " << viewer_stats.rejected.load()
        << " rejected, " << viewer_stats.disconnects.load() << " disconnects\n"
        << "  tile fetches       " << tile_fetches.latencies_ms.size() << ", errors "
        << tile_fetches.errors << ", p99 " << number(tile_latency.p99, 2) << " ms\n"
        << "  scans              " << number(report["scans"], 0) << ", late "
        << number(report["late_scans"], 0) << ", missed " << number(report["missed_scans"], 0)
        << ", link queue drops " << number(report["link_queue_drops"], 0) << "\n"
        << "  RSS MiB            start " << number(report["rss_mib"]["start"], 1) << "  end "
        << number(report["rss_mib"]["end"], 1) << "  max " << number(report["rss_mib"]["max"], 1)
        << "  second half: " << number(report["rss_mib"]["second_half_growth"], 2) << " MiB, "
        << number(report["rss_mib"]["second_half_slope_mib_per_min"], 3) << " MiB/min\n";
  if (!trend.every_10_s.empty()) {
    table << "  RSS every 10 s    ";
    for (const auto& value : trend.every_10_s) table << " " << number(value, 1);
    table << "\n";
  }
  table << "  statuses          ";
  for (const auto& [status, count] : rest.statuses) {
    table << " " << (status == 0 ? std::string("transport-failure") : std::to_string(status)) << ":"
          << count;
  }
  table << "\n";
  if (as_json) std::cout << report.dump() << std::endl;
  return 0;
}
