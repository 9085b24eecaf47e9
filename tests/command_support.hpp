#pragma once
// Running a program as a user would from a shell, for the tests of the command-line tools.

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace slam::testing {

/// A command's exit status (-1 when it did not exit), stdout and stderr.
struct CommandResult {
  int status = -1;
  std::string out;
  std::string err;
};

/// Runs `command` through the shell, its output kept in `scratch` (stdout, stderr).
inline CommandResult RunCommand(const std::string& command, const std::filesystem::path& scratch) {
  const std::filesystem::path out = scratch / "stdout", err = scratch / "stderr";
  const int raw = std::system((command + " >" + out.string() + " 2>" + err.string()).c_str());
  const auto read = [](const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    std::ostringstream text;
    text << in.rdbuf();
    return text.str();
  };
  CommandResult result;
  result.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
  result.out = read(out);
  result.err = read(err);
  return result;
}

}  // namespace slam::testing
