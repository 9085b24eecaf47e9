// The event stream (GET /api/v1/events, docs/http-api.md): Server-Sent Events of the map's
// tiles, the pose, metrics, budget, parameters, jobs and status, from the latest snapshot; a
// client that reconnects with Last-Event-ID resumes where it was. A stream never waits on the
// SLAM thread, and wakes up often enough to notice a client that went away.

#include <algorithm>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "engine/io/params_json.hpp"
#include "engine/thread_safety.hpp"
#include "server/api_json.hpp"
#include "server/http_server_impl.hpp"

namespace slam::server {

// One client's stream, owned by its content provider.
struct HttpServer::Impl::EventStream {
  bool hello_sent = false;
  uint64_t last_event_id = 0;
  // Every event's id: the map version up to which this client has been told every tile, so that
  // a reconnect with Last-Event-ID resumes exactly there.
  uint64_t covered = 0;
  uint64_t sequence = 0;
  uint64_t epoch = 0;
  std::map<TileKey, uint64_t> sent;  // tile versions the client has been told
  Clock::time_point last_tiles{};
  Clock::time_point last_pose{};
  Clock::time_point last_write = Clock::now();
  int64_t last_pose_scan = -1;
  uint64_t budget_revision = 0, params_revision = 0, job_revision = 0;
  std::string link_state, slam_state;
  std::string relocalization;  // the last relocalization event's data, as sent
};

void HttpServer::Impl::HandleEvents(const httplib::Request& req, httplib::Response& res) {
  if (streams.fetch_add(1) >= options.max_streams) {
    streams.fetch_sub(1);
    streams_rejected.fetch_add(1);
    res.set_header("Retry-After", "5");
    SendProblem(res, 503, "Service Unavailable",
                "too many event streams (" + std::to_string(options.max_streams) + ")");
    return;
  }
  auto stream = std::make_shared<EventStream>();
  if (req.has_header("Last-Event-ID")) {
    try {
      stream->last_event_id = std::stoull(req.get_header_value("Last-Event-ID"));
      stream->covered = stream->last_event_id;
    } catch (const std::exception&) {
      stream->last_event_id = 0;  // a garbled id: start afresh
    }
  }
  res.set_header("Cache-Control", "no-cache");
  res.set_header("X-Accel-Buffering", "no");
  res.set_chunked_content_provider(
      "text/event-stream",
      [this, stream](size_t, httplib::DataSink& sink) {
        if (stopping || !sink.is_writable()) return false;
        EventStream& s = *stream;
        auto snapshot =
            s.hello_sent ? service.WaitNewer(s.sequence, kStreamWake) : service.Snapshot();
        if (stopping) return false;
        const auto now = Clock::now();
        std::string out = HelloEvents(s, *snapshot, now);
        out += MapEvents(s, *snapshot, now);
        out += SettingsEvents(s);
        out += StatusEvents(s);
        if (out.empty() && Seconds(now - s.last_write) >= kPingEverySeconds) out = ": ping\n\n";
        if (!out.empty()) {
          s.last_write = now;
          if (!sink.write(out.data(), out.size())) return false;
        }
        return true;
      },
      [this](bool) { streams.fetch_sub(1); });
}

std::string HttpServer::Impl::HelloEvents(EventStream& s, const SlamSnapshot& snapshot,
                                          Clock::time_point now) {
  if (s.hello_sent) return {};
  s.hello_sent = true;
  if (s.last_event_id > snapshot.map_version) {
    // An id from another run of slamd (its versions went further): start afresh.
    s.last_event_id = 0;
    s.covered = 0;
  }
  s.epoch = snapshot.epoch;
  std::string out = SseEvent("hello", s.covered,
                             {{"version", SLAMD_VERSION},
                              {"epoch", snapshot.epoch},
                              {"instance", instance},
                              {"source", SourceJson(link.Status().source)},
                              {"simulated", service.simulated()},
                              {"map_version", snapshot.map_version}});
  // What the client already has (Last-Event-ID) is not resent.
  for (const TileRef& t : snapshot.tiles) {
    const uint64_t v = snapshot.ReportedVersion(*t.tile);
    if (v <= s.last_event_id) s.sent[{t.index.x, t.index.y}] = v;
  }
  s.last_tiles = now - std::chrono::hours(1);
  return out;
}

std::string HttpServer::Impl::MapEvents(EventStream& s, const SlamSnapshot& snapshot,
                                        Clock::time_point now) {
  std::string out;
  if (snapshot.epoch != s.epoch) {
    s.epoch = snapshot.epoch;
    s.sent.clear();
    out += SseEvent("reset", s.covered, {{"version", snapshot.map_version}});
  }
  // Tiles: every tile newer than what this client was told, coalesced, at most every half
  // second (a slow client simply gets fewer, larger announcements: latest wins).
  if (Seconds(now - s.last_tiles) >= kTilesEverySeconds) {
    json changed = json::array();
    for (const TileRef& t : snapshot.tiles) {
      const uint64_t v = snapshot.ReportedVersion(*t.tile);
      uint64_t& known = s.sent[{t.index.x, t.index.y}];
      if (v > known) {
        changed.push_back({{"x", t.index.x}, {"y", t.index.y}, {"version", v}});
        known = v;
      }
    }
    s.covered = std::max(s.covered, snapshot.map_version);
    if (!changed.empty()) {
      out += SseEvent("tiles", s.covered,
                      {{"version", snapshot.map_version}, {"tiles", std::move(changed)}});
      s.last_tiles = now;
    }
  }
  if (snapshot.last && snapshot.last->scan != s.last_pose_scan &&
      Seconds(now - s.last_pose) >= kPoseEverySeconds) {
    s.last_pose_scan = snapshot.last->scan;
    s.last_pose = now;
    out += SseEvent("pose", s.covered, PoseEventJson(snapshot));
    out += SseEvent("metrics", s.covered, MetricsEventJson(snapshot));
  }
  // The relocalisation's state when it changes (started, ended, a new one taken); the first
  // one with the hello's state.
  std::string relocalization = Dump(RelocalizationJson(snapshot));
  if (relocalization != s.relocalization) {
    out += "event: relocalization\nid: " + std::to_string(s.covered) + "\ndata: " + relocalization +
           "\n\n";
    s.relocalization = std::move(relocalization);
  }
  s.sequence = snapshot.sequence;
  return out;
}

std::string HttpServer::Impl::SettingsEvents(EventStream& s) {
  std::string out;
  const SlamService::RevisedBudget budget = service.BudgetRevised();
  if (s.budget_revision != budget.revision) {
    if (s.budget_revision != 0) out += SseEvent("budget", s.covered, BudgetJson(budget.budget));
    s.budget_revision = budget.revision;
  }
  const SlamService::RevisedParams params = service.ParamsRevised();
  if (s.params_revision != params.revision) {
    if (s.params_revision != 0) {
      json event = io::ParamsToJson(params.set.params);
      event["set"] = params.set.name;
      out += SseEvent("params", s.covered, event);
    }
    s.params_revision = params.revision;
  }
  const uint64_t job_revision = jobs.revision();
  if (job_revision != s.job_revision) {
    s.job_revision = job_revision;
    if (auto job = jobs.Latest()) out += SseEvent("job", s.covered, *job);
  }
  return out;
}

std::string HttpServer::Impl::StatusEvents(EventStream& s) {
  const std::string link_state = hw::ToString(link.Status().state);
  const std::string slam_state = ToString(service.Counters().state);
  if (link_state == s.link_state && slam_state == s.slam_state) return {};
  s.link_state = link_state;
  s.slam_state = slam_state;
  return SseEvent("status", s.covered, {{"link", link_state}, {"slam", slam_state}});
}

}  // namespace slam::server
