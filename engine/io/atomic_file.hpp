#pragma once
// Writing files so that readers (and a crash) see either the old or the new contents, never a
// partial file.

#include <string>

#include "engine/result.hpp"

namespace slam::io {

/// Writes `text` to `path` through a new temporary file in the same directory, fsync and rename
/// (then fsyncs the directory); on failure nothing was written, and the error says why.
Result<void> WriteFileAtomic(const std::string& path, const std::string& text);

}  // namespace slam::io
