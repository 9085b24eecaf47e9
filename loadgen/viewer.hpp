#pragma once
// Event-stream viewers that behave like the web page: each holds one text/event-stream, reads it
// continuously and fetches every tile PNG a `tiles` event announces over its own keep-alive
// connection (like a browser's second connection).

#include <httplib.h>

#include <atomic>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <utility>

#include "loadgen/measures.hpp"

namespace slam::loadgen {

/// What all viewers saw, counted as it happens.
struct ViewerStats {
  std::atomic<int64_t> events{0};
  std::atomic<int64_t> tiles_announced{0};
  std::atomic<int> connected{0};
  std::atomic<int64_t> connects{0};
  std::atomic<int64_t> rejected{0};     // non-200 answers to the stream request (503 at the cap)
  std::atomic<int64_t> disconnects{0};  // streams that ended while the run went on
};

/// Shared knowledge of which tiles exist (at most 4096), for the REST mix's tile requests.
class TileBook {
 public:
  void Note(int64_t x, int64_t y);
  /// The (k mod size)-th known tile; nullopt while none is known.
  std::optional<std::pair<int64_t, int64_t>> Pick(uint64_t k);

 private:
  std::mutex mutex_;
  std::map<std::pair<int64_t, int64_t>, bool> tiles_;
};

/// One viewer. Run() reconnects with Last-Event-ID when the stream ends, as a browser's
/// EventSource does, until `stop` is set.
class Viewer {
 public:
  Viewer(const Target& target, const std::atomic<bool>& stop, ViewerStats& stats, TileBook& tiles);

  void Run();

  /// The tile fetches' latencies and statuses (read after Run() returned).
  const Record& tile_record() const { return tile_record_; }

 private:
  bool Connect();
  bool Fail();
  bool ReadSome(int timeout_ms);
  void ReadUntilEnd();
  bool Decode();
  void HandleEvents();
  void FetchTiles(const std::string& data);

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

}  // namespace slam::loadgen
