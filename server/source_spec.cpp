#include "server/source_spec.hpp"

#include <charconv>
#include <filesystem>
#include <memory>

#include "sim/virtual_marxbot.hpp"
#include "sim/world.hpp"

namespace slam::server {
namespace {

constexpr const char* kForms =
    "sim:WORLD, candump:FILE, slcan:DEVICE, udp:[ADDRESS:]PORT[,from=SENDER] or socketcan:IFACE";

bool ParsePort(const std::string& text, uint16_t& port) {
  unsigned value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size() || value > 65535) return false;
  port = static_cast<uint16_t>(value);
  return true;
}

}  // namespace

hw::OpenResult OpenSourceSpec(const std::string& spec, const RobotDescription& robot,
                              const SourceSpecOptions& options) {
  const size_t colon = spec.find(':');
  if (colon == std::string::npos || colon + 1 == spec.size()) {
    return Error("source '" + spec + "': expected " + kForms);
  }
  const std::string kind = spec.substr(0, colon);
  const std::string value = spec.substr(colon + 1);
  if (kind == "sim") {
    const Result<sim::World> world = sim::ResolveWorld(value);
    if (!world.ok()) {
      std::string error = "source '" + spec + "': ";
      for (const ConfigError& e : world.errors()) error += e.detail + "; ";
      return Error(error.substr(0, error.size() - 2));
    }
    const std::string name =
        sim::BuiltinWorld(value) ? value : std::filesystem::path(value).stem().string();
    sim::ScenarioConfig config = sim::WithOdometryProfile({}, options.odometry);
    config.seed = options.seed;
    config.duration_s = options.duration_s > 0.0 ? options.duration_s : 1.0;
    sim::VirtualMarxbotOptions vm;
    vm.paced = options.paced;
    vm.speed = options.speed;
    vm.duration_s = options.duration_s;
    return std::make_unique<sim::VirtualMarxbotSource>(world.value(), name, robot, config, vm);
  }
  if (kind == "candump") {
    hw::CandumpReplayOptions replay;
    replay.paced = options.paced;
    replay.speed = options.speed;
    return hw::OpenCandumpReplay(value, replay);
  }
  if (kind == "slcan") return hw::OpenSlcan(value);
  if (kind == "socketcan") return hw::OpenSocketCan(value);
  if (kind == "udp") {
    // udp:[ADDRESS:]PORT[,from=SENDER]: loopback unless an address is given.
    std::string address = "127.0.0.1";
    std::string sender;
    std::string port_text = value;
    if (const size_t comma = value.find(','); comma != std::string::npos) {
      const std::string option = value.substr(comma + 1);
      if (option.rfind("from=", 0) != 0 || option.size() == 5) {
        return Error("source '" + spec + "': unknown UDP option '" + option +
                     "' (expected from=SENDER, the one IPv4 address datagrams are taken from)");
      }
      sender = option.substr(5);
      port_text = value.substr(0, comma);
    }
    const std::string where = port_text;
    if (const size_t c = where.rfind(':'); c != std::string::npos) {
      address = where.substr(0, c);
      port_text = where.substr(c + 1);
    }
    uint16_t port = 0;
    if (!ParsePort(port_text, port)) {
      return Error("source '" + spec + "': '" + port_text + "' is not a UDP port (0..65535)");
    }
    return hw::OpenUdp(port, address, sender);
  }
  return Error("source '" + spec + "': unknown kind '" + kind + "'; expected " + kForms);
}

}  // namespace slam::server
