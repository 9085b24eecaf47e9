#pragma once
// The link's and the scan assembler's counters as JSON, as slam-link prints them, slamd's
// /api/v1/status serves them (docs/http-api.md) and slam-replay reports a log's.

#include <nlohmann/json.hpp>

#include "engine/scan_assembler.hpp"
#include "hw_link/link.hpp"

namespace slam::hw {

/// state, source, last_error, source_errors, frames, frames_rejected, events_queued,
/// queue_drops, queue_size, reassembly{...}, decoder{...}, source_counters{...}.
nlohmann::json LinkStatusToJson(const LinkStatus& status);

/// Every counter of Aseba reassembly, by name.
nlohmann::json ReassemblyCountersToJson(const ReassemblyCounters& counters);

/// Every counter of the event decoder, by name.
nlohmann::json DecoderCountersToJson(const DecoderCounters& counters);

/// Every counter of the scan assembler, by name.
nlohmann::json AssemblerCountersToJson(const ScanAssemblerCounters& counters);

}  // namespace slam::hw
