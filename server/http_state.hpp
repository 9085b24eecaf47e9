#pragma once
// The HTTP server's state in small parts, each with its own lock: the PNG cache of the map's
// tiles, the cache of whole-map and trajectory exports, the coordinator of map saves and the
// count of requests answered (HttpServer::Impl holds one of each).

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <initializer_list>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <utility>

#include "engine/occupancy_grid.hpp"
#include "engine/result.hpp"
#include "engine/thread_safety.hpp"
#include "server/http_library.hpp"
#include "server/slam_service.hpp"
#include "server/state_store.hpp"

namespace slam::server {

/// Each tile's PNG at its version: encoded once per version, however many ask.
class TileCache {
 public:
  /// The PNG of `tile`, tile (x, y) at `version`.
  Result<std::string> Png(int32_t x, int32_t y, uint64_t version, const Tile& tile);

 private:
  struct Key {
    int32_t x, y;
    friend bool operator<(const Key& a, const Key& b) { return a.x != b.x ? a.x < b.x : a.y < b.y; }
  };
  Mutex mutex_;
  std::map<Key, std::pair<uint64_t, std::string>> cache_ SLAM_GUARDED_BY(mutex_);  // version, PNG
};

/// Whole-map exports and the trajectory cost time in proportion to the map and the run: each
/// kind is made at most once per published snapshot, one at a time; requests that come while
/// one is being made wait for it and share its bytes. Their CPU cost is thus bounded by the scan
/// rate, whatever the request rate.
class ExportCache {
 public:
  /// Makes an export of a snapshot: its body and media type, or false and why.
  using Make = std::function<bool(const SlamSnapshot&, std::string& body, std::string& type,
                                  std::string& error)>;

  /// The kinds served (fixed: the map of entries is not resized later).
  ExportCache(SlamService& service, std::initializer_list<const char*> kinds);

  /// Answers `res` with the export of `kind` for the service's latest snapshot (500 when it
  /// cannot be made). Precondition: `kind` is one of the constructor's.
  void Serve(const std::string& kind, const Make& make, httplib::Response& res);

  /// Exports made so far, by kind.
  std::map<std::string, uint64_t> Made() const;

 private:
  struct Entry {
    Mutex mutex;
    bool valid SLAM_GUARDED_BY(mutex) = false;
    uint64_t sequence SLAM_GUARDED_BY(mutex) = 0;  // of the snapshot it was made from
    std::string body SLAM_GUARDED_BY(mutex);
    std::string type SLAM_GUARDED_BY(mutex);
    std::atomic<uint64_t> renders{0};
  };
  SlamService& service_;
  std::map<std::string, Entry> entries_;
};

/// Saves of the map into --state-dir, one at a time, each of a snapshot at least as new as the
/// one before (the snapshot is taken under the lock: a slower save of an older snapshot could
/// otherwise land after a newer one and take the saved state back).
class SaveCoordinator {
 public:
  using Clock = std::chrono::steady_clock;

  /// `state_dir` empty: saving is off.
  SaveCoordinator(SlamService& service, std::string state_dir)
      : service_(service), state_dir_(std::move(state_dir)) {}

  bool enabled() const { return !state_dir_.empty(); }

  /// A request's save: a save started after the request `arrived` saved a snapshot at least as
  /// new as the one it would save, and its answer is this request's. Requests piling up on the
  /// lock thus make one more save between them, not one each. The answer: where, which version,
  /// how many tiles, and the copies not written.
  Result<nlohmann::json> SaveFor(Clock::time_point arrived);
  /// A save now (slamd's clean stop).
  Result<SaveReport> SaveNow();
  /// Saves written so far.
  uint64_t saves_made() const { return saves_made_.load(); }

 private:
  Result<SaveReport> SaveLocked() SLAM_REQUIRES(mutex_);

  SlamService& service_;
  const std::string state_dir_;
  Mutex mutex_;
  // The last save that succeeded: when it was started and its answer.
  struct LastSave {
    bool valid = false;
    Clock::time_point started;
    nlohmann::json answer;
  } last_ SLAM_GUARDED_BY(mutex_);
  std::atomic<uint64_t> saves_made_{0};
};

/// The requests answered, by method and status code.
class RequestCounter {
 public:
  /// Counts an answer. A method that is not one of HTTP's counts as "other": whatever a client
  /// sends as a method (httplib answers 400) would grow the counts without bound and go into
  /// /metrics unescaped.
  void Count(const std::string& method, int status);
  /// (method, code) -> count.
  std::map<std::pair<std::string, int>, uint64_t> Counts() const;

 private:
  mutable Mutex mutex_;
  std::map<std::pair<std::string, int>, uint64_t> counts_ SLAM_GUARDED_BY(mutex_);
};

}  // namespace slam::server
