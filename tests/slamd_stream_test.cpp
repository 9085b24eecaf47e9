// slamd over HTTP, as a black box (docs/http-api.md): bearer tokens and the event stream
// (hello, tiles, live events, Last-Event-ID, caps, announced changes). The harness and its
// conventions are slamd_http_test.cpp's (tests/slamd_harness.hpp).

#include <signal.h>

#include <algorithm>
#include <cstdlib>
#include <limits>
#include <sstream>

#include "engine/quality.hpp"
#include "tests/slamd_harness.hpp"

namespace slamd_test {
namespace {

// ---------------------------------------------------------------------------------------------
// Bearer token

class TokenSlamd : public SlamdSuite {
 protected:
  static constexpr const char* kToken = "s3cret-t0ken-0123456789";
  static void SetUpTestSuite() {
    dir_ = std::make_unique<ScratchDir>("token");
    WriteFile(dir_->path() / "token", std::string(kToken) + "\n");
    StartShared({"--token-file", (dir_->path() / "token").string(), "--budget", "8000"});
  }
  static void TearDownTestSuite() {
    StopShared();
    dir_.reset();
  }
  static inline std::unique_ptr<ScratchDir> dir_;
};

TEST_F(TokenSlamd, MissingTokenIs401WithWwwAuthenticate) {
  const Reply before = http().Get(kBudgetPath);
  const Reply reply = http().MergePatch(kBudgetPath, R"({"rays_per_scan": 9000})");
  ExpectProblem(reply, 401);
  EXPECT_NE(reply.Header("WWW-Authenticate").find("Bearer"), std::string::npos) << reply;
  EXPECT_NE(reply.Header("WWW-Authenticate").find("realm=\"slamd\""), std::string::npos)
      << reply.Header("WWW-Authenticate");
  EXPECT_EQ(http().Get(kBudgetPath).body, before.body);
  // Every mutating route.
  ExpectProblem(http().PutJson(kBudgetPath, before.body), 401);
  ExpectProblem(http().MergePatch(kParamsPath, R"({"particles": 2})"), 401);
  ExpectProblem(http().PostJson("/api/v1/map/save", "{}"), 401);
  ExpectProblem(http().PostJson("/api/v1/reset", "{}"), 401);
  ExpectProblem(http().PostJson("/api/v1/jobs/tune", "{}"), 401);
  ExpectProblem(http().Send("DELETE", "/api/v1/jobs/1", "", ""), 401);
}

TEST_F(TokenSlamd, WrongTokenIs401) {
  const Reply before = http().Get(kBudgetPath);
  for (const std::string value :
       {"Bearer wrong-token-0123456789", "Bearer s3cret-t0ken-012345678",
        "Bearer s3cret-t0ken-01234567890", "Basic czNjcmV0LXQwa2VuLTAxMjM0NTY3ODk=",
        "s3cret-t0ken-0123456789", "Bearer", "bearer  s3cret-t0ken-0123456789x"}) {
    SCOPED_TRACE(value);
    const Reply reply =
        http().MergePatch(kBudgetPath, R"({"rays_per_scan": 9000})", {{"Authorization", value}});
    ExpectProblem(reply, 401);
    EXPECT_NE(reply.Header("WWW-Authenticate").find("Bearer"), std::string::npos);
  }
  EXPECT_EQ(http().Get(kBudgetPath).body, before.body);
}

TEST_F(TokenSlamd, RightTokenIsAccepted) {
  const httplib::Headers auth = {{"Authorization", std::string("Bearer ") + kToken}};
  const Reply reply = http().MergePatch(kBudgetPath, R"({"rays_per_scan": 9000})", auth);
  ASSERT_EQ(reply.status, 200) << reply;
  EXPECT_EQ(reply.Json()["rays_per_scan"], 9000);
  const Reply restore = http().MergePatch(kBudgetPath, R"({"rays_per_scan": 8000})", auth);
  ASSERT_EQ(restore.status, 200) << restore;
  EXPECT_EQ(GetJson(http(), kBudgetPath)["rays_per_scan"], 8000);
  // With the token, the other checks still apply.
  Expect422At(http().MergePatch(kBudgetPath, R"({"rays_per_scan": 0})", auth), {"/rays_per_scan"});
  ExpectProblem(http().PostJson("/api/v1/map/save", "{}", auth), 409);
  ExpectProblem(http().Send("DELETE", "/api/v1/jobs/1", "", "", auth), 404);
}

TEST_F(TokenSlamd, ReadingNeedsNoToken) {
  for (const std::string path :
       {"/api/v1/health", "/api/v1/status", "/api/v1/budget", "/api/v1/params", "/api/v1/map",
        "/api/v1/trajectory", "/api/v1/jobs", "/metrics"}) {
    EXPECT_EQ(http().Get(path).status, 200) << path;
  }
  EventStream stream;
  EXPECT_EQ(stream.Open(port()), 200);
  EXPECT_TRUE(stream.WaitFor("hello", 5.0).has_value());
}

// ---------------------------------------------------------------------------------------------
// The event stream (at most two concurrent streams here)

class EventStreamSlamd : public SlamdSuite {
 protected:
  // Gentle odometry: LastEventIdResendsOnlyNewerTiles needs tiles left unchanged since the first
  // tiles event; with the tracked profile every one of them was rewritten by the time the test
  // looked, in every run tried. These tests are about event ids, not odometry.
  static void SetUpTestSuite() {
    StartShared({"--max-streams", "2", "--budget", "8000", "--odometry", "gentle"});
  }
  static void TearDownTestSuite() { StopShared(); }

