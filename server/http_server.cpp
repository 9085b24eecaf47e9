// slamd's HTTP server: the routes and their handlers (docs/http-api.md), over the bounded
// server (bounded_server.hpp), behind the request guard (request_guard.cpp); the event stream is
// in event_stream.cpp, the API's JSON in api_json.hpp.
#include "server/http_server.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <sstream>
#include <utility>

#include "engine/cell_encoding.hpp"
#include "engine/io/map_image.hpp"
#include "engine/io/params_json.hpp"
#include "engine/io/tum.hpp"
#include "engine/match_window.hpp"
#include "engine/thread_safety.hpp"
#include "hw_link/status_json.hpp"
#include "server/api_json.hpp"
#include "server/bounded_server.hpp"
#include "server/http_library.hpp"
#include "server/http_server_impl.hpp"
#include "server/request_guard.hpp"
#include "server/state_store.hpp"

#ifndef SLAMD_VERSION
#define SLAMD_VERSION "0"
#endif

namespace slam::server {

bool HttpServer::Impl::ParseBody(const httplib::Request& req, httplib::Response& res,
                                 const char* media, json& out) {
  const std::string type = MediaType(req.get_header_value("Content-Type"));
  if (type != media) {
    SendProblem(res, 415, "Unsupported Media Type",
                std::string("the body must be ") + media +
                    (type.empty() ? std::string(" (no Content-Type given)") : ", not " + type));
    return false;
  }
  // No body of slamd's nests deeper than a few levels (ParseJsonBounded says why it matters).
  Result<json> parsed = ParseJsonBounded(req.body);
  if (!parsed.ok()) {
    out = json();
    SendProblem(res, 400, "Bad Request", "the body is " + parsed.Message());
    return false;
  }
  out = std::move(parsed).value();
  return true;
}

void HttpServer::Impl::HandleBudgetChange(const httplib::Request& req, httplib::Response& res,
                                          bool patch) {
  json body;
  if (!ParseBody(req, res, patch ? "application/merge-patch+json" : "application/json", body)) {
    return;
  }
  const std::string if_match = req.get_header_value("If-Match");
  const bool conditional = HeadHasField(req, "If-Match");
  const SlamService::BudgetChange change = service.ChangeBudget(
      [&](uint64_t revision) {
        return !conditional || EntityTagListMatches(if_match, BudgetEtag(revision), false);
      },
      [&](const BudgetSettings& current) {
        return patch ? MergeBudget(current, body) : BudgetFromJson(body);
      });
  res.set_header("ETag", BudgetEtag(change.revision));
  if (change.precondition_failed) {
    SendProblem(
        res, 412, "Precondition Failed",
        "the budget changed since " + if_match + "; it is now " + BudgetEtag(change.revision));
  } else if (!change.errors.empty()) {
    SendProblem(res, 422, "Invalid budget", "the budget was not changed", change.errors);
  } else {
    SendJson(res, BudgetJson(change.budget));
  }
}

void HttpServer::Impl::HandleParamsPatch(const httplib::Request& req, httplib::Response& res) {
  json body;
  if (!ParseBody(req, res, "application/merge-patch+json", body)) return;
  const std::string if_match = req.get_header_value("If-Match");
  const bool conditional = HeadHasField(req, "If-Match");
  const SlamService::ParamsChange change = service.ChangeParams(
      [&](uint64_t revision) {
        return !conditional || EntityTagListMatches(if_match, ParamsEtag(revision), false);
      },
      [&](const SlamParams& current, const SlamParams& shipped) -> Result<SlamParams> {
        if (!body.is_object()) return ConfigErrors{{"", "must be a JSON object", 0}};
        return io::ApplyParamsPatch(current, body, shipped);
      });
  res.set_header("ETag", ParamsEtag(change.revision));
  if (change.precondition_failed) {
    SendProblem(res, 412, "Precondition Failed",
                "the parameters changed since " + if_match + "; they are now " +
                    ParamsEtag(change.revision));
  } else if (!change.errors.empty()) {
    SendProblem(res, 422, "Invalid parameters",
                body.is_object() ? "the parameters were not changed"
                                 : "a merge patch of the parameters must be an object",
                change.errors);
  } else {
    SendJson(res, io::ParamsToJson(change.params));
  }
}

void HttpServer::Impl::HandleTile(const httplib::Request& req, httplib::Response& res) {
  int x = 0, y = 0;
  try {
    x = std::stoi(req.matches[1].str());
    y = std::stoi(req.matches[2].str());
  } catch (const std::exception&) {
    SendProblem(res, 404, "Not Found", "no such tile");
    return;
  }
  const auto snapshot = service.Snapshot();
  const auto it = std::find_if(snapshot->tiles.begin(), snapshot->tiles.end(),
                               [&](const TileRef& t) { return t.index.x == x && t.index.y == y; });
  if (it == snapshot->tiles.end()) {
    SendProblem(res, 404, "Not Found",
                "no tile (" + std::to_string(x) + ", " + std::to_string(y) + ")");
    return;
  }
  const uint64_t version = snapshot->ReportedVersion(*it->tile);
  const std::string etag = "\"" + std::to_string(version) + "\"";
  res.set_header("ETag", etag);
  res.set_header("Cache-Control", "no-cache");
  if (req.has_header("If-None-Match") &&
      EntityTagListMatches(req.get_header_value("If-None-Match"), etag, true)) {
    res.status = 304;
    return;
  }
  const Result<std::string> png = tile_pngs.Png(x, y, version, *it->tile);
  if (!png.ok()) {
    SendProblem(res, 500, "Internal Server Error", png.Message());
    return;
  }
  res.set_content(png.value(), "image/png");
}

void HttpServer::Impl::HandleSave(httplib::Response& res) {
  if (service.localize_only()) {
    SendProblem(res, 409, "Conflict",
                "slamd localises on its map (--localize) and never changes it: nothing to save");
    return;
  }
  if (!saves.enabled()) {
    SendProblem(res, 409, "Conflict", "slamd was started without --state-dir: nowhere to save");
    return;
  }
  const Result<json> answer = saves.SaveFor(Clock::now());
  if (!answer.ok()) {
    SendProblem(res, 500, "Internal Server Error", "the map was not saved: " + answer.Message());
    return;
  }
  SendJson(res, answer.value());
}

Result<SaveReport> HttpServer::SaveMap() { return impl_->saves.SaveNow(); }

void HttpServer::Impl::HandleReset(httplib::Response& res) {
  if (service.localize_only()) {
    SendProblem(res, 409, "Conflict",
                "slamd localises on its map (--localize) and keeps it: POST /api/v1/relocalize "
                "searches it for the robot again");
    return;
  }
  const auto before = service.Snapshot();
  service.RequestReset();
  // The SLAM thread applies it before its next scan. One request waits for it (bounded) so that
  // its answer carries the new map version; requests meanwhile ask for the same reset (requests
  // before it is applied are one reset) and are answered at once, pending: each waiting held a
  // server thread for up to 2 s, and 24 of them stalled the API.
  if (reset_waiting.exchange(true)) {
    SendJson(res, {{"version", before->map_version}, {"pending", true}}, 202);
    return;
  }
  struct Release {
    std::atomic<bool>& flag;
    ~Release() { flag = false; }
  } release{reset_waiting};
  auto snapshot = before;
  const auto deadline = Clock::now() + std::chrono::seconds(2);
  while (snapshot->epoch == before->epoch && Clock::now() < deadline && !stopping) {
    snapshot = service.WaitNewer(snapshot->sequence, std::chrono::milliseconds(100));
  }
  if (snapshot->epoch == before->epoch) {
    SendJson(res, {{"version", before->map_version}, {"pending", true}}, 202);
    return;
  }
  SendJson(res, {{"version", snapshot->map_version}, {"pending", false}});
}

json HttpServer::Impl::StatusJson() {
  const auto snapshot = service.Snapshot();
  const ServiceCounters c = service.Counters();
  const hw::LinkStatus link_status = link.Status();
  json slam = {{"state", ToString(c.state)},
               {"scans", c.scans},
               {"late_scans", c.late_scans},
               {"refused_scans", c.refused_scans},
               {"resets", c.resets},
               {"relocalization",
                {{"state", RelocalizationJson(*snapshot)},
                 {"relocalizations", c.relocalizations},
                 {"refused", c.relocalizations_refused},
                 {"unsure_searches", c.relocalization_searches_unsure},
                 {"scans", c.relocalizing_scans},
                 {"lookups", c.relocalization_lookups},
                 {"poses_set", c.poses_set},
                 {"losses", c.losses}}},
               {"particles", snapshot->last ? snapshot->last->particles : 0},
               {"map_version", snapshot->map_version},
               {"tiles", snapshot->tiles.size()},
               {"last_latency_ms", snapshot->last ? snapshot->last->latency_s * 1e3 : 0.0},
               {"cpu_share", c.robot_s > 0.0 ? c.cpu_s / c.robot_s : 0.0},
               {"realtime_ratio", c.busy_s > 0.0 ? c.robot_s / c.busy_s : 0.0},
               {"robot_time_s", c.robot_s},
               {"assembler", hw::AssemblerCountersToJson(c.assembler)}};
  const auto job = jobs.Latest();
  return {
      {"version", SLAMD_VERSION},
      {"uptime_s", Seconds(Clock::now() - started)},
      {"source", SourceJson(link_status.source)},
      {"link", hw::LinkStatusToJson(link_status)},
      {"slam", slam},
      {"pose", snapshot->has_pose ? PoseJson(snapshot->pose) : json(nullptr)},
      {"budget", BudgetJson(service.Budget())},
      {"params", {{"set", service.Params().name}, {"follows_budget", service.ParamsFollowQuota()}}},
      {"job", job ? *job : json(nullptr)},
      {"features",
       {{"save", !options.state_dir.empty() && !service.localize_only()},
        {"localize", service.localize_only()},
        {"tuning", jobs.configured()},
        {"experiments", jobs.Experiments()},
        {"ray_kernel", BestWindowKernelName()}}}};
}

std::string HttpServer::Impl::MetricsText() {
  const auto snapshot = service.Snapshot();
  const ServiceCounters c = service.Counters();
  const hw::LinkStatus l = link.Status();
  std::ostringstream o;
  o.precision(9);
  const auto metric = [&](const char* name, const char* type, const char* help, auto value) {
    o << "# HELP slamd_" << name << ' ' << help << "\n# TYPE slamd_" << name << ' ' << type
      << "\nslamd_" << name << ' ' << value << '\n';
  };
  metric("scans_total", "counter", "Scans processed by the SLAM.", c.scans);
  metric("late_scans_total", "counter",
         "Scans whose result came later than one scan period after the scan was complete.",
         c.late_scans);
  metric(
      "refused_scans_total", "counter",
      "Scans the SLAM refused: odometry not finite, implausibly fast, or beyond the map's bound.",
      c.refused_scans);
  metric("relocalizing", "gauge",
         "1 while the SLAM relocalises (searches the map for the robot; nothing is mapped).",
         snapshot->relocalizing ? 1 : 0);
  metric("relocalizations_total", "counter", "Relocalisations taken.", c.relocalizations);
  metric("relocalizations_refused_total", "counter",
         "Relocalisation answers the engine refused (beyond the map's bound).",
         c.relocalizations_refused);
  metric("relocalization_unsure_searches_total", "counter",
         "Relocalisation searches that ended without a unique answer (searched again).",
         c.relocalization_searches_unsure);
  metric("relocalizing_scans_total", "counter", "Scans that went to the relocaliser.",
         c.relocalizing_scans);
  metric("relocalization_lookups_total", "counter",
         "Point lookups of the relocaliser's global search (32 are paid as one quota ray).",
         c.relocalization_lookups);
  metric("poses_set_total", "counter", "Poses given for the robot and taken as they were.",
         c.poses_set);
  metric("losses_total", "counter",
         "Times the loss detector found the tracker lost (readings landing where the map is free).",
         c.losses);
  metric("rays_planned_total", "counter", "Rays planned by the scheduler.", c.rays_planned);
  metric("rays_used_total", "counter", "Rays cast by the engine.", c.rays_used);
  const ScanMetrics last = snapshot->last.value_or(ScanMetrics{});
  metric("rays_per_scan_planned", "gauge", "Rays planned for the latest scan.", last.rays_planned);
  metric("rays_per_scan_used", "gauge", "Rays cast on the latest scan.", last.rays_used);
  metric("ray_quota", "gauge", "The scheduler's quota for the latest scan, rays.", last.quota);
  metric("lookups_per_scan", "gauge",
         "Point lookups of the latest scan besides its rays (the relocaliser's search or the loss "
         "detector's check; 32 are paid as one quota ray).",
         last.lookups);
  o << "# HELP slamd_scan_latency_seconds From a scan's last event to its published result.\n"
       "# TYPE slamd_scan_latency_seconds histogram\n";
  uint64_t cumulative = 0;
  const auto& bounds = LatencyBuckets();
  for (size_t i = 0; i < bounds.size(); ++i) {
    cumulative += c.latency_counts[i];
    o << "slamd_scan_latency_seconds_bucket{le=\"" << bounds[i] << "\"} " << cumulative << '\n';
  }
  cumulative += c.latency_counts.back();
  o << "slamd_scan_latency_seconds_bucket{le=\"+Inf\"} " << cumulative << '\n'
    << "slamd_scan_latency_seconds_sum " << c.latency_sum_s << '\n'
    << "slamd_scan_latency_seconds_count " << cumulative << '\n';
  metric("cpu_share", "gauge", "SLAM thread CPU time over robot time, latest scan.",
         last.cpu_share);
  metric("realtime_ratio", "gauge",
         "Robot time over SLAM processing time, latest scan (above 1: faster than real time).",
         last.realtime_ratio);
  metric("particles", "gauge", "Particles in the filter.", last.particles);
  metric("map_tiles", "gauge", "Tiles of the best particle's map.", snapshot->tiles.size());
  metric("map_version", "gauge", "Largest tile version.", snapshot->map_version);
  metric("link_up", "gauge", "1 when the link is reading its source.",
         l.state == hw::LinkState::kRunning ? 1 : 0);
  metric(
      "link_silent", "gauge",
      "1 when the link is running but has read no frame for a second (robot or transport quiet).",
      l.Silent() ? 1 : 0);
  metric("link_seconds_without_frames", "gauge", "Seconds since the latest CAN frame.",
         l.SecondsWithoutFrames());
  metric("link_frames_total", "counter", "CAN frames read from the source.", l.frames);
  metric("link_frames_rejected_total", "counter", "Frames dropped by reassembly or decoding.",
         l.reassembly.Rejected() + l.decoder.Rejected());
  metric("link_events_total", "counter", "Robot events queued for the SLAM.", l.events_queued);
  metric("link_queue_drops_total", "counter", "Robot events dropped because the queue was full.",
         l.queue_drops);
  metric("link_source_errors_total", "counter", "Errors of the frame source.", l.source_errors);
  o << "# HELP slamd_http_requests_total HTTP requests answered.\n"
       "# TYPE slamd_http_requests_total counter\n";
  for (const auto& [key, count] : requests.Counts()) {
    o << "slamd_http_requests_total{method=\"" << key.first << "\",code=\"" << key.second << "\"} "
      << count << '\n';
  }
  metric("http_connections_timed_out_total", "counter",
         "Connections closed at the gate: no whole request in time.",
         server.connections_timed_out());
  metric("http_connections_evicted_total", "counter",
         "Waiting connections closed to admit newer ones (too many from one address, or in all).",
         server.connections_evicted());
  metric("event_stream_clients", "gauge", "Open event streams.", streams.load());
  metric("event_streams_rejected_total", "counter", "Event streams refused (cap reached).",
         streams_rejected.load());
  metric("jobs_running", "gauge", "Tuning jobs running.", jobs.running());
  metric("map_saves_total", "counter",
         "Saves of the map written (requests waiting for a save share it).", saves.saves_made());
  o << "# HELP slamd_exports_made_total Whole-map and trajectory exports made (each at most once "
       "per snapshot and kind).\n# TYPE slamd_exports_made_total counter\n";
  for (const auto& [kind, made] : exports.Made()) {
    o << "slamd_exports_made_total{kind=\"" << kind << "\"} " << made << '\n';
  }
  MutexLock lock(extra_metrics_mutex);
  for (const auto& extra : extra_metrics) o << extra();
  return o.str();
}

void HttpServer::Impl::Route(const std::string& method, const std::string& pattern,
                             httplib::Server::Handler handler) {
  if (method == "GET") {
    server.Get(pattern, std::move(handler));
  } else if (method == "POST") {
    server.Post(pattern, std::move(handler));
  } else if (method == "PUT") {
    server.Put(pattern, std::move(handler));
  } else if (method == "PATCH") {
    server.Patch(pattern, std::move(handler));
  } else {
    server.Delete(pattern, std::move(handler));
  }
  const auto known = std::find_if(routes.begin(), routes.end(),
                                  [&](const KnownRoute& r) { return r.pattern == pattern; });
  if (known == routes.end()) {
    routes.push_back({pattern, std::regex(pattern), method});
  } else {
    known->allow += ", " + method;
  }
}

void HttpServer::Impl::Setup() {
  using httplib::Request;
  using httplib::Response;
  // httplib's own pool only hands accepted connections to the gate (BoundedServer); the
  // workers that serve requests are the server's: every event stream holds one for its
  // lifetime (notes point 2), the others serve whole requests in arrival order.
  server.new_task_queue = [] { return new httplib::ThreadPool(2); };
  // Small responses must not wait for the client's delayed ACK (Nagle: +40 ms per request on
  // a keep-alive connection).
  server.set_tcp_nodelay(true);
  server.set_keep_alive_max_count(1000);
  // Short: an idle keep-alive connection holds a pool thread (stop() no longer waits for it).
  server.set_keep_alive_timeout(2);
  server.set_read_timeout(5);
  server.set_write_timeout(5);
  server.request_deadline = std::chrono::seconds(10);  // a whole request, head and body
  server.set_payload_max_length(options.max_body_bytes);
  server.max_body_bytes = options.max_body_bytes;
  // SO_REUSEADDR only: with SO_REUSEPORT (the default) two slamd could share a port silently.
  server.set_socket_options([](socket_t sock) {
    int yes = 1;
    setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof(yes));
  });
  server.set_pre_routing_handler([this](const Request& req, Response& res) {
    // The library hands a const request, but owns it mutably; Guard rewrites Accept-Encoding.
    return Guard(const_cast<Request&>(req), res);
  });
  server.set_logger([](const Request&, const Response& res) {
    // A request the library could not parse (a malformed request line or header) is answered
    // 400 without reaching the guard; what follows it on the connection is not a request to
    // trust: it closes (1000 CRLFs once got 1000 answers on one connection).
    if (res.status == 400) CloseConnectionAfterResponse();
  });
  // Counted in the post-routing handler, which the library calls for every answer (its own 400
  // and 404 included) just before writing it, not in the logger, which it calls after: a client
  // reading /metrics right after an answer came could miss it.
  server.set_post_routing_handler(
      [this](const Request& req, Response& res) { requests.Count(req.method, res.status); });
  server.set_exception_handler([](const Request&, Response& res, std::exception_ptr ep) {
    std::string what = "unexpected error";
    try {
      std::rethrow_exception(ep);
    } catch (const std::exception& e) {
      what = e.what();
    } catch (...) {
    }
    SendProblem(res, 500, "Internal Server Error", what);
  });
  // Registered in this order: a request takes the first route whose pattern matches.
  AddStateRoutes();
  AddMapRoutes();
  AddJobRoutes();
  AddPageAndFallback();
}

