// slamd over HTTP, as a black box (docs/http-api.md): every route and every error path, request
// framing, metrics and the process's flags. Tokens and the event stream are in
// slamd_stream_test.cpp, reset, saving, resuming and localisation in slamd_state_test.cpp,
// tuning jobs in slamd_jobs_test.cpp.
//
// Each fixture starts its own slamd child process (`--port 0 --speed 4 --quiet` plus its flags),
// reads the URL from its first stdout line, waits for /api/v1/health and kills it at the end.
// Tests that do not disturb each other share one slamd per suite; tokens, state directories,
// stream caps, resets and jobs get their own. Waiting is always bounded polling, never a fixed
// sleep. The slamd binary is `$SLAMD_BIN` if set (to run this suite against another build),
// else the one built with the tests; slam-sim (which writes the tuning experiments) is
// `$SLAM_SIM_BIN`, else `tools/slam-sim` of slamd's build tree.

#include <signal.h>

#include <algorithm>
#include <cstdlib>
#include <limits>
#include <sstream>

#include "engine/quality.hpp"
#include "tests/slamd_harness.hpp"

namespace slamd_test {
namespace {

/// The default virtual marXbot, no token, no state dir, no experiments: routes that only read,
/// and changes that every test undoes.
class SharedSlamd : public SlamdSuite {
 protected:
  static void SetUpTestSuite() {
    web_root_ = std::make_unique<ScratchDir>("web");
    WriteFile(web_root_->path() / "index.html", "<html><body>slamd test page</body></html>\n");
    StartShared({"--web-root", web_root_->path().string()});
  }
  static void TearDownTestSuite() {
    StopShared();
    web_root_.reset();
  }
  static inline std::unique_ptr<ScratchDir> web_root_;
};

// --- health, status, static page --------------------------------------------------------------

TEST_F(SharedSlamd, ServingLineNamesTheUrlAndTheSource) {
  EXPECT_TRUE(StartsWith(slamd_->url(), "http://127.0.0.1:")) << slamd_->serving_line();
  EXPECT_NE(slamd_->serving_line().find("(source sim:rooms)"), std::string::npos)
      << slamd_->serving_line();
}

TEST_F(SharedSlamd, HealthIsOk) {
  const json health = GetJson(http(), "/api/v1/health");
  EXPECT_EQ(health, json({{"status", "ok"}}));
}

TEST_F(SharedSlamd, StatusHasTheDocumentedShape) {
  WaitForTiles(http(), 1);
  const json status = GetJson(http(), "/api/v1/status");
  ASSERT_TRUE(status.is_object()) << status.dump();
  EXPECT_TRUE(status["version"].is_string());
  EXPECT_TRUE(status["uptime_s"].is_number());
  EXPECT_GE(status.value("uptime_s", -1.0), 0.0);

  const json& source = status["source"];
  EXPECT_EQ(source.value("spec", ""), "sim:rooms");
  EXPECT_TRUE(source["description"].is_string());
  EXPECT_EQ(source.value("simulated", false), true);

  const json& link = status["link"];
  const std::set<std::string> link_states = {"idle", "running", "source_error", "ended", "stopped"};
  EXPECT_TRUE(link_states.count(link.value("state", "?"))) << link.dump();
  EXPECT_EQ(link.value("state", ""), "running");
  EXPECT_TRUE(link["last_error"].is_string());
  for (const char* key :
       {"frames", "source_errors", "events_queued", "queue_drops", "queue_size"}) {
    EXPECT_TRUE(link[key].is_number_integer()) << key << " in " << link.dump();
  }
  EXPECT_GT(link.value("frames", 0), 0);
  // The virtual marXbot talks all the time: never silent, frames a moment ago.
  EXPECT_EQ(link.value("silent", true), false) << link.dump();
  EXPECT_TRUE(link["seconds_without_frames"].is_number()) << link.dump();
  EXPECT_LT(link.value("seconds_without_frames", 99.0), 0.5) << link.dump();
  for (const char* key : {"reassembly", "decoder", "source_counters"}) {
    EXPECT_TRUE(link[key].is_object()) << key << " in " << link.dump();
  }

  const json& slam = status["slam"];
  EXPECT_EQ(slam.value("state", ""), "running") << slam.dump();
  for (const char* key : {"scans", "late_scans", "particles", "map_version", "tiles"}) {
    EXPECT_TRUE(slam[key].is_number_integer()) << key << " in " << slam.dump();
  }
  for (const char* key : {"last_latency_ms", "cpu_share", "realtime_ratio", "robot_time_s"}) {
    EXPECT_TRUE(slam[key].is_number()) << key << " in " << slam.dump();
  }
  EXPECT_GT(slam.value("scans", 0), 0);
  EXPECT_GT(slam.value("tiles", 0), 0);

  const json& pose = status["pose"];
  for (const char* key : {"t", "x", "y", "theta"}) {
    EXPECT_TRUE(pose[key].is_number()) << key << " in " << pose.dump();
  }
  EXPECT_EQ(status["budget"], GetJson(http(), kBudgetPath));
  EXPECT_TRUE(status.contains("job"));
  EXPECT_TRUE(status["job"].is_null());
  // How matching rays are cast on this processor (replay_test checks which one).
  const std::set<std::string> kernels = {"avx512", "avx2", "portable"};
  EXPECT_TRUE(kernels.count(status["features"].value("ray_kernel", "?")))
      << status["features"].dump();
}

TEST_F(SharedSlamd, ServesThePageFromTheWebRoot) {
  const Reply page = http().Get("/");
  EXPECT_EQ(page.status, 200) << page;
  EXPECT_NE(page.body.find("slamd test page"), std::string::npos) << page;
  EXPECT_TRUE(StartsWith(page.ContentType(), "text/html")) << page;
}

// --- unknown routes, methods ----------------------------------------------------------------

TEST_F(SharedSlamd, UnknownRouteIs404Problem) {
  ExpectProblem(http().Get("/api/v1/nope"), 404);
  ExpectProblem(http().Get("/api/v2/status"), 404);
  ExpectProblem(http().PostJson("/api/v1/nope", "{}"), 404);
  ExpectProblem(http().Get("/api/v1/jobs/999"), 404);
  ExpectProblem(http().Send("DELETE", "/api/v1/jobs/999", "", ""), 404);
}

TEST_F(SharedSlamd, WrongMethodOnAKnownRouteIs405WithAllow) {
  struct Case {
    std::string method, path, allowed;
  };
  const std::vector<Case> cases = {
      {"DELETE", kBudgetPath, "PATCH"},    {"POST", kBudgetPath, "PUT"},
      {"PUT", kParamsPath, "PATCH"},       {"POST", "/api/v1/health", "GET"},
      {"PATCH", "/api/v1/status", "GET"},  {"GET", "/api/v1/map/save", "POST"},
      {"GET", "/api/v1/reset", "POST"},    {"POST", "/api/v1/jobs", "GET"},
      {"PUT", "/api/v1/jobs/1", "DELETE"}, {"DELETE", "/api/v1/map", "GET"},
      {"POST", "/metrics", "GET"},
  };
  for (const auto& c : cases) {
    const bool bodied = c.method != "GET" && c.method != "DELETE";
    const Reply reply =
        http().Send(c.method, c.path, bodied ? "{}" : "", bodied ? "application/json" : "");
    SCOPED_TRACE(c.method + " " + c.path);
    ExpectProblem(reply, 405);
    EXPECT_NE(reply.Header("Allow").find(c.allowed), std::string::npos)
        << "Allow: " << reply.Header("Allow");
  }
}

// --- budget -----------------------------------------------------------------------------------

TEST_F(SharedSlamd, BudgetGetHasAnETagAndTheDocumentedKeys) {
  const Reply reply = http().Get(kBudgetPath);
  ASSERT_EQ(reply.status, 200) << reply;
  EXPECT_TRUE(StartsWith(reply.ContentType(), "application/json")) << reply;
  const std::string etag = reply.Header("ETag");
  ASSERT_GE(etag.size(), 3u) << reply;
  EXPECT_EQ(etag.front(), '"');
  EXPECT_EQ(etag.back(), '"');
  const json budget = reply.Json();
  EXPECT_TRUE(budget["mode"] == "rays" || budget["mode"] == "cpu_share") << budget.dump();
  EXPECT_TRUE(budget["rays_per_scan"].is_number_integer()) << budget.dump();
  EXPECT_TRUE(budget["cpu_share"].is_number()) << budget.dump();
  EXPECT_TRUE(budget["policy"] == "fixed" || budget["policy"] == "adaptive") << budget.dump();
  EXPECT_TRUE(budget["max_particles"].is_number_integer()) << budget.dump();
  EXPECT_EQ(budget.size(), 5u) << budget.dump();
  // The ETag is stable while nothing changes.
  EXPECT_EQ(http().Get(kBudgetPath).Header("ETag"), etag);
}

TEST_F(SharedSlamd, BudgetMergePatchAppliesAndNullResetsToTheDefault) {
  const Reply before = http().Get(kBudgetPath);
  ASSERT_EQ(before.status, 200);
  const json original = before.Json();
  const int64_t default_rays = original["rays_per_scan"].get<int64_t>();
  const int64_t new_rays = default_rays == 12345 ? 23456 : 12345;

  const Reply patched = http().MergePatch(kBudgetPath, json({{"rays_per_scan", new_rays}}).dump());
  ASSERT_EQ(patched.status, 200) << patched;
  EXPECT_TRUE(StartsWith(patched.ContentType(), "application/json")) << patched;
  json expected = original;
  expected["rays_per_scan"] = new_rays;
  EXPECT_EQ(patched.Json(), expected);
  const std::string new_etag = patched.Header("ETag");
  EXPECT_FALSE(new_etag.empty());
  EXPECT_NE(new_etag, before.Header("ETag"));
  const Reply after = http().Get(kBudgetPath);
  EXPECT_EQ(after.Json(), expected);
  EXPECT_EQ(after.Header("ETag"), new_etag);
  // The status reports the same object.
  EXPECT_EQ(GetJson(http(), "/api/v1/status")["budget"], expected);

  // Two keys at once.
  const Reply two = http().MergePatch(kBudgetPath, R"({"policy": "adaptive", "max_particles": 7})");
  ASSERT_EQ(two.status, 200) << two;
  EXPECT_EQ(two.Json()["policy"], "adaptive");
  EXPECT_EQ(two.Json()["max_particles"], 7);
  EXPECT_EQ(two.Json()["rays_per_scan"], new_rays);

  // null puts every named key back to its default (slamd was started without budget flags).
  const Reply reset = http().MergePatch(
      kBudgetPath, R"({"rays_per_scan": null, "policy": null, "max_particles": null})");
  ASSERT_EQ(reset.status, 200) << reset;
  EXPECT_EQ(reset.Json(), original);
  EXPECT_EQ(http().Get(kBudgetPath).Json(), original);
}

TEST_F(SharedSlamd, BudgetPutReplacesTheWholeObject) {
  const json original = GetJson(http(), kBudgetPath);
  const json replacement = {{"mode", "cpu_share"},
                            {"rays_per_scan", 4321},
                            {"cpu_share", 0.5},
                            {"policy", "adaptive"},
                            {"max_particles", 3}};
  const Reply put = http().PutJson(kBudgetPath, replacement.dump());
  ASSERT_EQ(put.status, 200) << put;
  EXPECT_EQ(put.Json(), replacement);
  EXPECT_FALSE(put.Header("ETag").empty());
  EXPECT_EQ(GetJson(http(), kBudgetPath), replacement);

  // PUT wants every key: a missing one is a validation error and changes nothing.
  json partial = original;
  partial.erase("policy");
  const Reply missing = http().PutJson(kBudgetPath, partial.dump());
  const json problem = ExpectProblem(missing, 422);
  const auto pointers = ErrorPointers(problem);
  EXPECT_TRUE(pointers.count("/policy") == 1 || pointers.count("") == 1) << missing;
  EXPECT_EQ(GetJson(http(), kBudgetPath), replacement);

  // Wrong type in a PUT.
  json wrong = original;
  wrong["max_particles"] = "many";
  Expect422At(http().PutJson(kBudgetPath, wrong.dump()), {"/max_particles"});

  const Reply restore = http().PutJson(kBudgetPath, original.dump());
  ASSERT_EQ(restore.status, 200) << restore;
  EXPECT_EQ(GetJson(http(), kBudgetPath), original);
}

TEST_F(SharedSlamd, BudgetRejectsWrongContentTypeWith415) {
  const Reply before = http().Get(kBudgetPath);
  ExpectProblem(http().Send("PATCH", kBudgetPath, R"({"rays_per_scan": 777})", "text/plain"), 415);
  ExpectProblem(http().Send("PATCH", kBudgetPath, R"({"rays_per_scan": 777})", ""), 415);
  ExpectProblem(http().Send("PUT", kBudgetPath, before.body, "text/plain"), 415);
  EXPECT_EQ(http().Get(kBudgetPath).body, before.body);
}

TEST_F(SharedSlamd, BudgetRejectsMalformedJsonWith400) {
  const Reply before = http().Get(kBudgetPath);
  for (const std::string body : {R"({"rays_per_scan": )", "not json", R"({"a":1}})", ""}) {
    SCOPED_TRACE(body);
    ExpectProblem(http().MergePatch(kBudgetPath, body), 400);
  }
  ExpectProblem(http().PutJson(kBudgetPath, "{"), 400);
  EXPECT_EQ(http().Get(kBudgetPath).body, before.body);
  EXPECT_EQ(http().Get(kBudgetPath).Header("ETag"), before.Header("ETag"));
}

TEST_F(SharedSlamd, BudgetValidationErrorsAre422WithOnePointerPerProblem) {
  const Reply before = http().Get(kBudgetPath);
  // Wrong types.
  Expect422At(http().MergePatch(kBudgetPath, R"({"rays_per_scan": "many"})"), {"/rays_per_scan"});
  Expect422At(http().MergePatch(kBudgetPath, R"({"rays_per_scan": 1.5})"), {"/rays_per_scan"});
  Expect422At(http().MergePatch(kBudgetPath, R"({"cpu_share": "half"})"), {"/cpu_share"});
  Expect422At(http().MergePatch(kBudgetPath, R"({"policy": 3})"), {"/policy"});
  Expect422At(http().MergePatch(kBudgetPath, R"({"mode": true})"), {"/mode"});
  // Out of range, all bounds.
  Expect422At(http().MergePatch(kBudgetPath, R"({"rays_per_scan": 0})"), {"/rays_per_scan"});
  Expect422At(http().MergePatch(kBudgetPath, R"({"rays_per_scan": 100000001})"),
              {"/rays_per_scan"});
  Expect422At(http().MergePatch(kBudgetPath, R"({"cpu_share": 0})"), {"/cpu_share"});
  Expect422At(http().MergePatch(kBudgetPath, R"({"cpu_share": 1.01})"), {"/cpu_share"});
  Expect422At(http().MergePatch(kBudgetPath, R"({"max_particles": 0})"), {"/max_particles"});
  Expect422At(http().MergePatch(kBudgetPath, R"({"max_particles": 1001})"), {"/max_particles"});
  Expect422At(http().MergePatch(kBudgetPath, R"({"mode": "fast"})"), {"/mode"});
  Expect422At(http().MergePatch(kBudgetPath, R"({"policy": "lazy"})"), {"/policy"});
  // Unknown keys.
  Expect422At(http().MergePatch(kBudgetPath, R"({"rays": 5})"), {"/rays"});
  // Several problems at once: one error each, and nothing applied (not even the valid key).
  Expect422At(http().MergePatch(kBudgetPath, R"({"rays_per_scan": 0, "cpu_share": 2,
                                                 "max_particles": "x", "bogus": 1,
                                                 "policy": "adaptive"})"),
              {"/rays_per_scan", "/cpu_share", "/max_particles", "/bogus"});
  // A body that is not an object is wrong as a whole.
  Expect422At(http().MergePatch(kBudgetPath, "[1, 2]"), {""});
  Expect422At(http().PutJson(kBudgetPath, "42"), {""});

