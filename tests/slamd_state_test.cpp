// slamd over HTTP, as a black box (docs/http-api.md): reset, saving and resuming a state
// directory, localisation on a saved map, poses given and relocalisation requested. The
// harness and its conventions are slamd_http_test.cpp's (tests/slamd_harness.hpp).

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
// Reset

TEST(SlamdResetTest, ResetDropsTilesAndVersionsKeepGrowing) {
  SlamdProcess slamd;
  std::string error;
  ASSERT_TRUE(slamd.Start({"--budget", "8000"}, &error)) << error;
  Http http(slamd.host(), slamd.port());
  WaitForTiles(http, 2);
  const json trajectory = WaitForTrajectory(http, 10);
  const int64_t version_before = MapVersion(http);
  ASSERT_GT(version_before, 0);

  EventStream stream;
  ASSERT_EQ(stream.Open(slamd.port()), 200);
  ASSERT_TRUE(stream.WaitFor("tiles", 5.0).has_value());

  const Reply reset = http.PostJson("/api/v1/reset", "{}");
  ASSERT_EQ(reset.status, 200) << reset;
  const json reset_body = reset.Json();
  ASSERT_TRUE(reset_body["version"].is_number_integer()) << reset;
  EXPECT_GE(reset_body["version"].get<int64_t>(), version_before);

  // Every tile listed now was written after the reset: the old ones were dropped.
  const json after = GetJson(http, "/api/v1/map");
  for (const auto& tile : after["tiles"]) {
    EXPECT_GT(tile["version"].get<int64_t>(), version_before) << tile.dump();
  }
  EXPECT_GE(after.value("version", int64_t{0}), version_before);
  const json restarted = GetJson(http, "/api/v1/trajectory");
  EXPECT_LT(restarted["slam"].size(), trajectory["slam"].size());

  // The stream tells viewers to drop their tiles.
  const auto reset_event = stream.WaitFor("reset", 3.0);
  ASSERT_TRUE(reset_event.has_value());
  EXPECT_EQ(reset_event->Json().value("version", int64_t{-1}),
            reset_body["version"].get<int64_t>());

  // Mapping goes on with ever larger versions.
  const json again = WaitForTiles(http, 1);
  for (const auto& tile : again["tiles"]) {
    EXPECT_GT(tile["version"].get<int64_t>(), version_before);
  }
  const auto tiles_event = stream.WaitFor("tiles", 5.0);
  ASSERT_TRUE(tiles_event.has_value());
  const json tiles_body = tiles_event->Json();  // a range-for would not keep a temporary alive
  for (const auto& tile : tiles_body["tiles"]) {
    EXPECT_GT(tile["version"].get<int64_t>(), version_before);
  }
}

// ---------------------------------------------------------------------------------------------
// Save and resume

TEST(SlamdStateDirTest, SavesRequestedTogetherShareASave) {
  // Each save waiting for the lock held a server thread for its own whole save: 16 at once
  // made 16 saves one after another. Those that waited share a save started after they came.
  ScratchDir state("state_together");
  SlamdProcess slamd;
  std::string error;
  ASSERT_TRUE(slamd.Start({"--state-dir", state.path().string(), "--budget", "8000"}, &error))
      << error;
  Http http(slamd.host(), slamd.port());
  WaitForTiles(http, 2);
  constexpr int kClients = 16;
  std::atomic<int> ok{0};
  std::atomic<int> ready{0};
  std::vector<std::thread> clients;
  for (int c = 0; c < kClients; ++c) {
    clients.emplace_back([&] {
      Http own(slamd.host(), slamd.port());
      ASSERT_EQ(own.Get("/api/v1/health").status, 200);  // connected before the burst
      ++ready;
      while (ready < kClients) std::this_thread::yield();
      const Reply reply = own.PostJson("/api/v1/map/save", "{}");
      if (reply.status == 200 && reply.Json()["version"].is_number_integer()) ++ok;
    });
  }
  for (auto& t : clients) t.join();
  EXPECT_EQ(ok.load(), kClients);
  const double together = Metric(GetMetrics(http), "slamd_map_saves_total").value_or(-1.0);
  EXPECT_GE(together, 1.0);
  EXPECT_LE(together, kClients / 2.0) << "saves requested together were each made";
  std::cout << "saves written for " << kClients << " requests at once: " << together << "\n";
  // A save asked for afterwards is made.
  ASSERT_EQ(http.PostJson("/api/v1/map/save", "{}").status, 200);
  EXPECT_EQ(Metric(GetMetrics(http), "slamd_map_saves_total").value_or(-1.0), together + 1.0);
}

