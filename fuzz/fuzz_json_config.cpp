// Fuzzes the readers of JSON configuration: the input is JSON text, read as robot.json, as a
// parameters file and as world.json, with errors located by line (engine/io/json_locate).
// Invariants: nothing crashes; every error the readers give has a line within the text when the
// text is valid JSON; LineOfPointer finds every member of a parsed document, on a line that
// exists.

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "engine/io/json_locate.hpp"
#include "engine/io/params_json.hpp"
#include "engine/io/robot_json.hpp"
#include "fuzz/fuzz_check.hpp"
#include "sim/world.hpp"

using slam::fuzz::Check;

namespace {

/// Pointers to the root's members and their members (enough to exercise every token kind).
void CheckPointers(const nlohmann::json& json, std::string_view text, int lines) {
  const nlohmann::json leaves = json.flatten();
  for (const auto& [pointer, value] : leaves.items()) {
    (void)value;
    // flatten() names leaves; their lines must exist. Duplicate keys, which nlohmann keeps the
    // last of, are located at their last occurrence too.
    const auto line = slam::io::LineOfPointer(text, pointer);
    Check(line.has_value(), "a leaf of a parsed document is not found");
    Check(*line >= 1 && *line <= lines, "a leaf's line is outside the text");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  const int lines = 1 + static_cast<int>(std::count(text.begin(), text.end(), '\n'));

  const nlohmann::json json = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (!json.is_discarded()) {
    // nlohmann stops reading at a NUL byte and ignores what follows; the locator reads to the
    // end and calls such text malformed (no line: the error is still shown, without it).
    if (json.size() < 2000 && text.find('\0') == std::string::npos) {
      CheckPointers(json, text, lines);
    }
    (void)slam::io::RobotFromJson(json);
    (void)slam::io::ParamsFromJson(json);
  }
  // Pointers from the input's own bytes, on the same text: never crash, lines within the text.
  const size_t split = size > 0 ? data[0] % (size + 1) : 0;
  const std::string_view pointer(text.data(), std::min(split, text.size()));
  if (const auto line = slam::io::LineOfPointer(text, pointer)) {
    Check(*line >= 1 && *line <= lines, "LineOfPointer gave a line outside the text");
  }
  if (const auto line = slam::io::LineOfNearestValue(text, pointer)) {
    Check(*line >= 1 && *line <= lines, "LineOfNearestValue gave a line outside the text");
  }
  const slam::Result<slam::sim::World> world = slam::sim::ParseWorld(text, "world.json");
  Check(world.ok() == world.errors().empty(), "a world is either read or explained");
  return 0;
}