  const Reply after = http().Get(kBudgetPath);
  EXPECT_EQ(after.body, before.body);
  EXPECT_EQ(after.Header("ETag"), before.Header("ETag"));
  // The boundaries themselves are valid.
  const json original = before.Json();
  const Reply edge = http().MergePatch(
      kBudgetPath, R"({"rays_per_scan": 1, "cpu_share": 1, "max_particles": 1000})");
  EXPECT_EQ(edge.status, 200) << edge;
  const Reply restore = http().PutJson(kBudgetPath, original.dump());
  EXPECT_EQ(restore.status, 200) << restore;
}

TEST_F(SharedSlamd, BudgetIfMatchStaleIs412AndCurrentApplies) {
  const Reply before = http().Get(kBudgetPath);
  const std::string etag = before.Header("ETag");
  ASSERT_FALSE(etag.empty());
  const json original = before.Json();
  const int64_t rays = original["rays_per_scan"].get<int64_t>();

  const Reply stale = http().MergePatch(kBudgetPath, json({{"rays_per_scan", rays + 1}}).dump(),
                                        {{"If-Match", "\"stale-etag\""}});
  ExpectProblem(stale, 412);
  EXPECT_EQ(http().Get(kBudgetPath).body, before.body);
  EXPECT_EQ(http().Get(kBudgetPath).Header("ETag"), etag);
  json replacement = original;
  replacement["rays_per_scan"] = rays + 1;
  ExpectProblem(http().PutJson(kBudgetPath, replacement.dump(), {{"If-Match", "\"b0-old\""}}), 412);
  EXPECT_EQ(http().Get(kBudgetPath).body, before.body);
  // An empty If-Match applied the change; a weak tag matches nothing under If-Match.
  const std::string patch = json({{"rays_per_scan", rays + 1}}).dump();
  const RawReply empty = RawExchange(
      port(), "PATCH " + std::string(kBudgetPath) +
                  " HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/merge-patch+json\r\n"
                  "If-Match:\r\nConnection: close\r\nContent-Length: " +
                  std::to_string(patch.size()) + "\r\n\r\n" + patch);
  EXPECT_EQ(empty.status, 412) << empty.raw;
  ExpectProblem(http().MergePatch(kBudgetPath, patch, {{"If-Match", "W/" + etag}}), 412);
  EXPECT_EQ(http().Get(kBudgetPath).body, before.body);

  const Reply current = http().MergePatch(kBudgetPath, json({{"rays_per_scan", rays + 1}}).dump(),
                                          {{"If-Match", etag}});
  ASSERT_EQ(current.status, 200) << current;
  const std::string new_etag = current.Header("ETag");
  EXPECT_FALSE(new_etag.empty());
  EXPECT_NE(new_etag, etag);
  EXPECT_EQ(current.Json()["rays_per_scan"], rays + 1);
  // The old ETag is stale now.
  ExpectProblem(http().MergePatch(kBudgetPath, R"({"rays_per_scan": 5})", {{"If-Match", etag}}),
                412);
  // PUT with the current ETag restores.
  const Reply restore = http().PutJson(kBudgetPath, original.dump(), {{"If-Match", new_etag}});
  ASSERT_EQ(restore.status, 200) << restore;
  EXPECT_EQ(restore.Json(), original);
}

// --- params -----------------------------------------------------------------------------------

const std::vector<std::string> kParamKeys = {
    "dist_error_ratio",        "dist_error_const_m",      "angle_error_ratio",
    "angle_error_const_deg",   "min_pos_uncertainty_m",   "min_angle_uncertainty_deg",
    "resampling_period_scans", "angle_between_scans_deg", "particles"};

TEST_F(SharedSlamd, ParamsGetHasTheTableIIKeysAndAnETag) {
  const Reply reply = http().Get(kParamsPath);
  ASSERT_EQ(reply.status, 200) << reply;
  EXPECT_TRUE(StartsWith(reply.ContentType(), "application/json")) << reply;
  EXPECT_FALSE(reply.Header("ETag").empty());
  const json params = reply.Json();
  ASSERT_TRUE(params.is_object()) << reply;
  EXPECT_EQ(params.size(), kParamKeys.size()) << params.dump();
  for (const auto& key : kParamKeys) {
    EXPECT_TRUE(params.contains(key) && params[key].is_number()) << key;
  }
  // slamd was started without --params, at 65000 rays/scan: the shipped set of that budget,
  // named in the status.
  const json shipped =
      json::parse(ReadFile(fs::path(SLAM_SOURCE_DIR) / "config" / "params" / "65000.json"));
  for (const auto& [key, value] : shipped.items()) {
    EXPECT_DOUBLE_EQ(params.value(key, -1.0), value.get<double>()) << key;
  }
  const json status = GetJson(http(), "/api/v1/status");
  EXPECT_EQ(status["params"], json({{"set", "shipped-65000"}, {"follows_budget", true}}));
}

TEST_F(SharedSlamd, TheShippedSetFollowsTheBudgetUntilParamsArePatched) {
  const json budget = GetJson(http(), kBudgetPath);
  const auto shipped = [](const char* file) {
    return json::parse(ReadFile(fs::path(SLAM_SOURCE_DIR) / "config" / "params" / file));
  };
  // 20000 rays/scan: the set of the largest paper budget not above it, with a new ETag at once.
  const std::string etag_before = http().Get(kParamsPath).Header("ETag");
  ASSERT_EQ(http().MergePatch(kBudgetPath, R"({"rays_per_scan": 20000})").status, 200);
  const Reply switched = http().Get(kParamsPath);
  EXPECT_EQ(switched.Json(), shipped("16250.json"));
  EXPECT_NE(switched.Header("ETag"), etag_before);
  EXPECT_EQ(GetJson(http(), "/api/v1/status")["params"]["set"], "shipped-16250");

  // A patch makes a set of its own that holds whatever the budget.
  const Reply patched = http().MergePatch(kParamsPath, R"({"particles": 3})");
  ASSERT_EQ(patched.status, 200) << patched;
  json expected = shipped("16250.json");
  expected["particles"] = 3;
  EXPECT_EQ(patched.Json(), expected);
  // The ETag changes with the parameters only: scans that follow (the engine taking the set up)
  // and a budget change leave it, so that an If-Match made from it still applies.
  const int64_t scans = GetJson(http(), "/api/v1/status")["slam"]["scans"].get<int64_t>();
  const auto deadline = After(10.0);
  while (GetJson(http(), "/api/v1/status")["slam"]["scans"].get<int64_t>() < scans + 2 &&
         Clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ASSERT_EQ(http().MergePatch(kBudgetPath, R"({"rays_per_scan": 65000})").status, 200);
  EXPECT_EQ(http().Get(kParamsPath).Header("ETag"), patched.Header("ETag"));
  EXPECT_EQ(GetJson(http(), kParamsPath), expected);
  EXPECT_EQ(GetJson(http(), "/api/v1/status")["params"],
            json({{"set", "shipped-16250, patched"}, {"follows_budget", false}}));

  // DELETE goes back to the shipped set of the budget.
  const Reply back = http().Send("DELETE", kParamsPath, "", "");
  ASSERT_EQ(back.status, 200) << back;
  EXPECT_EQ(back.Json(), shipped("65000.json"));
  EXPECT_NE(back.Header("ETag"), patched.Header("ETag"));
  EXPECT_EQ(GetJson(http(), "/api/v1/status")["params"],
            json({{"set", "shipped-65000"}, {"follows_budget", true}}));
  EXPECT_EQ(http().PutJson(kBudgetPath, budget.dump()).status, 200);
}

TEST_F(SharedSlamd, ParamsMergePatchAppliesAndNullResetsToTheDefault) {
  const Reply before = http().Get(kParamsPath);
  const json original = before.Json();
  const Reply patched =
      http().MergePatch(kParamsPath, R"({"particles": 2, "dist_error_ratio": 0.1})");
  ASSERT_EQ(patched.status, 200) << patched;
  json expected = original;
  expected["particles"] = 2;
  expected["dist_error_ratio"] = 0.1;
  EXPECT_EQ(patched.Json(), expected);
  EXPECT_NE(patched.Header("ETag"), before.Header("ETag"));
  EXPECT_FALSE(patched.Header("ETag").empty());
  EXPECT_EQ(GetJson(http(), kParamsPath), expected);

  const Reply reset =
      http().MergePatch(kParamsPath, R"({"particles": null, "dist_error_ratio": null})");
  ASSERT_EQ(reset.status, 200) << reset;
  EXPECT_EQ(reset.Json(), original);
  EXPECT_EQ(GetJson(http(), kParamsPath), original);
}

TEST_F(SharedSlamd, ParamsErrorsAre415And400And422AndChangeNothing) {
  const Reply before = http().Get(kParamsPath);
  ExpectProblem(http().Send("PATCH", kParamsPath, R"({"particles": 2})", "text/plain"), 415);
  ExpectProblem(http().MergePatch(kParamsPath, R"({"particles": )"), 400);
  Expect422At(http().MergePatch(kParamsPath, R"({"particles": "two"})"), {"/particles"});
  Expect422At(http().MergePatch(kParamsPath, R"({"particles": 2.5})"), {"/particles"});
  Expect422At(http().MergePatch(kParamsPath, R"({"particles": 0})"), {"/particles"});
  Expect422At(http().MergePatch(kParamsPath, R"({"particles": 1001})"), {"/particles"});
  Expect422At(http().MergePatch(kParamsPath, R"({"dist_error_ratio": 1.5})"),
              {"/dist_error_ratio"});
  Expect422At(http().MergePatch(kParamsPath, R"({"min_angle_uncertainty_deg": -1})"),
              {"/min_angle_uncertainty_deg"});
  Expect422At(http().MergePatch(kParamsPath, R"({"resampling_period_scans": 0})"),
              {"/resampling_period_scans"});
  Expect422At(http().MergePatch(kParamsPath, R"({"foo": 1})"), {"/foo"});
  Expect422At(http().MergePatch(kParamsPath,
                                R"({"particles": 0, "angle_between_scans_deg": 200,
                                    "foo": 1, "dist_error_const_m": "x"})"),
              {"/particles", "/angle_between_scans_deg", "/foo", "/dist_error_const_m"});
  Expect422At(http().MergePatch(kParamsPath, R"("text")"), {""});
  const Reply after = http().Get(kParamsPath);
  EXPECT_EQ(after.body, before.body);
  EXPECT_EQ(after.Header("ETag"), before.Header("ETag"));
}

TEST_F(SharedSlamd, ParamsIfMatchStaleIs412AndCurrentApplies) {
  const Reply before = http().Get(kParamsPath);
  const std::string etag = before.Header("ETag");
  ASSERT_FALSE(etag.empty());
  ExpectProblem(http().MergePatch(kParamsPath, R"({"particles": 3})", {{"If-Match", "\"p999\""}}),
                412);
  EXPECT_EQ(http().Get(kParamsPath).body, before.body);
  EXPECT_EQ(http().Get(kParamsPath).Header("ETag"), etag);

  const Reply current = http().MergePatch(kParamsPath, R"({"particles": 3})", {{"If-Match", etag}});
  ASSERT_EQ(current.status, 200) << current;
  EXPECT_EQ(current.Json()["particles"], 3);
  const std::string new_etag = current.Header("ETag");
  EXPECT_NE(new_etag, etag);
  EXPECT_FALSE(new_etag.empty());
  const Reply restore =
      http().MergePatch(kParamsPath, R"({"particles": null})", {{"If-Match", new_etag}});
  ASSERT_EQ(restore.status, 200) << restore;
  EXPECT_EQ(restore.Json(), before.Json());
}

// --- map --------------------------------------------------------------------------------------

TEST_F(SharedSlamd, MapIndexListsTilesWithinSecondsAndVersionsGrow) {
  const json map = WaitForTiles(http(), 1);
  EXPECT_DOUBLE_EQ(map.value("resolution_m", 0.0), 0.01);
  EXPECT_EQ(map.value("tile_size", 0), 64);
  ASSERT_TRUE(map["origin"].is_array() && map["origin"].size() == 2) << map.dump();
  EXPECT_TRUE(map["origin"][0].is_number() && map["origin"][1].is_number());
  int64_t largest = 0;
  std::set<std::pair<int64_t, int64_t>> seen;
  for (const auto& tile : map["tiles"]) {
    ASSERT_TRUE(tile["x"].is_number_integer() && tile["y"].is_number_integer() &&
                tile["version"].is_number_integer())
        << tile.dump();
    EXPECT_TRUE(seen.insert({tile["x"].get<int64_t>(), tile["y"].get<int64_t>()}).second)
        << "duplicate tile " << tile.dump();
    largest = std::max(largest, tile["version"].get<int64_t>());
  }
  EXPECT_EQ(map.value("version", int64_t{-1}), largest);

  const int64_t first = map["version"].get<int64_t>();
  const auto deadline = After(10.0);
  int64_t now = first;
  while (now <= first && Clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    now = MapVersion(http());
  }
  EXPECT_GT(now, first) << "the map version did not grow in 10 s";
}

TEST_F(SharedSlamd, TilePngIs64x64GreyWithETagAndConditionalGet) {
  const json map = WaitForTiles(http(), 1);
  // The least recently changed tile, so that it stays put while we ask for it twice.
  json oldest = map["tiles"][0];
  for (const auto& tile : map["tiles"]) {
    if (tile["version"].get<int64_t>() < oldest["version"].get<int64_t>()) oldest = tile;
  }
  const std::string path = "/api/v1/map/tiles/" + std::to_string(oldest["x"].get<int64_t>()) + "/" +
                           std::to_string(oldest["y"].get<int64_t>()) + ".png";
  const Reply tile = http().Get(path);
  ASSERT_EQ(tile.status, 200) << path << " " << tile;
  EXPECT_EQ(tile.ContentType(), "image/png");
  ASSERT_GE(tile.body.size(), 33u);
  EXPECT_EQ(tile.body.substr(0, 8), kPngSignature);
  EXPECT_EQ(tile.body.substr(12, 4), "IHDR");
  EXPECT_EQ(BigEndian32(tile.body, 16), 64u);     // width
  EXPECT_EQ(BigEndian32(tile.body, 20), 64u);     // height
  EXPECT_EQ(static_cast<int>(tile.body[24]), 8);  // bit depth
  EXPECT_EQ(static_cast<int>(tile.body[25]), 0);  // colour type: grey

  // ETag: "VERSION", at least the version the index listed.
  const std::string etag = tile.Header("ETag");
  ASSERT_GE(etag.size(), 3u);
  ASSERT_EQ(etag.front(), '"');
  ASSERT_EQ(etag.back(), '"');
  const int64_t version = std::atoll(etag.substr(1, etag.size() - 2).c_str());
  EXPECT_GE(version, oldest["version"].get<int64_t>()) << etag;
  EXPECT_EQ(etag, "\"" + std::to_string(version) + "\"");

  // If-None-Match with the current ETag: 304 (a changed tile answers 200 with a new ETag).
  std::string current = etag;
  bool got_304 = false;
  for (int attempt = 0; attempt < 5 && !got_304; ++attempt) {
    const Reply again = http().Get(path, {{"If-None-Match", current}});
    if (again.status == 304) {
      got_304 = true;
      EXPECT_TRUE(again.body.empty());
    } else {
      ASSERT_EQ(again.status, 200) << again;
      EXPECT_NE(again.Header("ETag"), current) << "200 for an unchanged ETag";
      current = again.Header("ETag");
    }
  }
  EXPECT_TRUE(got_304);
  // A stale ETag gets the tile. "*", a weak tag and a list holding the tag are 304 (they were 200).
  EXPECT_EQ(http().Get(path, {{"If-None-Match", "\"0\""}}).status, 200);
  for (const std::string& matching : {std::string("*"), "W/" + current, "\"0\", " + current}) {
    const Reply again = http().Get(path, {{"If-None-Match", matching}});
    if (again.status == 200) current = again.Header("ETag");  // the tile changed meanwhile
    EXPECT_TRUE(again.status == 304 || (matching != "*" && again.status == 200))
        << matching << again;
  }
  // ?v= is only for cache busting.
  const Reply busted = http().Get(path + "?v=1");
  EXPECT_EQ(busted.status, 200) << busted;
  EXPECT_EQ(busted.body.substr(0, 8), kPngSignature);
}

TEST_F(SharedSlamd, UnknownTileIs404Problem) {
  ExpectProblem(http().Get("/api/v1/map/tiles/100000/100000.png"), 404);
  ExpectProblem(http().Get("/api/v1/map/tiles/-100000/7.png"), 404);
  ExpectProblem(http().Get("/api/v1/map/tiles/a/b.png"), 404);
}

TEST_F(SharedSlamd, WholeMapAsPgmYamlAndPng) {
  WaitForTiles(http(), 1);
  const Reply pgm = http().Get("/api/v1/map.pgm");
  ASSERT_EQ(pgm.status, 200) << pgm;
  EXPECT_NE(pgm.Header("Content-Disposition").find("attachment"), std::string::npos);
  ASSERT_GE(pgm.body.size(), 2u);
  EXPECT_EQ(pgm.body.substr(0, 2), "P5");
  {
    // "P5 <w> <h> <max>\n" then w*h bytes (comments allowed after the magic).
    std::istringstream head(pgm.body);
    std::string magic, token;
    head >> magic;
    std::vector<long> numbers;
    while (numbers.size() < 3 && head >> token) {
      if (token.front() == '#') {
        std::getline(head, token);
        continue;
      }
      numbers.push_back(std::atol(token.c_str()));
    }
    ASSERT_EQ(numbers.size(), 3u);
    EXPECT_GT(numbers[0], 0);
    EXPECT_GT(numbers[1], 0);
    EXPECT_EQ(numbers[2], 255);
    const auto header_end = static_cast<size_t>(head.tellg()) + 1;
    EXPECT_EQ(pgm.body.size() - header_end, static_cast<size_t>(numbers[0] * numbers[1]));
  }

  const Reply yaml = http().Get("/api/v1/map.yaml");
  ASSERT_EQ(yaml.status, 200) << yaml;
  EXPECT_NE(yaml.Header("Content-Disposition").find("attachment"), std::string::npos);
  EXPECT_NE(yaml.body.find("image: map.pgm"), std::string::npos) << yaml.body;
  const size_t resolution = yaml.body.find("resolution:");
  ASSERT_NE(resolution, std::string::npos) << yaml.body;
  EXPECT_DOUBLE_EQ(std::strtod(yaml.body.c_str() + resolution + 11, nullptr), 0.01);
  EXPECT_NE(yaml.body.find("origin:"), std::string::npos) << yaml.body;

  const Reply png = http().Get("/api/v1/map.png");
  ASSERT_EQ(png.status, 200) << png;
  EXPECT_EQ(png.ContentType(), "image/png");
  EXPECT_NE(png.Header("Content-Disposition").find("attachment"), std::string::npos);
  EXPECT_EQ(png.body.substr(0, 8), kPngSignature);
}

// --- trajectory -------------------------------------------------------------------------------

TEST_F(SharedSlamd, TrajectoryJsonGrowsAndHasGroundTruth) {
  const json first = WaitForTrajectory(http(), 2);
  ASSERT_TRUE(first["slam"].is_array());
  for (const auto& pose : first["slam"]) {
    ASSERT_TRUE(pose.is_array() && pose.size() == 4) << pose.dump();
    for (const auto& value : pose) EXPECT_TRUE(value.is_number());
  }
  ASSERT_TRUE(first.contains("ground_truth")) << "simulated source: ground truth expected";
  ASSERT_TRUE(first["ground_truth"].is_array());
  EXPECT_FALSE(first["ground_truth"].empty());
  for (const auto& pose : first["ground_truth"]) {
    ASSERT_TRUE(pose.is_array() && pose.size() == 4) << pose.dump();
  }
  // Times do not go back.
  for (size_t i = 1; i < first["slam"].size(); ++i) {
    EXPECT_GE(first["slam"][i][0].get<double>(), first["slam"][i - 1][0].get<double>());
  }
  const json explicit_json = GetJson(http(), "/api/v1/trajectory?format=json");
  EXPECT_GE(explicit_json["slam"].size(), first["slam"].size());
  const json later = WaitForTrajectory(http(), first["slam"].size() + 2, 10.0);
  EXPECT_GT(later["slam"].size(), first["slam"].size());
}

TEST_F(SharedSlamd, TrajectoryTumIsTextWithEightColumns) {
  WaitForTrajectory(http(), 2);
  const Reply tum = http().Get("/api/v1/trajectory?format=tum");
  ASSERT_EQ(tum.status, 200) << tum;
  EXPECT_TRUE(StartsWith(tum.ContentType(), "text/plain")) << tum;
  const auto rows = ParseTum(tum.body);
  ASSERT_GE(rows.size(), 2u) << tum.body;
  for (const auto& row : rows) {
    ASSERT_EQ(row.size(), 8u);
    EXPECT_NEAR(row[4] * row[4] + row[5] * row[5] + row[6] * row[6] + row[7] * row[7], 1.0, 1e-3);
  }
}

TEST_F(SharedSlamd, TrajectoryUnknownFormatIs400) {
  ExpectProblem(http().Get("/api/v1/trajectory?format=xml"), 400);
  ExpectProblem(http().Get("/api/v1/trajectory?format="), 400);
}

// --- save, reset and jobs where they are not configured ----------------------------------------

TEST_F(SharedSlamd, SaveWithoutStateDirIs409) {
  ExpectProblem(http().PostJson("/api/v1/map/save", "{}"), 409);
}

TEST_F(SharedSlamd, TuningWithoutExperimentsIs409) {
  ExpectProblem(http().PostJson("/api/v1/jobs/tune", "{}"), 409);
  const json jobs = GetJson(http(), "/api/v1/jobs");
  ASSERT_TRUE(jobs["jobs"].is_array()) << jobs.dump();
  EXPECT_TRUE(jobs["jobs"].empty());
}

// --- request framing and origin ------------------------------------------------------------

// Every framing refusal below targets POST /api/v1/map/save: accepted by mistake, it would
// answer 409 (no --state-dir), never the status under test.

TEST_F(SharedSlamd, CrossOriginMutationIs403AndSameOriginIsAllowed) {
  const Reply before = http().Get(kBudgetPath);
  const json original = before.Json();
  const std::string same_value = json({{"rays_per_scan", original["rays_per_scan"]}}).dump();
  ExpectProblem(http().MergePatch(kBudgetPath, R"({"rays_per_scan": 99})",
                                  {{"Origin", "http://evil.example"}}),
                403);
  ExpectProblem(http().PostJson("/api/v1/reset", "{}", {{"Origin", "http://evil.example"}}), 403);
  ExpectProblem(http().PostJson("/api/v1/map/save", "{}",
                                {{"Origin", "http://localhost:" + std::to_string(port())}}),
                403);
  EXPECT_EQ(http().Get(kBudgetPath).body, before.body);
  const std::string own_origin = "http://127.0.0.1:" + std::to_string(port());
  EXPECT_EQ(http().MergePatch(kBudgetPath, same_value, {{"Origin", own_origin}}).status, 200);
  // Reading is never refused.
  EXPECT_EQ(http().Get(kBudgetPath, {{"Origin", "http://evil.example"}}).status, 200);
}

TEST_F(SharedSlamd, BodyOver64KiBIs413) {
  const std::string body = "{\"pad\": \"" + std::string(70 * 1024, 'x') + "\"}";
  const std::string request =
      "POST /api/v1/map/save HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(port()) +
      "\r\nContent-Type: application/json\r\nContent-Length: " + std::to_string(body.size()) +
      "\r\nConnection: close\r\n\r\n" + body;
  const RawReply reply = RawExchange(port(), request);
  EXPECT_EQ(reply.status, 413) << reply;
  // Exactly 64 KiB is still fine (and then the route answers).
  const std::string edge_body = "{\"pad\": \"" + std::string(64 * 1024 - 12, 'x') + "\"}";
  ASSERT_EQ(edge_body.size(), 64u * 1024u - 1u);
  const RawReply edge = RawExchange(
      port(), "POST /api/v1/map/save HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(port()) +
                  "\r\nContent-Type: application/json\r\nContent-Length: " +
                  std::to_string(edge_body.size()) + "\r\nConnection: close\r\n\r\n" + edge_body);
  EXPECT_EQ(edge.status, 409) << edge;
}

TEST_F(SharedSlamd, DeeplyNestedBodiesAre400AndSlamdServesOn) {
  // nlohmann-json copies and compares nested values recursively: 64 KiB of brackets nest 32 000
  // deep, a stack frame or more each (under AddressSanitizer, more than a thread's stack).
  const std::string arrays = std::string(32'000, '[') + std::string(32'000, ']');
  std::string objects;
  for (int i = 0; i < 6'000; ++i) objects += R"({"a":)";
  objects += "1" + std::string(6'000, '}');
  for (const std::string& body : {arrays, objects}) {
    SCOPED_TRACE(body.substr(0, 8));
    ExpectProblem(http().Send("PUT", kBudgetPath, body, "application/json"), 400);
    ExpectProblem(http().MergePatch(kBudgetPath, body), 400);
    ExpectProblem(http().MergePatch("/api/v1/params", body), 400);
    ExpectProblem(http().PostJson("/api/v1/map/save", body), 400);
  }
  // 32 levels are still JSON slamd reads (and then refuses as a budget).
  const std::string nested_32 = std::string(31, '[') + std::string(31, ']');
  ExpectProblem(
      http().Send("PUT", kBudgetPath, R"({"mode": )" + nested_32 + "}", "application/json"), 422);
  EXPECT_EQ(http().Get("/api/v1/health").status, 200);
}

TEST_F(SharedSlamd, ChunkedBodyIs411) {
  const std::string request =
      "POST /api/v1/map/save HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(port()) +
      "\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n"
      "Connection: close\r\n\r\n2\r\n{}\r\n0\r\n\r\n";
  const RawReply reply = RawExchange(port(), request);
  EXPECT_EQ(reply.status, 411) << reply;
  EXPECT_TRUE(StartsWith(reply.Header("Content-Type"), "application/problem+json")) << reply;
}

TEST_F(SharedSlamd, PostWithoutContentLengthIs411Quickly) {
  const std::string request =
      "POST /api/v1/map/save HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(port()) +
      "\r\nContent-Type: application/json\r\n\r\n";
  const RawReply reply = RawExchange(port(), request, 4.0);
  EXPECT_EQ(reply.status, 411) << reply;
  EXPECT_LT(reply.seconds, 1.0) << reply;
}

TEST_F(SharedSlamd, ContentEncodingIs415) {
  // gzip of "{}".
  const unsigned char gzip_bytes[] = {0x1f, 0x8b, 0x08, 0x00, 0x00, 0x00, 0x00, 0x00,
                                      0x00, 0x03, 0xab, 0xae, 0x05, 0x00, 0x43, 0xbf,
                                      0xa6, 0xa3, 0x02, 0x00, 0x00, 0x00};
  const std::string body(reinterpret_cast<const char*>(gzip_bytes), sizeof gzip_bytes);
  const std::string request =
      "POST /api/v1/map/save HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(port()) +
      "\r\nContent-Type: application/json\r\nContent-Encoding: gzip\r\nContent-Length: " +
      std::to_string(body.size()) + "\r\nConnection: close\r\n\r\n" + body;
  const RawReply reply = RawExchange(port(), request);
  EXPECT_EQ(reply.status, 415) << reply;
  // Also on a PATCH, through the ordinary client.
  ExpectProblem(
      http().Send("PATCH", kBudgetPath, body, kMergePatch, {{"Content-Encoding", "gzip"}}), 415);
}

TEST_F(SharedSlamd, PostBodyMustBeJson) {
  ExpectProblem(http().Send("POST", "/api/v1/map/save", "{}", "text/plain"), 415);
  ExpectProblem(http().PostJson("/api/v1/map/save", "{"), 400);
}

// --- metrics ----------------------------------------------------------------------------------

TEST_F(SharedSlamd, MetricsAreTextFormatWithEveryDocumentedName) {
  WaitForTiles(http(), 1);
  const Reply reply = http().Get("/metrics");
  ASSERT_EQ(reply.status, 200) << reply;
  EXPECT_TRUE(StartsWith(reply.ContentType(), "text/plain")) << reply.ContentType();
  EXPECT_NE(reply.ContentType().find("0.0.4"), std::string::npos) << reply.ContentType();
  const auto samples = ParseMetrics(reply.body);
  for (const char* name : {"scans_total",
                           "late_scans_total",
                           "rays_planned_total",
                           "rays_used_total",
                           "rays_per_scan_planned",
                           "rays_per_scan_used",
                           "ray_quota",
                           "cpu_share",
                           "realtime_ratio",
                           "particles",
                           "map_tiles",
                           "map_version",
                           "link_frames_total",
                           "link_events_total",
                           "link_queue_drops_total",
                           "link_source_errors_total",
                           "link_frames_rejected_total",
                           "link_up",
                           "link_silent",
                           "link_seconds_without_frames",
                           "http_requests_total",
                           "event_stream_clients",
                           "event_streams_rejected_total",
                           "jobs_running",
                           "map_saves_total"}) {
    EXPECT_TRUE(Metric(samples, std::string("slamd_") + name).has_value()) << name;
  }
  for (const char* suffix : {"_bucket", "_sum", "_count"}) {
    EXPECT_TRUE(Metric(samples, std::string("slamd_scan_latency_seconds") + suffix).has_value())
        << suffix;
  }
  EXPECT_TRUE(Metric(samples, "slamd_scan_latency_seconds_bucket", {{"le", "+Inf"}}).has_value());
  EXPECT_NE(reply.body.find("# TYPE slamd_scans_total counter"), std::string::npos);
  EXPECT_NE(reply.body.find("# TYPE slamd_scan_latency_seconds histogram"), std::string::npos);
  EXPECT_NE(reply.body.find("# TYPE slamd_map_tiles gauge"), std::string::npos);
  EXPECT_EQ(Metric(samples, "slamd_link_up"), 1.0);
  EXPECT_EQ(Metric(samples, "slamd_jobs_running"), 0.0);
  EXPECT_GT(Metric(samples, "slamd_map_tiles").value_or(0.0), 0.0);
  EXPECT_GT(Metric(samples, "slamd_link_frames_total").value_or(0.0), 0.0);
}

// Every family slamd exports is named in docs/http-api.md's `GET /metrics` section, as `name`,
// `name{...}` or `name (...)`: a metric added without its line there fails here.
TEST_F(SharedSlamd, EveryExportedMetricFamilyIsInTheApiDocument) {
  const Reply reply = http().Get("/metrics");
  ASSERT_EQ(reply.status, 200) << reply;
  const std::string whole = ReadFile(fs::path(SLAM_SOURCE_DIR) / "docs/http-api.md");
  const size_t from = whole.find("### `GET /metrics`"), to = whole.find("\n### ", from + 1);
  ASSERT_NE(from, std::string::npos);
  const std::string doc = whole.substr(from, to - from);  // that section only
  std::istringstream lines(reply.body);
  int families = 0;
  for (std::string line; std::getline(lines, line);) {
    const std::string type = "# TYPE slamd_";
    if (line.compare(0, type.size(), type) != 0) continue;
    const std::string name = line.substr(type.size(), line.find(' ', type.size()) - type.size());
    ++families;
    const bool named = doc.find("`" + name + "`") != std::string::npos ||
                       doc.find("`" + name + "{") != std::string::npos ||
                       doc.find("`" + name + " (") != std::string::npos;
    EXPECT_TRUE(named) << "slamd_" << name << " is not in docs/http-api.md's GET /metrics";
  }
  EXPECT_GE(families, 20);
}

TEST_F(SharedSlamd, MetricsScansTotalGrows) {
  const double first = Metric(GetMetrics(http()), "slamd_scans_total").value_or(-1.0);
  ASSERT_GE(first, 0.0);
  const auto later =
      PollMetric(http(), "slamd_scans_total", 10.0, [&](double value) { return value > first; });
  ASSERT_TRUE(later.has_value());
  EXPECT_GT(*later, first);
  const auto samples = GetMetrics(http());
  EXPECT_GE(Metric(samples, "slamd_rays_used_total").value_or(-1.0), 0.0);
  EXPECT_GE(Metric(samples, "slamd_scan_latency_seconds_count").value_or(-1.0), *later);
}

TEST_F(SharedSlamd, MetricsCountHttpRequestsByMethodAndCode) {
  const auto before = GetMetrics(http());
  const double get_200 =
      Metric(before, "slamd_http_requests_total", {{"method", "GET"}, {"code", "200"}})
          .value_or(0.0);
  const double get_404 =
      Metric(before, "slamd_http_requests_total", {{"method", "GET"}, {"code", "404"}})
          .value_or(0.0);
  const double patch_422 =
      Metric(before, "slamd_http_requests_total", {{"method", "PATCH"}, {"code", "422"}})
          .value_or(0.0);
  for (int i = 0; i < 5; ++i) ASSERT_EQ(http().Get("/api/v1/health").status, 200);
  for (int i = 0; i < 3; ++i) ASSERT_EQ(http().Get("/api/v1/nope").status, 404);
  ASSERT_EQ(http().MergePatch(kBudgetPath, R"({"bogus": 1})").status, 422);
  // slamd counts a request before its answer is written: a client that has its answer finds it
  // counted in the next /metrics, at once (no waiting: the counts once landed after the answer,
  // and a client reading /metrics at once missed one). The `before` read is itself a GET 200,
  // counted before its answer came; the `after` read not yet when it renders.
  const auto count = [](const std::vector<MetricSample>& metrics, const char* method,
                        const char* code) {
    return Metric(metrics, "slamd_http_requests_total", {{"method", method}, {"code", code}})
        .value_or(0.0);
  };
  const auto after = GetMetrics(http());
  EXPECT_EQ(count(after, "GET", "200") - get_200, 5.0 + 1.0);
  EXPECT_EQ(count(after, "GET", "404") - get_404, 3.0);
  EXPECT_EQ(count(after, "PATCH", "422") - patch_422, 1.0);
}

// ---------------------------------------------------------------------------------------------
// Process-level behaviour

TEST(SlamdProcessTest, NonLoopbackBindWithoutTokenExits2WithAMessage) {
  SlamdProcess slamd;
  std::string error;
  ASSERT_TRUE(slamd.Spawn({"--bind", "0.0.0.0"}, &error)) << error;
  const auto code = slamd.WaitExit(10.0);
  ASSERT_TRUE(code.has_value()) << "slamd kept running";
  EXPECT_EQ(*code, 2);
  const std::string message = Lower(slamd.Stderr());
  EXPECT_NE(message.find("token"), std::string::npos) << message;
  EXPECT_EQ(slamd.Stdout().find("slamd: serving"), std::string::npos) << slamd.Stdout();
}

TEST(SlamdProcessTest, ARobotWithALaserIsRefusedAtStartNamingTheFile) {
  // slamd's sources carry the marXbot's CAN events; a laser robot would get no scan at all.
  const std::string robot = std::string(SLAM_SOURCE_DIR) + "/config/pioneer-lms.robot.json";
  SlamdProcess slamd;
  std::string error;
  ASSERT_TRUE(slamd.Spawn({"--robot", robot}, &error)) << error;
  const auto code = slamd.WaitExit(10.0);
  ASSERT_TRUE(code.has_value()) << "slamd kept running";
  EXPECT_EQ(*code, 2);
  const std::string message = slamd.Stderr();
  EXPECT_NE(message.find("pioneer-lms.robot.json"), std::string::npos) << message;
  EXPECT_NE(message.find("range sensor"), std::string::npos) << message;
  EXPECT_NE(message.find("slam-replay"), std::string::npos) << message;
  EXPECT_EQ(slamd.Stdout().find("slamd: serving"), std::string::npos) << slamd.Stdout();
}

TEST(SlamdProcessTest, SigtermStopsCleanlyWithExitCode0) {
  SlamdProcess slamd;
  std::string error;
  ASSERT_TRUE(slamd.Start({"--budget", "8000"}, &error)) << error;
  Http http(slamd.host(), slamd.port());
  // With an open event stream too: stopping must not wait for it.
  EventStream stream;
  ASSERT_EQ(stream.Open(slamd.port()), 200);
  ASSERT_TRUE(stream.WaitFor("hello", 5.0).has_value());
  const auto start = Clock::now();
  ::kill(slamd.pid(), SIGTERM);
  const auto code = slamd.WaitExit(5.0);
  ASSERT_TRUE(code.has_value()) << "slamd did not stop within 5 s of SIGTERM";
  EXPECT_EQ(*code, 0);
  EXPECT_LT(SecondsSince(start), 3.0);
}

TEST(SlamdProcessTest, ParamsFlagHoldsOneSetWhateverTheBudget) {
  ScratchDir dir("params-flag");
  const std::string path = (dir.path() / "mine.json").string();
  WriteFile(path, R"({"particles": 2, "min_pos_uncertainty_m": 0.03})");
  SlamdProcess slamd;
  std::string error;
  ASSERT_TRUE(slamd.Start({"--budget", "8125", "--params", path}, &error)) << error;
  Http http(slamd.host(), slamd.port());
  EXPECT_EQ(GetJson(http, "/api/v1/status")["params"],
            json({{"set", path}, {"follows_budget", false}}));
  ASSERT_EQ(http.MergePatch(kBudgetPath, R"({"rays_per_scan": 65000})").status, 200);
  const json params = GetJson(http, kParamsPath);
  EXPECT_EQ(params.value("particles", 0), 2);
  EXPECT_DOUBLE_EQ(params.value("min_pos_uncertainty_m", 0.0), 0.03);
  EXPECT_EQ(GetJson(http, "/api/v1/status")["params"]["set"], path);
}

TEST(SlamdProcessTest, BudgetFlagSetsTheInitialBudget) {
  SlamdProcess slamd;
  std::string error;
  ASSERT_TRUE(
      slamd.Start({"--budget", "8000", "--policy", "adaptive", "--max-particles", "5"}, &error))
      << error;
  Http http(slamd.host(), slamd.port());
  const json budget = GetJson(http, kBudgetPath);
  EXPECT_EQ(budget.value("mode", ""), "rays");
  EXPECT_EQ(budget.value("rays_per_scan", 0), 8000);
  EXPECT_EQ(budget.value("policy", ""), "adaptive");
  EXPECT_EQ(budget.value("max_particles", 0), 5);
}

}  // namespace
}  // namespace slamd_test