// Health, status, the budget and the parameters.
void HttpServer::Impl::AddStateRoutes() {
  using httplib::Request;
  using httplib::Response;
  Route("GET", "/api/v1/health", [](const Request&, Response& res) {
    SendJson(res, {{"status", "ok"}});
  });
  Route("GET", "/api/v1/status",
        [this](const Request&, Response& res) { SendJson(res, StatusJson()); });

  Route("GET", "/api/v1/budget", [this](const Request&, Response& res) {
    const SlamService::RevisedBudget budget = service.BudgetRevised();
    res.set_header("ETag", BudgetEtag(budget.revision));
    SendJson(res, BudgetJson(budget.budget));
  });
  Route("PATCH", "/api/v1/budget",
        [this](const Request& req, Response& res) { HandleBudgetChange(req, res, true); });
  Route("PUT", "/api/v1/budget",
        [this](const Request& req, Response& res) { HandleBudgetChange(req, res, false); });

  Route("GET", "/api/v1/params", [this](const Request&, Response& res) {
    const SlamService::RevisedParams params = service.ParamsRevised();
    res.set_header("ETag", ParamsEtag(params.revision));
    SendJson(res, io::ParamsToJson(params.set.params));
  });
  Route("PATCH", "/api/v1/params",
        [this](const Request& req, Response& res) { HandleParamsPatch(req, res); });
  // Back to the shipped set of each scan's budget (after a PATCH or --params).
  Route("DELETE", "/api/v1/params", [this](const Request&, Response& res) {
    const SlamService::RevisedParams params = service.ResetParams();
    res.set_header("ETag", ParamsEtag(params.revision));
    SendJson(res, io::ParamsToJson(params.set.params));
  });
}

