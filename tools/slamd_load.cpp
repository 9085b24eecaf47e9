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
// With --foxglove, Foxglove clients subscribe to every channel of slamd's Foxglove server and
// read every message meanwhile.
//
//   slamd-load --url http://127.0.0.1:8080/ [--viewers 8] [--rate 500] [--duration 60]
//              [--token-file F] [--pid PID] [--foxglove ws://127.0.0.1:8765 [--foxglove-clients 4]]
//              [--json]
//
// The table goes to stdout, or to stderr with --json, which prints one JSON object on stdout.

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cctype>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>

#include "loadgen/load_run.hpp"
#include "tools/command_line.hpp"

namespace {

std::string Trim(std::string text) {
  const auto not_space = [](unsigned char c) { return !std::isspace(c); };
  text.erase(text.begin(), std::find_if(text.begin(), text.end(), not_space));
  text.erase(std::find_if(text.rbegin(), text.rend(), not_space).base(), text.end());
  return text;
}

/// slamd-load's command line, as parsed.
struct LoadConfig {
  std::string url;
  int viewers = 8;
  double rate_hz = 500;
  double duration_s = 60;
  std::string token_file;
  int pid = 0;
  int connections = 4;
  bool as_json = false;
  std::string foxglove_url;  // with foxglove_given
  bool foxglove_given = false;
  int foxglove_clients = 4;
};

void AddOptions(CLI::App& app, LoadConfig& c) {
  app.add_option("--url", c.url, "slamd's base URL, e.g. http://127.0.0.1:8080/")->required();
  app.add_option("--viewers", c.viewers, "event-stream viewers (each fetches announced tiles)")
      ->capture_default_str()
      ->check(CLI::Range(0, 1000));
  app.add_option("--rate", c.rate_hz, "REST requests per second (open loop)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100000.0));
  app.add_option("--duration", c.duration_s, "seconds of load")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 86400.0));
  app.add_option("--token-file", c.token_file, "bearer token for the PATCH requests")
      ->check(CLI::ExistingFile);
  app.add_option("--pid", c.pid, "slamd's process id: its RSS is sampled every second")
      ->check(CLI::PositiveNumber);
  app.add_option("--connections", c.connections, "keep-alive connections for the REST requests")
      ->capture_default_str()
      ->check(CLI::Range(1, 256));
  app.add_option("--foxglove", c.foxglove_url,
                 "slamd's Foxglove WebSocket server, e.g. ws://127.0.0.1:8765: Foxglove "
                 "clients subscribe to every channel and read every message");
  app.add_option("--foxglove-clients", c.foxglove_clients, "Foxglove clients (with --foxglove)")
      ->capture_default_str()
      ->check(CLI::Range(1, 100));
  app.add_flag("--json", c.as_json, "print one JSON object on stdout (the table goes to stderr)");
}

/// The load run the configuration asks for, or why it cannot be run.
slam::Result<slam::loadgen::LoadOptions> ToLoadOptions(const LoadConfig& c) {
  const auto target = slam::loadgen::ParseUrl(c.url);
  if (!target) {
    return slam::Error("--url must look like http://HOST:PORT/, got '" + c.url + "'");
  }
  slam::loadgen::LoadOptions options;
  if (!c.token_file.empty()) {
    std::ifstream in(c.token_file);
    std::stringstream text;
    text << in.rdbuf();
    options.token = Trim(text.str());
    if (options.token.empty()) return slam::Error("the token file " + c.token_file + " is empty");
  }
  if (c.foxglove_given) {
    const auto foxglove = slam::loadgen::ParseUrl(c.foxglove_url, "ws://");
    if (!foxglove) {
      return slam::Error("--foxglove must look like ws://HOST:PORT, got '" + c.foxglove_url + "'");
    }
    options.foxglove = *foxglove;
    options.foxglove_clients = c.foxglove_clients;
  }
  options.url = c.url;
  options.target = *target;
  options.viewers = c.viewers;
  options.rate_hz = c.rate_hz;
  options.duration_s = c.duration_s;
  options.connections = c.connections;
  options.pid = c.pid;
  return options;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"slamd-load: event-stream viewers plus REST requests at a fixed rate against slamd"};
  LoadConfig config;
  AddOptions(app, config);
  app.set_version_flag("--version", std::string("slamd-load ") + SLAM_VERSION);
  if (const std::optional<int> exit_code = slam::cli::Parse(app, argc, argv)) return *exit_code;
  config.foxglove_given = app.count("--foxglove") > 0;

  const auto options = ToLoadOptions(config);
  if (!options.ok()) {
    std::cerr << "slamd-load: " << options.Message() << "\n";
    return 2;
  }
  const auto report = slam::loadgen::RunLoad(options.value());
  if (!report.ok()) {
    std::cerr << "slamd-load: " << report.Message() << "\n";
    return 1;
  }
  slam::loadgen::PrintTable(report.value(), config.as_json ? std::cerr : std::cout);
  if (config.as_json) std::cout << report.value().dump() << std::endl;
  return 0;
}
