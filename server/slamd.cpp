// slamd: the SLAM server on the robot (docs/design.md sections 6-7, docs/http-api.md). The link
// thread reads the robot (or the virtual marXbot), the SLAM thread maps under the ray-budget
// scheduler, and the HTTP server streams the map to the browser page and takes REST control.
//   slamd                                   virtual marXbot in the "rooms" arena, page on :8080
//   slamd --source slcan:/dev/ttyACM0 --state-dir /var/lib/slamd

#include <pthread.h>
#include <signal.h>
#include <string.h>

#include <CLI/CLI.hpp>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "engine/cell_encoding.hpp"
#include "engine/io/map_yaml.hpp"
#include "engine/io/params_json.hpp"
#include "engine/io/robot_json.hpp"
#include "engine/io/shipped_path.hpp"
#include "engine/robot.hpp"
#include "hw_link/link.hpp"
#include "server/foxglove_server.hpp"
#include "server/http_server.hpp"
#include "server/request_guard.hpp"
#include "server/slam_service.hpp"
#include "server/source_spec.hpp"
#include "server/state_store.hpp"
#include "server/tune_jobs.hpp"
#include "sim/virtual_marxbot.hpp"
#include "sim/world.hpp"
#include "tools/command_line.hpp"

#ifndef SLAMD_WEB_ROOT
#define SLAMD_WEB_ROOT ""
#endif