// The map, its tiles and exports, the trajectory, the event stream, saves and resets.
void HttpServer::Impl::AddMapRoutes() {
  using httplib::Request;
  using httplib::Response;
  Route("GET", "/api/v1/map", [this](const Request&, Response& res) {
    const auto s = service.Snapshot();
    json tiles = json::array();
    for (const TileRef& t : s->tiles) {
      tiles.push_back(
          {{"x", t.index.x}, {"y", t.index.y}, {"version", s->ReportedVersion(*t.tile)}});
    }
    SendJson(res, {{"resolution_m", s->resolution_m},
                   {"tile_size", kTileSize},
                   {"origin", {0.0, 0.0}},
                   {"version", s->map_version},
                   {"epoch", s->epoch},
                   {"tiles", std::move(tiles)}});
  });
  Route("GET", R"(/api/v1/map/tiles/(-?\d{1,9})/(-?\d{1,9})\.png)",
        [this](const Request& req, Response& res) { HandleTile(req, res); });
  const auto whole_map = [this](const std::string& kind) {
    return [this, kind](const Request&, Response& res) {
      exports.Serve(
          "map." + kind,
          [&](const SlamSnapshot& s, std::string& body, std::string& type, std::string& error) {
            const OccupancyGrid grid = SnapshotGrid(s, service.encoded_logodds_limit());
            const io::GridImage image = io::MakeGridImage(grid);
            if (kind == "pgm") {
              body = io::EncodePgm(image);
              type = "image/x-portable-graymap";
            } else if (kind == "yaml") {
              body = io::MapYaml("map.pgm", image);
              type = "application/yaml";
            } else {
              const Result<io::PngBytes> png =
                  io::EncodeGrayPng(image.width, image.height, image.gray);
              if (!png.ok()) {
                error = png.Message();
                return false;
              }
              body.assign(png.value().begin(), png.value().end());
              type = "image/png";
            }
            return true;
          },
          res);
      if (res.status < 300) {
        res.set_header("Content-Disposition", "attachment; filename=\"map." + kind + "\"");
      }
    };
  };
  Route("GET", "/api/v1/map.pgm", whole_map("pgm"));
  Route("GET", "/api/v1/map.yaml", whole_map("yaml"));
  Route("GET", "/api/v1/map.png", whole_map("png"));

  Route("GET", "/api/v1/trajectory", [this](const Request& req, Response& res) {
    const std::string format = req.has_param("format") ? req.get_param_value("format") : "json";
    if (format != "json" && format != "tum") {
      SendProblem(res, 400, "Bad Request", "format must be json or tum, not \"" + format + "\"");
      return;
    }
    exports.Serve(
        "trajectory." + format,
        [&](const SlamSnapshot& s, std::string& body, std::string& type, std::string&) {
          const std::vector<TimedPose> trajectory = ScanEndTrajectory(s);
          if (format == "tum") {
            body = io::FormatTum(trajectory);
            type = "text/plain; charset=utf-8";
            return true;
          }
          const auto rows = [](const std::vector<TimedPose>& poses) {
            json list = json::array();
            for (const TimedPose& p : poses) {
              list.push_back({p.t, p.pose.x, p.pose.y, p.pose.theta});
            }
            return list;
          };
          json j = {{"slam", rows(trajectory)}};
          if (service.simulated()) j["ground_truth"] = rows(service.GroundTruth());
          body = Dump(j);
          type = kJson;
          return true;
        },
        res);
    if (format == "tum") {
      res.set_header("Content-Disposition", "attachment; filename=\"trajectory.tum\"");
    }
  });

  Route("GET", "/api/v1/events",
        [this](const Request& req, Response& res) { HandleEvents(req, res); });

  Route("POST", "/api/v1/map/save", [this](const Request& req, Response& res) {
    json body;
    if (ParseBody(req, res, "application/json", body)) HandleSave(res);
  });
  Route("POST", "/api/v1/reset", [this](const Request& req, Response& res) {
    json body;
    if (ParseBody(req, res, "application/json", body)) HandleReset(res);
  });
  Route("POST", "/api/v1/pose", [this](const Request& req, Response& res) {
    json body;
    if (!ParseBody(req, res, "application/json", body)) return;
    const Result<PoseRequest> request = PoseRequestFromJson(body, service.config().resolution_m);
    if (!request.ok()) {
      SendProblem(res, 422, "Invalid pose", "the pose was not changed", request.errors());
      return;
    }
    service.RequestPose(request.value());
    const bool hint = request.value().sigma_m || request.value().sigma_deg;
    SendJson(res, {{"pending", true}, {"mode", hint ? "relocalize_around" : "set"}}, 202);
  });
  Route("POST", "/api/v1/sim/kidnap", [this](const Request& req, Response& res) {
    json body;
    if (!ParseBody(req, res, "application/json", body)) return;
    if (!service.simulated()) {
      SendProblem(res, 409, "Conflict", "the source is not the virtual marXbot: nothing to lift");
      return;
    }
    std::optional<Pose2> target;
    if (!(body.is_object() && body.empty())) {
      // A target in the world frame, as the pose route's body (no deviations).
      const Result<PoseRequest> parsed = PoseRequestFromJson(body, service.config().resolution_m);
      if (!parsed.ok() || parsed.value().sigma_m || parsed.value().sigma_deg) {
        SendProblem(res, 422, "Invalid target", "the robot was not moved",
                    parsed.ok() ? ConfigErrors{{"", "a target has no sigma_m or sigma_deg", 0}}
                                : parsed.errors());
        return;
      }
      target = parsed.value().pose;
    }
    const Result<Pose2> landed = service.KidnapSimulatedRobot(target);
    if (!landed.ok()) {
      SendProblem(res, 422, "Invalid target", landed.Message(), {{"", landed.Message(), 0}});
      return;
    }
    const Pose2& p = landed.value();
    SendJson(res, {{"x", p.x}, {"y", p.y}, {"theta", p.theta}, {"frame", "world"}}, 202);
  });
  Route("POST", "/api/v1/relocalize", [this](const Request& req, Response& res) {
    json body;
    if (!ParseBody(req, res, "application/json", body)) return;
    if (!service.RequestRelocalize()) {
      SendProblem(res, 409, "Conflict", "nothing is mapped yet: there is nothing to relocalise in");
      return;
    }
    SendJson(res, {{"pending", true}}, 202);
  });
}