  /// Waits (bounded) until slamd counts `expected` open streams; the last count.
  double WaitForStreamClients(double expected, double timeout_s) {
    return PollMetric(http(), "slamd_event_stream_clients", timeout_s,
                      [&](double value) { return value == expected; })
        .value_or(-1.0);
  }
};

TEST_F(EventStreamSlamd, ConnectGivesHelloTilesThenLiveEvents) {
  const json map = WaitForTiles(http(), 1);
  EventStream stream;
  ASSERT_EQ(stream.Open(port()), 200);
  EXPECT_TRUE(StartsWith(stream.Header("Content-Type"), "text/event-stream"))
      << stream.Header("Content-Type");

  const auto hello = stream.Next(5.0);
  ASSERT_TRUE(hello.has_value());
  EXPECT_EQ(hello->name, "hello");
  EXPECT_TRUE(hello->has_id);
  const json hello_data = hello->Json();
  EXPECT_TRUE(hello_data["version"].is_string()) << hello->data;
  EXPECT_TRUE(hello_data["source"].is_object()) << hello->data;
  EXPECT_EQ(hello_data.value("simulated", false), true) << hello->data;

  // Next, every tile (no Last-Event-ID).
  const auto tiles = stream.Next(5.0);
  ASSERT_TRUE(tiles.has_value());
  ASSERT_EQ(tiles->name, "tiles");
  ASSERT_TRUE(tiles->has_id);
  const json tiles_data = tiles->Json();
  ASSERT_TRUE(tiles_data["tiles"].is_array()) << tiles->data;
  EXPECT_GE(tiles_data["tiles"].size(), map["tiles"].size());
  EXPECT_TRUE(tiles_data["version"].is_number_integer());
  int64_t largest = 0;
  for (const auto& tile : tiles_data["tiles"]) {
    ASSERT_TRUE(tile["x"].is_number_integer() && tile["y"].is_number_integer() &&
                tile["version"].is_number_integer())
        << tile.dump();
    largest = std::max(largest, tile["version"].get<int64_t>());
  }
  EXPECT_GE(largest, map["version"].get<int64_t>());
  EXPECT_LE(largest, tiles->Id()) << "id is the map version at the time of the event";
  EXPECT_EQ(tiles_data["version"].get<int64_t>(), largest);

  // Live: pose, metrics and newer tiles within a few seconds.
  bool saw_pose = false, saw_metrics = false, saw_newer_tiles = false;
  int metrics_events = 0;
  double last_ate_m = -1.0;
  const auto deadline = After(12.0);
  while (!(saw_pose && metrics_events >= 6 && saw_newer_tiles) && Clock::now() < deadline) {
    const auto event = stream.Next(std::chrono::duration<double>(deadline - Clock::now()).count());
    if (!event) break;
    const json data = event->Json();
    if (event->name == "pose") {
      saw_pose = true;
      for (const char* key : {"scan", "t", "x", "y", "theta"}) {
        EXPECT_TRUE(data[key].is_number()) << key << " in " << event->data;
      }
      ASSERT_TRUE(data.contains("truth")) << event->data;
      EXPECT_TRUE(data["truth"].is_object()) << "simulated: truth expected " << event->data;
      for (const char* key : {"x", "y", "theta"}) {
        EXPECT_TRUE(data["truth"][key].is_number()) << key << " in " << event->data;
      }
    } else if (event->name == "metrics") {
      saw_metrics = true;
      for (const char* key : {"scan", "rays_planned", "rays_used", "quota", "latency_ms",
                              "cpu_share", "realtime_ratio", "particles", "candidates", "ess"}) {
        EXPECT_TRUE(data[key].is_number()) << key << " in " << event->data;
      }
      // Every event of a simulated run carries both errors (once, most were null: the ground
      // truth had not reached the scan's end yet).
      ++metrics_events;
      ASSERT_TRUE(data.contains("pose_error_m")) << event->data;
      EXPECT_TRUE(data["pose_error_m"].is_number()) << "simulated: a pose error " << event->data;
      ASSERT_TRUE(data.contains("ate_m")) << event->data;
      EXPECT_TRUE(data["ate_m"].is_number()) << "simulated: an ATE so far " << event->data;
      if (data["ate_m"].is_number()) last_ate_m = data["ate_m"].get<double>();
    } else if (event->name == "tiles") {
      for (const auto& tile : data["tiles"]) {
        EXPECT_GT(tile["version"].get<int64_t>(), tiles->Id()) << event->data;
        EXPECT_LE(tile["version"].get<int64_t>(), event->Id()) << event->data;
      }
      saw_newer_tiles = saw_newer_tiles || !data["tiles"].empty();
    }
  }
  EXPECT_TRUE(saw_pose);
  EXPECT_TRUE(saw_metrics);
  EXPECT_GE(metrics_events, 6);
  EXPECT_TRUE(saw_newer_tiles);

  // The live ATE is the offline one of the trajectory served a moment later (a scan or two more).
  const json trajectory = GetJson(http(), "/api/v1/trajectory");
  const auto poses = [](const json& rows) {
    std::vector<slam::TimedPose> out;
    for (const auto& r : rows) {
      out.push_back(
          {r[0].get<double>(), {r[1].get<double>(), r[2].get<double>(), r[3].get<double>()}});
    }
    return out;
  };
  const auto offline =
      slam::EvaluateTrajectory(poses(trajectory["slam"]), poses(trajectory["ground_truth"]));
  ASSERT_TRUE(offline.has_value()) << trajectory.dump().substr(0, 300);
  ASSERT_GE(last_ate_m, 0.0);
  EXPECT_NEAR(last_ate_m, offline->ate_rmse_m, 0.005 + 0.25 * offline->ate_rmse_m);
}

TEST_F(EventStreamSlamd, LastEventIdResendsOnlyNewerTiles) {
  WaitForTiles(http(), 2);
  int64_t first_id = 0;
  {
    EventStream stream;
    ASSERT_EQ(stream.Open(port()), 200);
    ASSERT_TRUE(stream.WaitFor("hello", 5.0).has_value());
    const auto tiles = stream.WaitFor("tiles", 5.0);
    ASSERT_TRUE(tiles.has_value());
    first_id = tiles->Id();
    ASSERT_GT(first_id, 0);
  }
  // Resume from the version at which the least recently written tile was last written, once
  // the robot has left some tiles behind (while it stands where it was, each scan rewrites
  // every tile it sees).
  json map;
  int64_t resume_id = 0;
  const auto deadline = After(20.0);
  do {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    map = GetJson(http(), "/api/v1/map");
    int64_t lo = std::numeric_limits<int64_t>::max(), hi = 0;
    for (const auto& tile : map["tiles"]) {
      lo = std::min(lo, tile["version"].get<int64_t>());
      hi = std::max(hi, tile["version"].get<int64_t>());
    }
    if (lo < hi) resume_id = lo;
  } while (resume_id == 0 && Clock::now() < deadline);
  ASSERT_GT(resume_id, 0) << "precondition: tiles of different versions";
  size_t older = 0;  // at least the tile whose version is resume_id
  for (const auto& tile : map["tiles"]) older += tile["version"].get<int64_t>() <= resume_id;

  EventStream resumed;
  ASSERT_EQ(resumed.Open(port(), std::to_string(resume_id)), 200);
  const auto hello = resumed.Next(5.0);
  ASSERT_TRUE(hello.has_value());
  EXPECT_EQ(hello->name, "hello");
  const auto tiles = resumed.Next(5.0);
  ASSERT_TRUE(tiles.has_value());
  ASSERT_EQ(tiles->name, "tiles");
  const json data = tiles->Json();
  ASSERT_TRUE(data["tiles"].is_array());
  EXPECT_FALSE(data["tiles"].empty());
  for (const auto& tile : data["tiles"]) {
    EXPECT_GT(tile["version"].get<int64_t>(), resume_id) << tile.dump();
  }
  EXPECT_LT(data["tiles"].size(), map["tiles"].size() - older + 8)
      << "about the changed tiles only";
}

TEST_F(EventStreamSlamd, DisconnectIsNoticedWithinTwoSeconds) {
  ASSERT_EQ(WaitForStreamClients(0, 5.0), 0.0) << "streams of earlier tests still counted";
  EventStream stream;
  ASSERT_EQ(stream.Open(port()), 200);
  ASSERT_TRUE(stream.WaitFor("hello", 5.0).has_value());
  EXPECT_EQ(WaitForStreamClients(1, 2.0), 1.0);
  stream.Close();
  const auto closed_at = Clock::now();
  EXPECT_EQ(WaitForStreamClients(0, 3.0), 0.0);
  EXPECT_LT(SecondsSince(closed_at), 2.5) << "disconnect noticed too late";
}

TEST_F(EventStreamSlamd, MoreStreamsThanTheCapAre503WithRetryAfter) {
  ASSERT_EQ(WaitForStreamClients(0, 5.0), 0.0) << "streams of earlier tests still counted";
  const double rejected_before =
      Metric(GetMetrics(http()), "slamd_event_streams_rejected_total").value_or(-1.0);
  ASSERT_GE(rejected_before, 0.0);
  EventStream first, second, third;
  ASSERT_EQ(first.Open(port()), 200);
  ASSERT_TRUE(first.WaitFor("hello", 5.0).has_value());
  ASSERT_EQ(second.Open(port()), 200);
  ASSERT_TRUE(second.WaitFor("hello", 5.0).has_value());
  EXPECT_EQ(third.Open(port()), 503);
  EXPECT_EQ(third.Header("Retry-After"), "5");
  EXPECT_TRUE(StartsWith(third.Header("Content-Type"), "application/problem+json"))
      << third.Header("Content-Type");
  third.Close();
  // REST still answers while the streams are at the cap.
  EXPECT_EQ(http().Get("/api/v1/status").status, 200);
  EXPECT_EQ(Metric(GetMetrics(http()), "slamd_event_streams_rejected_total").value_or(-1.0),
            rejected_before + 1.0);
  // Once one stream goes away, a new one is accepted.
  first.Close();
  ASSERT_EQ(WaitForStreamClients(1, 3.0), 1.0);
  EventStream fourth;
  EXPECT_EQ(fourth.Open(port()), 200);
  EXPECT_TRUE(fourth.WaitFor("hello", 5.0).has_value());
}

TEST_F(EventStreamSlamd, BudgetAndParamsChangesAreAnnounced) {
  ASSERT_EQ(WaitForStreamClients(0, 5.0), 0.0);
  EventStream stream;
  ASSERT_EQ(stream.Open(port()), 200);
  ASSERT_TRUE(stream.WaitFor("hello", 5.0).has_value());
  const json budget = GetJson(http(), kBudgetPath);
  const Reply patched = http().MergePatch(kBudgetPath, R"({"rays_per_scan": 7000})");
  ASSERT_EQ(patched.status, 200) << patched;
  const auto budget_event = stream.WaitFor("budget", 3.0);
  ASSERT_TRUE(budget_event.has_value());
  EXPECT_EQ(budget_event->Json(), patched.Json());

  const Reply params = http().MergePatch(kParamsPath, R"({"particles": 2})");
  ASSERT_EQ(params.status, 200) << params;
  const auto params_event = stream.WaitFor("params", 3.0);
  ASSERT_TRUE(params_event.has_value());
  // The parameters and the name of their set: the shipped set of 7000 rays/scan (the smallest
  // budget's) with the patch.
  json expected = params.Json();
  expected["set"] = "shipped-8125, patched";
  EXPECT_EQ(params_event->Json(), expected);

  EXPECT_EQ(http().PutJson(kBudgetPath, budget.dump()).status, 200);
  EXPECT_EQ(http().MergePatch(kParamsPath, R"({"particles": null})").status, 200);
}

}  // namespace
}  // namespace slamd_test
