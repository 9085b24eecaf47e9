#include "hw_link/status_json.hpp"

namespace slam::hw {

nlohmann::json ReassemblyCountersToJson(const ReassemblyCounters& r) {
  return {{"frames", r.frames},
          {"messages", r.messages},
          {"extended", r.extended},
          {"remote", r.remote},
          {"fd", r.fd},
          {"foreign", r.foreign},
          {"bad_length", r.bad_length},
          {"middle_without_start", r.middle_without_start},
          {"stop_without_start", r.stop_without_start},
          {"oversize", r.oversize},
          {"abandoned", r.abandoned}};
}

nlohmann::json DecoderCountersToJson(const DecoderCounters& d) {
  return {{"messages", d.messages},
          {"odometry", d.odometry},
          {"scanner", d.scanner},
          {"unknown_node", d.unknown_node},
          {"unknown_type", d.unknown_type},
          {"bad_size", d.bad_size},
          {"raw_out_of_range", d.raw_out_of_range}};
}

nlohmann::json LinkStatusToJson(const LinkStatus& s) {
  nlohmann::json source = nlohmann::json::object();
  for (const auto& [name, value] : s.source_counters) source[name] = value;
  return {{"state", ToString(s.state)},
          {"source", s.source},
          {"last_error", s.last_error},
          {"source_errors", s.source_errors},
          {"frames", s.frames},
          {"silent", s.Silent()},
          {"seconds_without_frames", s.SecondsWithoutFrames()},
          {"frames_rejected", s.reassembly.Rejected() + s.decoder.Rejected()},
          {"events_queued", s.events_queued},
          {"queue_drops", s.queue_drops},
          {"queue_size", s.queue_size},
          {"reassembly", ReassemblyCountersToJson(s.reassembly)},
          {"decoder", DecoderCountersToJson(s.decoder)},
          {"source_counters", source}};
}

nlohmann::json AssemblerCountersToJson(const ScanAssemblerCounters& a) {
  return {{"scans", a.scans},
          {"samples", a.samples},
          {"samples_in_scans", a.samples_in_scans},
          {"odometry", a.odometry},
          {"out_of_order", a.out_of_order},
          {"samples_lost", a.samples_lost},
          {"odometry_lost", a.odometry_lost},
          {"sample_gaps", a.sample_gaps},
          {"odometry_gaps", a.odometry_gaps},
          {"odometry_jumps", a.odometry_jumps},
          {"samples_unposed", a.samples_unposed},
          {"scans_discarded", a.scans_discarded},
          {"scans_too_long", a.scans_too_long}};
}

}  // namespace slam::hw
