#pragma once
// The real-size built-in worlds, sim/worlds/*.json, compiled into the library so that `sim:flat`
// works wherever slamd runs (sim/CMakeLists.txt embeds them).

#include <string_view>
#include <vector>

namespace slam::sim {

struct WorldFile {
  std::string_view name;  // the file's stem, which is also the world's "name"
  std::string_view json;  // the file's text
};

/// Every sim/worlds/*.json, in the order sim/CMakeLists.txt lists them.
const std::vector<WorldFile>& BuiltinWorldFiles();

}  // namespace slam::sim
