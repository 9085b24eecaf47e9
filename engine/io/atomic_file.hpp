#pragma once
// Files in directories that others may write to (slamd's state directory): written so that
// readers (and a crash) see either the old or the new contents, never a partial file, and read
// or entered without following a symbolic link planted there.

#include <cstdint>
#include <string>

#include "engine/result.hpp"

namespace slam::io {

/// Writes `text` to `path` through a new temporary file in the same directory, fsync and rename
/// (then fsyncs the directory); on failure nothing was written, and the error says why. A
/// symbolic link at `path` is replaced by the file, never written through.
Result<void> WriteFileAtomic(const std::string& path, const std::string& text);

/// The contents of the regular file `path`, opened without following a symbolic link and
/// without blocking on a FIFO; an error naming the file when it is a link, not a regular file,
/// larger than `max_bytes`, or cannot be read.
Result<std::string> ReadRegularFile(const std::string& path, uint64_t max_bytes);

/// Makes sure `path` is a directory, not a symbolic link to one, creating it (mode 0755, its
/// parent must exist) when missing; an error naming it otherwise.
Result<void> MakeRealDirectory(const std::string& path);

}  // namespace slam::io
