// slam-link: listens to the robot through any source and shows what the link and the scan
// assembler make of it -- the first thing to run when connecting a real robot.
//   slam-link --source slcan:/dev/ttyACM0            one status line per second
//   slam-link --source candump:run/can.log --events  every decoded event, then the counters

#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "engine/io/robot_json.hpp"
#include "engine/io/shipped_path.hpp"
#include "engine/scan_assembler.hpp"
#include "hw_link/frame_decoder.hpp"
#include "hw_link/link.hpp"
#include "hw_link/status_json.hpp"
#include "server/source_spec.hpp"
#include "sim/world.hpp"
#include "tools/command_line.hpp"

namespace {

std::atomic<bool> g_interrupted{false};

void OnSignal(int) { g_interrupted = true; }

nlohmann::json StatusJson(const slam::hw::LinkStatus& s, const slam::ScanAssemblerCounters& a) {
  nlohmann::json j = slam::hw::LinkStatusToJson(s);
  j["scans"] = slam::hw::AssemblerCountersToJson(a);
  return j;
}

void PrintEvent(const slam::RobotEvent& event) {
  if (const auto* o = std::get_if<slam::OdometryReading>(&event)) {
    std::printf("%.6f odometry seq=%u left=%d right=%d gyro=%d\n", o->t, o->seq, o->left_ticks,
                o->right_ticks, o->gyro_raw);
  } else {
    const auto& s = std::get<slam::ScannerReading>(event);
    std::printf("%.6f scanner seq=%u angle=%u raw=%u,%u,%u,%u rectifier_mv=%u\n", s.t, s.seq,
                s.angle_raw, s.raw[0], s.raw[1], s.raw[2], s.raw[3], s.rectifier_mv);
  }
}

/// Decodes a recorded source to its end on this thread, losing nothing (the link thread would
/// drop events that arrive faster than they are consumed, as it must on live data); prints the
/// counters. The exit status.
int DecodeAsFast(slam::hw::FrameSource& source, const slam::RobotDescription& robot, bool events) {
  slam::hw::FrameDecoder decoder(robot);
  slam::ScanAssembler assembler(robot);
  std::vector<slam::Scan> scans;
  const slam::Result<void> decoded =
      slam::hw::DecodeToEnd(source, decoder, [&](const slam::RobotEvent& e) {
        if (events) PrintEvent(e);
        scans.clear();
        assembler.Add(e, scans);
      });
  slam::hw::LinkStatus status;
  status.state = decoded.ok() ? slam::hw::LinkState::kEnded : slam::hw::LinkState::kSourceError;
  status.source = source.Describe();
  status.last_error = decoded.ok() ? "" : decoded.Message();
  status.frames = decoder.frames();
  status.reassembly = decoder.reassembly();
  status.decoder = decoder.decoder();
  status.source_counters = source.Counters();
  std::fflush(stdout);
  std::cout << StatusJson(status, assembler.counters()).dump(2) << "\n";
  return decoded.ok() ? 0 : 1;
}

/// The status line of the last second.
void ReportSecond(const slam::hw::LinkStatus& s, const slam::ScanAssemblerCounters& c,
                  uint64_t last_frames) {
  std::fprintf(stderr,
               "[slam-link] %s %s: %llu frames/s, %llu odometry, %llu samples, %llu scans; "
               "rejected %llu frames, %llu messages; %llu queue drops%s%s\n",
               s.source.c_str(), slam::hw::ToString(s.state),
               static_cast<unsigned long long>(s.frames - last_frames),
               static_cast<unsigned long long>(c.odometry),
               static_cast<unsigned long long>(c.samples), static_cast<unsigned long long>(c.scans),
               static_cast<unsigned long long>(s.reassembly.Rejected()),
               static_cast<unsigned long long>(s.decoder.Rejected()),
               static_cast<unsigned long long>(s.queue_drops),
               s.last_error.empty() ? "" : "; last error: ", s.last_error.c_str());
}

/// Listens through the link thread until the source ends, --seconds pass or a signal, with a
/// status line every second; prints the counters. The exit status.
int Listen(std::unique_ptr<slam::hw::FrameSource> source, const slam::RobotDescription& robot,
           double seconds, bool events) {
  slam::hw::Link link(std::move(source), robot);
  slam::ScanAssembler assembler(robot);
  std::vector<slam::Scan> scans;
  const auto consume = [&](const slam::hw::LinkEvent& event) {
    if (events) PrintEvent(event.event);
    scans.clear();
    assembler.Add(event.event, scans);
  };
  link.Start();
  const auto start = std::chrono::steady_clock::now();
  auto next_report = start + std::chrono::seconds(1);
  uint64_t last_frames = 0;
  slam::hw::LinkEvent event;
  while (!g_interrupted && !link.Drained()) {
    const auto now = std::chrono::steady_clock::now();
    if (seconds > 0.0 && std::chrono::duration<double>(now - start).count() >= seconds) break;
    if (link.PopWait(event, std::chrono::milliseconds(20))) consume(event);
    if (now >= next_report) {
      const slam::hw::LinkStatus s = link.Status();
      ReportSecond(s, assembler.counters(), last_frames);
      last_frames = s.frames;
      next_report += std::chrono::seconds(1);
    }
  }
  link.Stop();
  while (link.Pop(event)) consume(event);
  std::fflush(stdout);
  std::cout << StatusJson(link.Status(), assembler.counters()).dump(2) << "\n";
  return 0;
}

/// slam-link's command line, as parsed.
struct LinkConfig {
  std::string spec;
  std::string robot_path = slam::io::ShippedPath("config/marxbot.robot.json");
  double seconds = 0.0;
  bool events = false;
  bool as_fast = false;
};

void AddOptions(CLI::App& app, LinkConfig& c) {
  app.add_option("--source", c.spec,
                 "sim:WORLD (a built-in world: " + slam::sim::BuiltinWorldList() +
                     "; or a world.json), candump:FILE, slcan:DEVICE, "
                     "udp:[ADDRESS:]PORT[,from=SENDER] (loopback unless ADDRESS is given) or "
                     "socketcan:IFACE")
      ->required();
  app.add_option("--robot", c.robot_path, "robot description")->capture_default_str();
  app.add_option("--seconds", c.seconds, "stop after this many seconds (0: never)")
      ->check(CLI::Range(0.0, 1e9));
  app.add_flag("--events", c.events, "print every decoded event on stdout");
  app.add_flag("--as-fast", c.as_fast,
               "sim and candump: decode as fast as possible on one thread, losing nothing, "
               "instead of paced through the link thread (needs a source that ends: a log, or "
               "sim with --seconds)");
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Listens to the robot through a source and reports what the link decodes: frames, Aseba "
      "messages, robot events, every rejection, and the scans they assemble into. Ends when the "
      "source ends, after --seconds, or on Ctrl-C, printing all counters as JSON on stdout."};
  LinkConfig config;
  AddOptions(app, config);
  app.set_version_flag("--version", std::string("slam-link ") + SLAM_VERSION);
  if (const std::optional<int> exit_code = slam::cli::Parse(app, argc, argv)) return *exit_code;

  const auto robot = slam::io::LoadRobot(config.robot_path);
  if (!robot.ok()) {
    std::cerr << "slam-link: " << robot.Message() << "\n";
    return 1;
  }
  slam::server::SourceSpecOptions options;
  options.paced = !config.as_fast;
  if (config.as_fast) {
    if (config.spec.rfind("sim:", 0) == 0 && config.seconds <= 0.0) {
      std::cerr << "slam-link: --as-fast with a sim source needs --seconds (simulated time)\n";
      return 2;
    }
    options.duration_s = config.seconds;
  }
  auto opened = slam::server::OpenSourceSpec(config.spec, robot.value(), options);
  if (!opened.ok()) {
    std::cerr << "slam-link: " << opened.Message() << "\n";
    return 1;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  auto source = std::move(opened).value();
  if (config.as_fast) return DecodeAsFast(*source, robot.value(), config.events);
  return Listen(std::move(source), robot.value(), config.seconds, config.events);
}
