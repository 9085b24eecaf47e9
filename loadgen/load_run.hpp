#pragma once
// A whole load run against slamd (docs/design.md section 7; the results in RELIABILITY.md):
// viewers first, then the REST mix at a fixed rate for the duration, with /metrics and the status
// read before and after (scans, late scans, link queue drops, missed scans) and the RSS of a
// process sampled every second.

#include <nlohmann/json.hpp>
#include <ostream>
#include <string>

#include "engine/result.hpp"
#include "loadgen/measures.hpp"

namespace slam::loadgen {

struct LoadOptions {
  std::string url;  // as given, for the report
  Target target;    // ParseUrl(url)
  int viewers = 8;
  double rate_hz = 500;  // REST requests per second; 0 for viewers only
  double duration_s = 60;
  int connections = 4;  // keep-alive connections for the REST requests
  std::string token;    // bearer token for the PATCHes; empty for none
  int pid = 0;          // slamd's process id for the RSS samples; 0 for none
  /// slamd's Foxglove WebSocket server, and how many Foxglove clients subscribe to everything.
  Target foxglove;
  int foxglove_clients = 0;
};

/// Runs the load and returns its report (the JSON of `slamd-load --json`), or why it could not
/// start or finish: slamd unreachable, its budget or /metrics unreadable, /proc/PID unreadable.
Result<nlohmann::json> RunLoad(const LoadOptions& options);

/// The report as a table for people.
void PrintTable(const nlohmann::json& report, std::ostream& out);

}  // namespace slam::loadgen