TEST(SlamdStateDirTest, SaveWritesTheFilesAndARestartResumes) {
  ScratchDir state("state");
  size_t saved_tiles = 0;
  int64_t saved_version = 0;
  std::vector<std::vector<double>> saved_trajectory;
  {
    SlamdProcess slamd;
    std::string error;
    ASSERT_TRUE(slamd.Start({"--state-dir", state.path().string(), "--budget", "8000"}, &error))
        << error;
    Http http(slamd.host(), slamd.port());
    WaitForTiles(http, 2);
    WaitForTrajectory(http, 5);
    const Reply save = http.PostJson("/api/v1/map/save", "{}");
    ASSERT_EQ(save.status, 200) << save;
    const json body = save.Json();
    ASSERT_TRUE(body["path"].is_string()) << save;
    EXPECT_TRUE(fs::equivalent(fs::path(body["path"].get<std::string>()), state.path()))
        << body.dump();
    ASSERT_TRUE(body["version"].is_number_integer() && body["tiles"].is_number_integer());
    saved_version = body["version"].get<int64_t>();
    saved_tiles = body["tiles"].get<size_t>();
    EXPECT_GT(saved_version, 0);
    EXPECT_GT(saved_tiles, 0u);
    for (const char* name : {"map.pgm", "map.yaml", "map.png", "trajectory.tum", "state.json"}) {
      EXPECT_TRUE(fs::exists(state.path() / name)) << name;
      EXPECT_GT(fs::file_size(state.path() / name), 0u) << name;
    }
    EXPECT_EQ(ReadFile(state.path() / "map.pgm").substr(0, 2), "P5");
    EXPECT_NE(ReadFile(state.path() / "map.yaml").find("map.pgm"), std::string::npos);
    EXPECT_EQ(ReadFile(state.path() / "map.png").substr(0, 8), kPngSignature);
    EXPECT_FALSE(json::parse(ReadFile(state.path() / "state.json"), nullptr, false).is_discarded());
    saved_trajectory = ParseTum(ReadFile(state.path() / "trajectory.tum"));
    EXPECT_GE(saved_trajectory.size(), 5u);
    // No temporaries left behind.
    const auto file_names = [&] {
      std::set<std::string> names;
      for (const auto& entry : fs::directory_iterator(state.path())) {
        names.insert(entry.path().filename().string());
      }
      return names;
    };
    const std::set<std::string> first_files = file_names();
    for (const auto& name : first_files) {
      EXPECT_TRUE(name.find("tmp") == std::string::npos && name.front() != '.' &&
                  name.back() != '~')
          << "temporary file left: " << name;
    }
    // Saving again is fine (files replaced, none piling up).
    EXPECT_EQ(http.PostJson("/api/v1/map/save", "{}").status, 200);
    EXPECT_EQ(file_names().size(), first_files.size());
    const auto code = slamd.Stop();
    ASSERT_TRUE(code.has_value());
    EXPECT_EQ(*code, 0);
    // Keep the numbers of the last save (the second one).
    saved_trajectory = ParseTum(ReadFile(state.path() / "trajectory.tum"));
  }
  SlamdProcess resumed;
  std::string error;
  // The virtual marXbot starts over from its start pose, the map's origin (no reset here): said
  // with --pose, so that mapping goes on at once (without it slamd relocalises first).
  ASSERT_TRUE(resumed.Start(
      {"--state-dir", state.path().string(), "--budget", "8000", "--pose", "0,0,0"}, &error))
      << error;
  Http http(resumed.host(), resumed.port());
  // Right after the start: the saved map is there.
  const json map = GetJson(http, "/api/v1/map");
  EXPECT_GE(map["tiles"].size(), saved_tiles);
  EXPECT_GE(map.value("version", int64_t{0}), saved_version);
  // The trajectory starts with the saved one and goes on.
  const json trajectory = GetJson(http, "/api/v1/trajectory");
  ASSERT_TRUE(trajectory["slam"].is_array());
  ASSERT_GE(trajectory["slam"].size(), saved_trajectory.size());
  ASSERT_FALSE(saved_trajectory.empty());
  for (size_t i = 0; i < saved_trajectory.size();
       i += std::max<size_t>(1, saved_trajectory.size() / 5)) {
    EXPECT_NEAR(trajectory["slam"][i][0].get<double>(), saved_trajectory[i][0], 1e-3) << i;
    EXPECT_NEAR(trajectory["slam"][i][1].get<double>(), saved_trajectory[i][1], 1e-3) << i;
    EXPECT_NEAR(trajectory["slam"][i][2].get<double>(), saved_trajectory[i][2], 1e-3) << i;
  }
  const json later = WaitForTrajectory(http, saved_trajectory.size() + 3, 10.0);
  EXPECT_GT(later["slam"].size(), saved_trajectory.size());
  const auto& last = later["slam"].back();
  EXPECT_GT(last[0].get<double>(), saved_trajectory.back()[0]) << "time goes on after resuming";
  // New tiles get versions above the saved ones.
  const auto deadline = After(10.0);
  int64_t version = 0;
  while ((version = MapVersion(http)) <= saved_version && Clock::now() < deadline) Nap();
  EXPECT_GT(version, saved_version);
}

