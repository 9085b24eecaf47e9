#pragma once
// Writing files so that readers (and a crash) see either the old or the new contents, never a
// partial file.

#include <optional>
#include <string>

namespace slam::io {

/// Writes `text` to `path` through a new temporary file in the same directory, fsync and rename
/// (then fsyncs the directory); nullopt on success, else why nothing was written.
[[nodiscard]] std::optional<std::string> WriteFileAtomic(const std::string& path,
                                                         const std::string& text);

}  // namespace slam::io
