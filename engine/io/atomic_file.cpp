#include "engine/io/atomic_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
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

/// What a file that is not a regular file is, for messages.
std::string KindOf(mode_t mode) {
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISSOCK(mode)) return "a socket";
  if (S_ISLNK(mode)) return "a symbolic link";
  return "not a regular file";
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

Result<std::string> ReadRegularFile(const std::string& path, uint64_t max_bytes) {
  // O_NOFOLLOW: a link planted in place of the file is refused, not read through (a link to
  // /dev/zero would be read until memory runs out). O_NONBLOCK: opening a FIFO does not wait
  // for a writer; fstat then refuses it.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_NOCTTY | O_CLOEXEC);
  if (fd < 0) {
    if (errno == ELOOP) return Error(path + ": is a symbolic link (not followed)");
    return Error(ErrnoText("cannot open", path));
  }
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    std::string error = ErrnoText("cannot stat", path);
    ::close(fd);
    return Error(error);
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    return Error(path + ": is " + KindOf(st.st_mode) + ", not a regular file");
  }
  if (static_cast<uint64_t>(st.st_size) > max_bytes) {
    ::close(fd);
    return Error(path + ": " + std::to_string(st.st_size) + " bytes, more than the " +
                 std::to_string(max_bytes) + " such a file can hold");
  }
  // st_size bytes, then one more read to see that the file ended there: files here are replaced
  // by rename, never written in place, so one still growing is not what was sized.
  std::string text(static_cast<size_t>(st.st_size), '\0');
  size_t filled = 0;
  char extra = 0;
  while (true) {
    char* into = filled < text.size() ? text.data() + filled : &extra;
    const size_t want = filled < text.size() ? text.size() - filled : 1;
    const ssize_t n = ::read(fd, into, want);
    if (n < 0) {
      if (errno == EINTR) continue;
      std::string error = ErrnoText("cannot read", path);
      ::close(fd);
      return Error(error);
    }
    if (n == 0) break;
    if (into == &extra) {
      ::close(fd);
      return Error(path + ": grew while being read");
    }
    filled += static_cast<size_t>(n);
  }
  ::close(fd);
  text.resize(filled);  // shorter when it shrank meanwhile: the parser judges what is there
  return text;
}

Result<void> MakeRealDirectory(const std::string& path) {
  if (::mkdir(path.c_str(), 0755) != 0 && errno != EEXIST) {
    return Error(ErrnoText("cannot create", path));
  }
  // lstat, not stat: a link to a directory elsewhere would have what is written "into" this one
  // land there.
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0) return Error(ErrnoText("cannot stat", path));
  if (S_ISLNK(st.st_mode)) return Error(path + ": is a symbolic link (not followed)");
  if (!S_ISDIR(st.st_mode)) {
    return Error(path + ": is " + KindOf(st.st_mode) + ", not a directory");
  }
  return {};
}

}  // namespace slam::io