// Tuning jobs and the metrics.
void HttpServer::Impl::AddJobRoutes() {
  using httplib::Request;
  using httplib::Response;
  Route("POST", "/api/v1/jobs/tune", [this](const Request& req, Response& res) {
    json body;
    if (!ParseBody(req, res, "application/json", body)) return;
    if (!jobs.configured()) {
      SendProblem(res, 409, "Conflict",
                  "slamd was started without --experiments: no recorded experiments to tune on");
      return;
    }
    const Result<TuneRequest> parsed = ParseTuneRequest(body, jobs.Experiments());
    if (!parsed.ok()) {
      SendProblem(res, 422, "Invalid tuning job", "no job was started", parsed.errors());
      return;
    }
    const TuneRequest& request = parsed.value();
    const Result<json> job = jobs.Start(request);
    if (!job.ok()) {
      SendProblem(res, 409, "Conflict", job.Message());
      return;
    }
    res.set_header("Location", "/api/v1/jobs/" + job.value()["id"].get<std::string>());
    SendJson(res, job.value(), 202);
  });
  Route("GET", "/api/v1/jobs",
        [this](const Request&, Response& res) { SendJson(res, jobs.List()); });
  Route("GET", R"(/api/v1/jobs/([^/]+))", [this](const Request& req, Response& res) {
    const auto job = jobs.Get(req.matches[1].str());
    if (!job) {
      SendProblem(res, 404, "Not Found", "no job " + req.matches[1].str());
      return;
    }
    SendJson(res, *job);
  });
  Route("DELETE", R"(/api/v1/jobs/([^/]+))", [this](const Request& req, Response& res) {
    const std::string id = req.matches[1].str();
    const int status = jobs.Delete(id);
    if (status == 404) {
      SendProblem(res, 404, "Not Found", "no job " + id);
      return;
    }
    SendJson(res, {{"id", id}, {"state", status == 202 ? "cancelling" : "deleted"}}, status);
  });

  Route("GET", "/metrics", [this](const Request&, Response& res) {
    res.set_content(MetricsText(), "text/plain; version=0.0.4; charset=utf-8");
  });
}