// ---------------------------------------------------------------------------------------------
// Where the robot is: a pose given, a relocalisation requested, the virtual marXbot kidnapped

class LocalizationSlamd : public SlamdSuite {
 protected:
  static void SetUpTestSuite() { StartShared({"--budget", "16250"}); }
  static void TearDownTestSuite() { StopShared(); }

  json Relocalization() { return GetJson(http(), "/api/v1/status")["slam"]["relocalization"]; }
};

TEST_F(LocalizationSlamd, PoseRequestsAreValidatedAndChangeNothingWhenWrong) {
  Expect422At(http().PostJson("/api/v1/pose", "{}"), {"/x", "/y", "/theta_deg"});
  Expect422At(http().PostJson("/api/v1/pose", R"({"x": "1", "y": 0, "theta_deg": 0})"), {"/x"});
  Expect422At(http().PostJson("/api/v1/pose", R"({"x": 0, "y": 0, "theta_deg": 0, "z": 1})"),
              {"/z"});
  Expect422At(http().PostJson("/api/v1/pose", R"({"x": 1e9, "y": 0, "theta_deg": 0})"), {""});
  Expect422At(http().PostJson("/api/v1/pose", R"({"x": 0, "y": 0, "theta_deg": 0, "sigma_m": -1})"),
              {"/sigma_m"});
  Expect422At(
      http().PostJson("/api/v1/pose", R"({"x": 0, "y": 0, "theta_deg": 0, "sigma_deg": 181})"),
      {"/sigma_deg"});
  ExpectProblem(http().PostJson("/api/v1/pose", "[1, 2]"), 422);
  ExpectProblem(http().Send("POST", "/api/v1/pose", "x=1", "text/plain"), 415);
  EXPECT_EQ(Relocalization()["poses_set"], 0);
}

TEST_F(LocalizationSlamd, APoseGivenIsTakenAndTrackedFrom) {
  WaitForTrajectory(http(), 10);
  const Reply set = http().PostJson("/api/v1/pose", R"({"x": 0.3, "y": -0.2, "theta_deg": 45})");
  ASSERT_EQ(set.status, 202) << set;
  EXPECT_EQ(set.Json()["mode"], "set");
  const auto deadline = After(10.0);
  while (Relocalization()["poses_set"] != 1 && Clock::now() < deadline) Nap();
  ASSERT_EQ(Relocalization()["poses_set"], 1);
  // The next scans start there: a scan end within one scan's driving of it, its heading within
  // a scan's turning (the robot turns in place at up to 1 rad/s; the browser test compares
  // with the ground truth's motion since). Before, the robot was 0.6 m away.
  const size_t before = GetJson(http(), "/api/v1/trajectory")["slam"].size();
  const json trajectory = WaitForTrajectory(http(), before + 3);
  bool near = false;
  for (const json& p : trajectory["slam"]) {
    const double dx = p[1].get<double>() - 0.3, dy = p[2].get<double>() + 0.2;
    const double dtheta = std::remainder(p[3].get<double>() - M_PI / 4, 2 * M_PI);
    near = near || (std::hypot(dx, dy) < 0.15 && std::abs(dtheta) < 1.0);
  }
  EXPECT_TRUE(near) << trajectory["slam"].dump();
  EXPECT_EQ(Metric(GetMetrics(http()), "slamd_poses_set_total"), 1.0);
}

