#include "engine/io/atomic_file.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>

namespace slam::io {
namespace {

std::string ErrnoText(const std::string& what, const std::string& path) {
  return what + " " + path + ": " + std::strerror(errno);
}

// Writes all of `text` to `fd`.
bool WriteAll(int fd, const std::string& text) {
  const char* data = text.data();
  std::size_t left = text.size();
  while (left > 0) {
    const ssize_t written = ::write(fd, data, left);
    if (written < 0) {
      if (errno == EINTR) continue;
      return false;
    }
    data += written;
    left -= static_cast<std::size_t>(written);
  }
  return true;
}

}  // namespace

Result<void> WriteFileAtomic(const std::string& path, const std::string& text) {
  static std::atomic<unsigned> counter{0};
  const std::string temp =
      path + ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter.fetch_add(1));
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) return Error(ErrnoText("cannot create", temp));
  if (!WriteAll(fd, text) || ::fsync(fd) != 0) {
    std::string error = ErrnoText("cannot write", temp);
    ::close(fd);
    ::unlink(temp.c_str());
    return Error(error);
  }
  if (::close(fd) != 0) {
    std::string error = ErrnoText("cannot write", temp);
    ::unlink(temp.c_str());
    return Error(error);
  }
  if (std::rename(temp.c_str(), path.c_str()) != 0) {
    std::string error = ErrnoText("cannot rename " + temp + " to", path);
    ::unlink(temp.c_str());
    return Error(error);
  }
  // Make the rename itself durable (best effort).
  std::string directory = std::filesystem::path(path).parent_path().string();
  if (directory.empty()) directory = ".";
  const int dir_fd = ::open(directory.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir_fd >= 0) {
    ::fsync(dir_fd);
    ::close(dir_fd);
  }
  return {};
}

}  // namespace slam::io