namespace {

namespace fs = std::filesystem;

int Fail(const std::string& message, int code = 2) {
  std::cerr << "slamd: " << message << "\n";
  return code;
}

/// The page installed beside the program, else the source tree's, else where `cmake --install`
/// put it.
std::string DefaultWebRoot() {
  for (const std::string& candidate : {slam::io::ShippedPath("web"), std::string(SLAMD_WEB_ROOT)}) {
    if (!candidate.empty() && fs::exists(fs::path(candidate) / "index.html")) return candidate;
  }
  return {};
}

/// slamd's command line, as parsed.
struct SlamdConfig {
  std::string source = "sim:rooms";
  std::string robot_path = slam::io::ShippedPath("config/marxbot.robot.json");
  std::string params_path;
  std::string bind = "127.0.0.1";
  int port = 8080;
  int foxglove_port = slam::server::FoxgloveOptions{}.port;
  int foxglove_buffer_kb =
      static_cast<int>(slam::server::FoxgloveOptions{}.max_queued_bytes / 1024);
  std::optional<int64_t> budget_rays;  // --budget, when given
  std::optional<double> cpu_share;     // --cpu-share, when given
  std::string policy = "fixed";
  int max_particles = slam::BudgetSettings{}.max_particles;
  std::string state_dir, experiments_dir, token_file, web_root = DefaultWebRoot();
  std::vector<std::string> allowed_hosts;
  double speed = 1.0;
  uint64_t seed = 1;
  std::string odometry = "tracked";
  std::string pose;  // --pose: "X,Y,THETA_DEG" or "saved"; empty: relocalise on a resumed map
  bool localize = false;
  std::string map_path;  // --map: a ROS map.yaml to localise on
  int max_streams = 16;
  bool quiet = false;
};

void AddOptions(CLI::App& app, SlamdConfig& c) {
  app.add_option(
         "--source", c.source,
         "sim:WORLD (a built-in world: " + slam::sim::BuiltinWorldList() +
             "; or a world.json), candump:FILE, slcan:DEVICE, udp:[ADDRESS:]PORT[,from=SENDER] "
             "(loopback unless ADDRESS is given) or socketcan:IFACE")
      ->capture_default_str();
  app.add_option("--robot", c.robot_path, "robot description (robot.json)")->capture_default_str();
  app.add_option("--params", c.params_path,
                 "SLAM parameters (JSON, e.g. a slam-tune params/<budget>.json), whatever the "
                 "budget [the shipped set of the budget, config/params/]");
  app.add_option("--bind", c.bind,
                 "address to listen on; beyond loopback a --token-file is required")
      ->capture_default_str();
  app.add_option("--port", c.port, "TCP port (0: any free port, printed at start)")
      ->check(CLI::Range(0, 65535))
      ->capture_default_str();
  app.add_option("--foxglove-port", c.foxglove_port,
                 "TCP port of the Foxglove WebSocket server (foxglove.websocket.v1) on the "
                 "--bind address, with the same token and host rules as HTTP (0: off)")
      ->check(CLI::Range(0, 65535))
      ->capture_default_str();
  app.add_option("--foxglove-buffer-kb", c.foxglove_buffer_kb,
                 "send buffer of each Foxglove client, KiB: a client that reads more slowly "
                 "loses messages beyond it (counted in /metrics)")
      ->check(CLI::Range(16, 1 << 20))
      ->capture_default_str();
  auto* budget_opt = app.add_option_function<int64_t>(
                            "--budget", [&c](int64_t rays) { c.budget_rays = rays; },
                            "ray budget per scan (default 65000)")
                         ->check(CLI::Range(int64_t{1}, slam::kMaxRaysPerScan));
  auto* share_opt = app.add_option_function<double>(
      "--cpu-share", [&c](double share) { c.cpu_share = share; },
      "budget as a share of one core (0..1] instead of rays per scan");
  budget_opt->excludes(share_opt);
  app.add_option("--policy", c.policy, "fixed or adaptive particle count")->capture_default_str();
  app.add_option("--max-particles", c.max_particles, "cap of the adaptive policy")
      ->capture_default_str();
  app.add_option("--state-dir", c.state_dir,
                 "where map/save writes; the saved map and trajectory are resumed at start");
  app.add_option("--pose", c.pose,
                 "the robot's pose on the resumed map: X,Y,THETA_DEG (metres, degrees, map "
                 "frame) or \"saved\" (the last pose saved: the robot was not moved while slamd "
                 "was off); without it slamd relocalises on the resumed map before mapping");
  app.add_flag("--localize", c.localize,
               "localisation only: track and relocalise on the map of --state-dir, never change "
               "it (no mapping, no saves, no resets)");
  app.add_option("--map", c.map_path,
                 "with --localize: a ROS map_server map (map.yaml and its PGM or PNG image) to "
                 "localise on, instead of --state-dir's");
  app.add_option("--experiments", c.experiments_dir,
                 "recorded experiments with ground truth for tuning jobs");
  app.add_option("--token-file", c.token_file,
                 "file holding the bearer token that mutating routes require");
  app.add_option("--allow-host", c.allowed_hosts,
                 "also answer requests for this Host name (e.g. robot.local, a reverse proxy's); "
                 "only loopback names and IP addresses otherwise (repeatable)");
  app.add_option("--web-root", c.web_root, "folder of the web page")->capture_default_str();
  app.add_option("--speed", c.speed, "sim and candump sources: times real time")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--seed", c.seed, "sim source: the simulation's seed")->capture_default_str();
  app.add_option("--odometry", c.odometry,
                 "sim source: how the odometry errs: tracked (a tracked robot with a MEMS gyro, "
                 "as slam-sim) or gentle (the original arenas' small drift)")
      ->capture_default_str()
      ->check(CLI::IsMember({"tracked", "gentle"}));
  app.add_option("--max-streams", c.max_streams, "concurrent event streams (503 beyond)")
      ->check(CLI::Range(1, 256))
      ->capture_default_str();
  app.add_flag("--quiet", c.quiet, "no periodic status line on stderr");
  app.set_version_flag("--version", std::string("slamd ") + SLAMD_VERSION);
}

/// The robot of --robot: slamd maps the marXbot's infrared scanner only.
slam::Result<slam::RobotDescription> LoadInfraredRobot(const std::string& path) {
  auto robot = slam::io::LoadRobot(path);
  if (!robot.ok()) return robot;
  if (slam::HasRangeScanner(robot.value())) {
    // Every source carries the marXbot's Aseba CAN events, which have no message for a laser's
    // sweep: such a robot would run without a scan ever arriving.
    return slam::Error(
        path +
        ": the scanner is a range sensor (laser, time-of-flight); slamd's sources carry the "
        "marXbot's infrared scanner over CAN only. Map a laser's CARMEN log with "
        "slam-replay LOG.clf or slam-evaluate.");
  }
  return robot;
}

slam::Result<slam::BudgetSettings> BudgetOf(const SlamdConfig& c) {
  slam::BudgetSettings budget;
  if (c.cpu_share) {
    budget.mode = slam::QuotaMode::kCpuShare;
    budget.cpu_share = *c.cpu_share;
  }
  if (c.budget_rays) budget.rays_per_scan = *c.budget_rays;
  const auto parsed_policy = slam::ParseBudgetPolicy(c.policy);
  if (!parsed_policy) {
    return slam::Error("--policy must be fixed or adaptive, not \"" + c.policy + "\"");
  }
  budget.policy = *parsed_policy;
  budget.max_particles = c.max_particles;
  if (const auto errors = slam::Validate(budget); !errors.empty()) {
    return slam::Error("bad budget: " + slam::FormatErrors(errors));
  }
  return budget;
}

/// The token of --token-file, trimmed: at least 16 characters.
slam::Result<std::string> ReadToken(const std::string& path) {
  std::ifstream in(path);
  if (!in) return slam::Error(path + ": cannot read the token file");
  std::stringstream text;
  text << in.rdbuf();
  std::string token = text.str();
  token.erase(token.find_last_not_of(" \t\r\n") + 1);
  token.erase(0, token.find_first_not_of(" \t\r\n"));
  if (token.size() < 16) return slam::Error(path + ": the token must have at least 16 characters");
  return token;
}

slam::Result<slam::server::HttpOptions> HttpOptionsOf(const SlamdConfig& c) {
  slam::server::HttpOptions http;
  http.bind = c.bind;
  for (const std::string& name : c.allowed_hosts) {
    std::string lower;
    for (const char ch : name)
      lower += static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    http.allowed_hosts.push_back(lower);
  }
  http.port = c.port;
  http.web_root = c.web_root;
  http.state_dir = c.state_dir;
  http.max_streams = c.max_streams;
  http.source_spec = c.source;
  if (!c.token_file.empty()) {
    auto token = ReadToken(c.token_file);
    if (!token.ok()) return token.errors();
    http.token = token.value();
  }
  if (!slam::server::IsLoopback(c.bind) && http.token.empty()) {
    return slam::Error("--bind " + c.bind +
                       " exposes slamd beyond this machine: give a --token-file so that only its "
                       "holders can change it");
  }
  return http;
}

/// Prints the periodic status line every 5 s until `done`.
void ReportStatus(const slam::server::SlamService& service, const slam::hw::Link& link,
                  const std::atomic<bool>& done) {
  while (!done) {
    for (int i = 0; i < 50 && !done; ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (done) break;
    const auto c = service.Counters();
    const auto l = link.Status();
    std::fprintf(stderr, "slamd: link %s, %llu frames; %lld scans (%lld late), CPU %.1f %%\n",
                 slam::hw::ToString(l.state), static_cast<unsigned long long>(l.frames),
                 static_cast<long long>(c.scans), static_cast<long long>(c.late_scans),
                 c.robot_s > 0 ? 100.0 * c.cpu_s / c.robot_s : 0.0);
  }
}

slam::server::ServiceOptions ServiceOptionsOf(const SlamdConfig& c,
                                              const slam::RobotDescription& robot,
                                              const slam::ParamsChoice& params,
                                              const slam::BudgetSettings& budget) {
  slam::server::ServiceOptions options;
  options.robot = robot;
  options.params = params;
  options.budget = budget;
  options.config.seed = c.seed;
  options.config.resolution_m = slam::DefaultResolution(robot);
  options.scan_points = c.foxglove_port != 0;  // only Foxglove's /scan shows them
  return options;
}

/// The pose of --pose on the resumed map (none: relocalise); an exit status when it is bad.
std::optional<int> ResumePose(const std::string& text,
                              slam::server::ServiceOptions& service_options) {
  if (text.empty()) return std::nullopt;
  std::optional<slam::Pose2> pose;  // none: "saved"
  if (text != "saved") {
    const std::optional<slam::Pose2> typed = slam::cli::PoseArgument(text);
    if (!typed) {
      return Fail(
          "--pose must be X,Y,THETA_DEG (three finite numbers: metres, metres, degrees) "
          "or \"saved\", not \"" +
          text + "\"");
    }
    slam::server::PoseRequest request;
    request.pose = *typed;
    const slam::ConfigErrors errors =
        slam::server::ValidatePoseRequest(request, service_options.config.resolution_m);
    if (!errors.empty()) return Fail("--pose " + text + ": " + slam::FormatErrors(errors));
    pose = request.pose;
  }
  if (!service_options.resume) {
    std::fprintf(stderr,
                 "slamd: no saved map to resume: --pose ignored, mapping from the origin\n");
    return std::nullopt;
  }
  if (!pose) {
    const auto& saved = service_options.resume->trajectory;
    if (saved.empty()) return Fail("--pose saved: the saved state holds no trajectory");
    pose = saved.back().pose;
  }
  service_options.resume_pose = pose;
  return std::nullopt;
}

/// The frame source of --source, paced at --speed.
slam::hw::OpenResult OpenSource(const SlamdConfig& c, const slam::RobotDescription& robot) {
  slam::server::SourceSpecOptions options;
  options.paced = true;
  options.speed = c.speed;
  options.seed = c.seed;
  options.odometry = *slam::sim::OdometryProfileFromName(c.odometry);
  return slam::server::OpenSourceSpec(c.source, robot, options);
}

/// The Foxglove server's options: HTTP's address, token and host names.
slam::server::FoxgloveOptions FoxgloveOptionsOf(const SlamdConfig& c,
                                                const slam::server::HttpOptions& http) {
  slam::server::FoxgloveOptions fox;
  fox.bind = c.bind;
  fox.port = c.foxglove_port;
  fox.max_queued_bytes = static_cast<size_t>(c.foxglove_buffer_kb) * 1024;
  fox.token = http.token;
  fox.allowed_hosts = http.allowed_hosts;
  return fox;
}

/// Locks --state-dir for this slamd and takes the saved map and pose to resume from, if any;
/// an exit status when the directory is another slamd's or its state cannot be resumed.
std::optional<int> LockAndResume(const std::string& state_dir,
                                 slam::server::ServiceOptions& service_options,
                                 std::optional<slam::server::StateDirLock>& state_lock) {
  if (state_dir.empty()) return std::nullopt;
  auto locked = slam::server::StateDirLock::Acquire(state_dir);
  if (!locked.ok()) return Fail(locked.Message(), 1);
  state_lock.emplace(std::move(locked).value());
  auto loaded = slam::server::LoadState(state_dir);
  if (!loaded.ok()) {
    return Fail("cannot resume the saved state: " + loaded.Message() +
                "\n(move the state directory away to start with an empty map)");
  }
  if (std::optional<slam::server::SavedState>& saved = loaded.value(); saved) {
    if (std::abs(saved->resolution_m - service_options.config.resolution_m) > 1e-12) {
      return Fail(state_dir + ": the saved map's resolution differs from this robot's");
    }
    service_options.resume = std::move(saved);
  }
  return std::nullopt;
}

/// Serves until one of `signals` arrives (a thread waits for it and stops the server), with the
/// status line every 5 s unless `quiet`.
void ServeUntilSignal(sigset_t& signals, slam::server::HttpServer& server,
                      const slam::server::SlamService& service, const slam::hw::Link& link,
                      bool quiet) {
  std::atomic<bool> done{false};
  std::thread signal_thread([&] {
    int received = 0;
    sigwait(&signals, &received);
    if (!done) {
      if (!quiet) std::fprintf(stderr, "slamd: %s: stopping\n", strsignal(received));
      server.Stop();
    }
  });
  std::thread status_thread;
  if (!quiet) status_thread = std::thread([&] { ReportStatus(service, link, done); });

  server.Run();  // until a signal
  done = true;
  pthread_kill(signal_thread.native_handle(), SIGTERM);  // wakes sigwait if no signal came
  signal_thread.join();
  if (status_thread.joinable()) status_thread.join();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"slamd: real-time SLAM server for the marXbot (map in the browser, REST control)"};
  SlamdConfig config;
  AddOptions(app, config);
  if (const std::optional<int> exit_code = slam::cli::Parse(app, argc, argv)) return *exit_code;

  const auto robot = LoadInfraredRobot(config.robot_path);
  if (!robot.ok()) return Fail(robot.Message());
  slam::ParamsChoice params;  // the shipped set of each scan's quota
  if (!config.params_path.empty()) {
    const auto loaded = slam::io::LoadParams(config.params_path);
    if (!loaded.ok()) return Fail(loaded.Message());
    params = slam::ParamsChoice(config.params_path, loaded.value());
  }
  const auto budget = BudgetOf(config);
  if (!budget.ok()) return Fail(budget.Message());
  const auto http_options = HttpOptionsOf(config);
  if (!http_options.ok()) return Fail(http_options.Message());
  const slam::server::HttpOptions& http = http_options.value();

  slam::server::ServiceOptions service_options =
      ServiceOptionsOf(config, robot.value(), params, budget.value());
  const std::string& state_dir = config.state_dir;
  // Held until slamd exits: a second slamd on the same directory would race its saves.
  std::optional<slam::server::StateDirLock> state_lock;
  if (const auto status = LockAndResume(state_dir, service_options, state_lock)) return *status;
  if (!config.map_path.empty()) {
    if (!config.localize) return Fail("--map is a map to localise on: give --localize too");
    if (!state_dir.empty()) return Fail("--map and --state-dir: give one map to localise on");
    const slam::Result<slam::OccupancyGrid> grid = slam::io::LoadMapYaml(
        config.map_path, slam::GridGeometry(service_options.config.resolution_m),
        slam::EncodeLogOdds(service_options.config.logodds_limit));
    if (!grid.ok()) return Fail(grid.Message());
    slam::server::SavedState map;
    map.version = 1;
    map.resolution_m = service_options.config.resolution_m;
    for (const slam::TileRef& t : grid.value().Tiles()) {
      map.tiles.push_back({t.index, 1, {t.tile->cells.begin(), t.tile->cells.end()}});
    }
    if (map.tiles.empty()) return Fail(config.map_path + ": the map has no known cell");
    service_options.resume = std::move(map);
  }
  if (config.localize) {
    if (!service_options.resume) {
      return Fail(config.state_dir.empty()
                      ? "--localize needs a map to localise on: give --state-dir DIR"
                      : "--localize: " + state_dir + " holds no saved map to localise on");
    }
    service_options.localize_only = true;
  }
  if (const auto status = ResumePose(config.pose, service_options)) return *status;

  auto opened = OpenSource(config, robot.value());
  if (!opened.ok()) return Fail(opened.Message(), 1);
  auto frame_source = std::move(opened).value();
  auto* virtual_robot = dynamic_cast<slam::sim::VirtualMarxbotSource*>(frame_source.get());

  // Signals go to one thread that stops the server cleanly; every other thread blocks them.
  // SIGHUP (the terminal went away) and SIGQUIT stop it cleanly too, instead of killing it
  // mid-write; SIGUSR1 and SIGUSR2 mean nothing to slamd and are ignored.
  sigset_t signals;
  sigemptyset(&signals);
  for (const int s : {SIGINT, SIGTERM, SIGHUP, SIGQUIT}) sigaddset(&signals, s);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  ::signal(SIGUSR1, SIG_IGN);
  ::signal(SIGUSR2, SIG_IGN);

  slam::hw::Link link(std::move(frame_source), robot.value());
  slam::server::SlamService service(link, virtual_robot, service_options);
  slam::server::JobManager jobs(config.experiments_dir, state_dir);
  slam::server::HttpServer server(service, link, jobs, http);
  const slam::Result<int> bound_port = server.Bind();
  if (!bound_port.ok()) return Fail(bound_port.Message(), 1);
  const int bound = bound_port.value();
  std::optional<slam::server::FoxgloveServer> foxglove;
  int foxglove_bound = 0;
  if (config.foxglove_port != 0) {
    foxglove.emplace(service, FoxgloveOptionsOf(config, http));
    const slam::Result<int> fox_port = foxglove->Bind();
    if (!fox_port.ok()) return Fail(fox_port.Message(), 1);
    foxglove_bound = fox_port.value();
    server.AddMetrics([&foxglove] { return foxglove->MetricsText(); });
  }

  link.Start();
  service.Start();
  if (foxglove) foxglove->Start();
  const std::string host =
      config.bind.find(':') != std::string::npos ? "[" + config.bind + "]" : config.bind;
  std::printf("slamd: serving http://%s:%d/ (source %s)\n", host.c_str(), bound,
              config.source.c_str());
  if (foxglove)
    std::printf("slamd: Foxglove WebSocket on ws://%s:%d\n", host.c_str(), foxglove_bound);
  std::fflush(stdout);
  const bool quiet = config.quiet;
  if (service_options.resume && !quiet) {
    std::fprintf(stderr, "slamd: %s the map saved in %s (%zu tiles, version %llu)\n",
                 config.localize ? "localising on" : "resumed",
                 config.map_path.empty() ? state_dir.c_str() : config.map_path.c_str(),
                 service_options.resume->tiles.size(),
                 static_cast<unsigned long long>(service_options.resume->version));
    if (!service_options.resume_pose) {
      std::fprintf(stderr,
                   "slamd: relocalising on the resumed map (nothing is mapped until the robot is "
                   "found; --pose gives its pose)\n");
    }
  }

  ServeUntilSignal(signals, server, service, link, quiet);
  if (foxglove) foxglove->Stop();
  service.Stop();
  link.Stop();
  // What was mapped since the last save is kept: a clean stop (systemd's SIGTERM) saves. A
  // localising slamd changed nothing.
  if (!state_dir.empty() && !config.localize) {
    const slam::Result<slam::server::SaveReport> saved = server.SaveMap();
    if (!saved.ok()) {
      std::fprintf(stderr, "slamd: the map was not saved at exit: %s\n", saved.Message().c_str());
      return 1;
    }
    if (!quiet) std::fprintf(stderr, "slamd: saved the map in %s\n", state_dir.c_str());
  }
  return 0;
}