TEST_F(LocalizationSlamd, ARelocalisationRequestedMapsNothingPaysFromTheQuotaAndAPoseEndsIt) {
  WaitForTrajectory(http(), 30, 30.0);  // a map to search in
  const Reply asked = http().PostJson("/api/v1/relocalize", "{}");
  ASSERT_EQ(asked.status, 202) << asked;
  const auto status = [&] { return GetJson(http(), "/api/v1/status")["slam"]; };
  json first = status();
  const auto deadline = After(10.0);
  while (first["relocalization"]["scans"].get<int>() < 1 && Clock::now() < deadline) {
    Nap();
    first = status();
  }
  ASSERT_GE(first["relocalization"]["scans"].get<int>(), 1) << first.dump();
  json later = first;
  const auto three_more = After(10.0);
  while (later["relocalization"]["scans"].get<int>() <
             first["relocalization"]["scans"].get<int>() + 3 &&
         Clock::now() < three_more) {
    Nap();
    later = status();
  }
  const json& r = later["relocalization"];
  EXPECT_GT(r["lookups"].get<int64_t>(), 0);
  EXPECT_LE(r["lookups"].get<int64_t>(), r["scans"].get<int64_t>() * 16250 * 32);
  if (r["relocalizations"] == 0) {
    // Still searching: nothing was mapped meanwhile.
    EXPECT_EQ(later["state"], "relocalizing");
    EXPECT_TRUE(r["state"]["active"].get<bool>());
    EXPECT_EQ(r["state"]["cause"], "request");
    EXPECT_EQ(later["map_version"], first["map_version"]);
    EXPECT_EQ(Metric(GetMetrics(http()), "slamd_relocalizing"), 1.0);
    ASSERT_EQ(http().PostJson("/api/v1/pose", R"({"x": 0, "y": 0, "theta_deg": 0})").status, 202);
  } else {  // found within the scans above
    ASSERT_TRUE(r["state"]["last"].is_object()) << r.dump();
    EXPECT_EQ(r["state"]["last"]["cause"], "request");
    EXPECT_GE(r["state"]["last"]["score"].get<double>(), 0.8);
  }
  // Mapping goes on.
  const auto running = After(10.0);
  while (status()["state"] != "running" && Clock::now() < running) Nap();
  EXPECT_EQ(status()["state"], "running");
  // No search under way: no places where the robot may be.
  const json done = status()["relocalization"]["state"];
  EXPECT_EQ(done["places"], json::array()) << done.dump();
  EXPECT_TRUE(done["places_t"].is_null()) << done.dump();
  const size_t before = GetJson(http(), "/api/v1/trajectory")["slam"].size();
  WaitForTrajectory(http(), before + 2);
  const auto samples = GetMetrics(http());
  EXPECT_EQ(Metric(samples, "slamd_relocalizing"), 0.0);
  EXPECT_GT(Metric(samples, "slamd_relocalizing_scans_total").value_or(0.0), 0.0);
  EXPECT_GT(Metric(samples, "slamd_relocalization_lookups_total").value_or(0.0), 0.0);
}

TEST_F(LocalizationSlamd, TheVirtualMarxbotIsKidnappedOnRequestAndRefusesAWall) {
  WaitForTrajectory(http(), 5);
  const Reply wall = http().PostJson("/api/v1/sim/kidnap", R"({"x": 50, "y": 50, "theta_deg": 0})");
  ExpectProblem(wall, 422);
  const Reply lifted = http().PostJson("/api/v1/sim/kidnap", "{}");
  ASSERT_EQ(lifted.status, 202) << lifted;
  EXPECT_EQ(lifted.Json()["frame"], "world");
  EXPECT_TRUE(lifted.Json()["x"].is_number());
}

TEST(SlamdProcessTest, NothingMappedNothingToRelocaliseInAndNoRobotToKidnap) {
  SlamdProcess slamd;
  std::string error;
  // A UDP source nobody sends to: no scan ever comes.
  ASSERT_TRUE(slamd.Start({"--source", "udp:" + std::to_string(FreeTcpPort())}, &error)) << error;
  Http http(slamd.host(), slamd.port());
  ExpectProblem(http.PostJson("/api/v1/relocalize", "{}"), 409);
  ExpectProblem(http.PostJson("/api/v1/sim/kidnap", "{}"), 409);
  // A pose on an empty map is taken as it is, even as a hint.
  EXPECT_EQ(
      http.PostJson("/api/v1/pose", R"({"x": 1, "y": 2, "theta_deg": 90, "sigma_m": 0.1})").status,
      202);
}

TEST(SlamdProcessTest, ABadPoseFlagExits2AndOneWithoutASavedMapIsIgnored) {
  for (const std::string bad : {"1,2", "a,b,c", "1,2,3,4", "1e9,0,0", "nan,0,0", "0,0,inf"}) {
    SlamdProcess slamd;
    std::string error;
    ASSERT_TRUE(slamd.Spawn({"--pose", bad}, &error)) << error;
    const auto code = slamd.WaitExit(10.0);
    ASSERT_TRUE(code.has_value()) << bad;
    EXPECT_EQ(*code, 2) << bad << ": " << slamd.Stderr();
    EXPECT_NE(slamd.Stderr().find("--pose"), std::string::npos) << slamd.Stderr();
  }
  SlamdProcess slamd;
  std::string error;
  ASSERT_TRUE(slamd.Start({"--pose", "0.5,0,90"}, &error)) << error;
  EXPECT_NE(slamd.Stderr().find("--pose ignored"), std::string::npos) << slamd.Stderr();
}

