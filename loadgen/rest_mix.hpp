#pragma once
// The REST side of a load run: requests on an open-loop schedule (request k is due at
// start + k / rate whatever happened before, and its latency counts from that due time, so a slow
// server cannot slow the load down and hide its own queueing). The mix cycles through GET status,
// budget, map, a tile and /metrics, with a PATCH of the budget to its own value every 50th.

#include <atomic>
#include <cstdint>
#include <string>

#include "loadgen/measures.hpp"
#include "loadgen/viewer.hpp"

namespace slam::loadgen {

enum class RequestKind { kStatus, kBudget, kMap, kTile, kMetrics, kPatchBudget };

/// Request k of the mix: a PATCH every 50th, otherwise the five GETs in turn.
RequestKind KindOf(uint64_t k);

struct RestConfig {
  Target target;
  double rate_hz = 500;
  uint64_t total = 0;  // requests due over the run
  Clock::time_point start;
  Clock::time_point end;   // nothing is sent after it: a backlog is left unsent, not drained
  std::string patch_body;  // the budget's own rays_per_scan
  std::string token;       // bearer token for the PATCHes; empty for none
};

/// One keep-alive connection's worker: takes the next request number from `next`, waits for its
/// due time, sends it and records it; returns when all are taken or the time is up. `last_done`
/// is when its last answer came.
void RestWorker(const RestConfig& config, std::atomic<uint64_t>& next, TileBook& tiles,
                Record& record, Clock::time_point& last_done);

}  // namespace slam::loadgen