// The page's files, then 405 on a known route and 404 elsewhere, as problem+json.
void HttpServer::Impl::AddPageAndFallback() {
  using httplib::Request;
  using httplib::Response;
  if (!options.web_root.empty()) {
    const std::string vendor = options.web_root + "/node_modules/uplot/dist";
    if (std::filesystem::is_directory(vendor)) server.set_mount_point("/vendor/uplot", vendor);
    server.set_mount_point("/", options.web_root);
  }

  // Known routes answer 405 to other methods; anything else is 404, as problem+json.
  const auto fallback = [this](const Request& req, Response& res) {
    for (const KnownRoute& route : routes) {
      if (std::regex_match(req.path, route.regex)) {
        res.set_header("Allow", route.allow);
        SendProblem(
            res, 405, "Method Not Allowed",
            req.method + " is not allowed on " + req.path + " (allowed: " + route.allow + ")");
        return;
      }
    }
    SendProblem(res, 404, "Not Found", "no route " + req.method + " " + req.path);
  };
  server.Get(".*", fallback);
  server.Post(".*", fallback);
  server.Put(".*", fallback);
  server.Patch(".*", fallback);
  server.Delete(".*", fallback);
  server.Options(".*", fallback);
}

HttpServer::HttpServer(SlamService& service, hw::Link& link, JobManager& jobs,
                       const HttpOptions& options)
    : impl_(std::make_unique<Impl>(service, link, jobs, options)) {
  impl_->Setup();
}