TEST(SlamdStateDirTest, LocalisingOnASavedMapNeverChangesItOrTheStateDirectory) {
  ScratchDir state("localize");
  {
    SlamdProcess mapper;
    std::string error;
    ASSERT_TRUE(mapper.Start({"--state-dir", state.path().string(), "--budget", "8000"}, &error))
        << error;
    Http http(mapper.host(), mapper.port());
    WaitForTrajectory(http, 20);
    ASSERT_EQ(mapper.Stop(), 0);  // saves at exit
  }
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::directory_iterator(state.path())) {
    if (entry.path().filename() != "slamd.lock") {
      files[entry.path().filename().string()] = ReadFile(entry.path());
    }
  }
  ASSERT_TRUE(files.count("map.pgm"));
  SlamdProcess slamd;
  std::string error;
  ASSERT_TRUE(slamd.Start(
      {"--state-dir", state.path().string(), "--budget", "8000", "--localize", "--pose", "0,0,0"},
      &error))
      << error;
  Http http(slamd.host(), slamd.port());
  const int64_t version = MapVersion(http);
  const json status = GetJson(http, "/api/v1/status");
  EXPECT_TRUE(status["features"]["localize"].get<bool>());
  EXPECT_FALSE(status["features"]["save"].get<bool>());
  const size_t before = GetJson(http, "/api/v1/trajectory")["slam"].size();
  WaitForTrajectory(http, before + 10);  // tracking
  EXPECT_EQ(MapVersion(http), version);
  const Reply pgm = http.Get("/api/v1/map.pgm");
  ASSERT_EQ(pgm.status, 200);
  EXPECT_EQ(pgm.body, files["map.pgm"]) << "the map served is the map saved, byte for byte";
  ExpectProblem(http.PostJson("/api/v1/map/save", "{}"), 409);
  ExpectProblem(http.PostJson("/api/v1/reset", "{}"), 409);
  EXPECT_EQ(http.PostJson("/api/v1/relocalize", "{}").status, 202);
  ASSERT_EQ(slamd.Stop(), 0);
  for (const auto& [name, text] : files) {
    EXPECT_EQ(ReadFile(state.path() / name), text) << name << " changed";
  }
  // The same map as a ROS map.yaml: localised on the same way.
  {
    SlamdProcess on_yaml;
    ASSERT_TRUE(on_yaml.Start({"--localize", "--map", (state.path() / "map.yaml").string(),
                               "--pose", "0,0,0", "--budget", "8000"},
                              &error))
        << error;
    Http yaml_http(on_yaml.host(), on_yaml.port());
    EXPECT_GT(GetJson(yaml_http, "/api/v1/map")["tiles"].size(), 0u);
    const int64_t yaml_version = MapVersion(yaml_http);
    const size_t first = GetJson(yaml_http, "/api/v1/trajectory")["slam"].size();
    WaitForTrajectory(yaml_http, first + 5);
    EXPECT_EQ(MapVersion(yaml_http), yaml_version);
    EXPECT_EQ(on_yaml.Stop(), 0);
  }
  WriteFile(state.path() / "bad.yaml", "image: missing.pgm\nresolution: 0.05\n");
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"--map", (state.path() / "map.yaml").string()},
        std::vector<std::string>{"--localize", "--map", (state.path() / "bad.yaml").string()},
        std::vector<std::string>{"--localize", "--map", (state.path() / "map.yaml").string(),
                                 "--state-dir", state.path().string()}}) {
    SlamdProcess refused;
    ASSERT_TRUE(refused.Spawn(args, &error)) << error;
    EXPECT_EQ(refused.WaitExit(10.0), 2) << refused.Stderr();
  }
  // Without a map there is nothing to localise on.
  ScratchDir empty("localize-empty");
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"--localize"},
        std::vector<std::string>{"--localize", "--state-dir", empty.path().string()}}) {
    SlamdProcess refused;
    ASSERT_TRUE(refused.Spawn(args, &error)) << error;
    EXPECT_EQ(refused.WaitExit(10.0), 2) << refused.Stderr();
    EXPECT_NE(refused.Stderr().find("--localize"), std::string::npos) << refused.Stderr();
  }
}

}  // namespace
}  // namespace slamd_test
