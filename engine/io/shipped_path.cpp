#include "engine/io/shipped_path.hpp"

#include <filesystem>
#include <system_error>

// Both come from engine/io/CMakeLists.txt: the data folder relative to the installed programs'
// folder (GNUInstallDirs: "../share/slamd"), and the source tree.
#if !defined(SLAM_DATA_DIR_FROM_BIN) || !defined(SLAM_SOURCE_DIR)
#error "SLAM_DATA_DIR_FROM_BIN and SLAM_SOURCE_DIR are defined by engine/io/CMakeLists.txt"
#endif

namespace slam::io {

std::string ShippedPath(const std::string& relative) {
  namespace fs = std::filesystem;
  std::error_code error;
  // The program itself, symbolic links resolved (Linux).
  const fs::path program = fs::read_symlink("/proc/self/exe", error);
  if (!error) {
    const fs::path installed =
        (program.parent_path() / SLAM_DATA_DIR_FROM_BIN / relative).lexically_normal();
    if (fs::exists(installed, error)) return installed.string();
  }
  return (fs::path(SLAM_SOURCE_DIR) / relative).string();
}

}  // namespace slam::io