HttpServer::~HttpServer() { Stop(); }

Result<int> HttpServer::Bind() {
  auto& s = impl_->server;
  if (impl_->options.port == 0) {
    const int port = s.bind_to_any_port(impl_->options.bind);
    if (port <= 0) return Error("cannot listen on " + impl_->options.bind + " (any port)");
    s.WidenListenBacklog();
    return port;
  }
  if (!s.bind_to_port(impl_->options.bind, impl_->options.port)) {
    return Error("cannot listen on " + impl_->options.bind + ":" +
                 std::to_string(impl_->options.port) +
                 " (in use, or not an address of this machine)");
  }
  s.WidenListenBacklog();
  return impl_->options.port;
}

void HttpServer::Run() {
  impl_->server.StartServing(static_cast<size_t>(impl_->options.max_streams) + 8);
  impl_->server.listen_after_bind();
  impl_->server.Shutdown();
}

void HttpServer::AddMetrics(std::function<std::string()> metrics) {
  MutexLock lock(impl_->extra_metrics_mutex);
  impl_->extra_metrics.push_back(std::move(metrics));
}

std::string HttpServer::HandleInMemory(std::string_view request, size_t max_response_bytes) {
  return impl_->server.ProcessInMemory(request, max_response_bytes);
}

void HttpServer::Stop() {
  impl_->stopping = true;
  impl_->server.stop();
}

}  // namespace slam::server
