#pragma once
// Reading text files, and whitespace-separated text records (TUM trajectories, benchmark relations,
// CARMEN logs): a line's fields and strict numbers. Locale-independent enough for logs: strtod in
// the "C" locale, which the tools never change.

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "engine/result.hpp"

namespace slam::io {

/// The fields of `line`, separated by spaces, tabs or carriage returns.
inline std::vector<std::string_view> SplitFields(std::string_view line) {
  std::vector<std::string_view> fields;
  size_t i = 0;
  const auto blank = [&](size_t k) { return line[k] == ' ' || line[k] == '\t' || line[k] == '\r'; };
  while (i < line.size()) {
    while (i < line.size() && blank(i)) ++i;
    const size_t start = i;
    while (i < line.size() && !blank(i)) ++i;
    if (i > start) fields.push_back(line.substr(start, i - start));
  }
  return fields;
}

/// True when the whole of `field` is a finite number, written to `value`.
inline bool ParseFiniteDouble(std::string_view field, double& value) {
  char buffer[64];
  if (field.empty() || field.size() >= sizeof(buffer)) return false;
  field.copy(buffer, field.size());
  buffer[field.size()] = '\0';
  char* end = nullptr;
  value = std::strtod(buffer, &end);
  return end == buffer + field.size() && std::isfinite(value);
}

/// Calls `line(number, text)` for each line of `text` (numbered from 1; the last line may lack
/// its newline).
template <typename F>
void ForEachLine(std::string_view text, F&& line) {
  size_t number = 0, pos = 0;
  while (pos < text.size()) {
    const size_t end = std::min(text.find('\n', pos), text.size());
    line(++number, text.substr(pos, end - pos));
    pos = end + 1;
  }
}

/// What is wrong with a text file's lines, as "file:line: detail" messages: the first
/// `kept_at_most` of them (a garbled file should not produce megabytes of messages).
class LineProblems {
 public:
  explicit LineProblems(std::string source, size_t kept_at_most = 20)
      : source_(std::move(source)), kept_at_most_(kept_at_most) {}

  void Add(size_t line_number, std::string_view detail) {
    if (kept_.size() >= kept_at_most_) return;
    kept_.push_back(source_ + ":" + std::to_string(line_number) + ": " + std::string(detail));
  }
  bool empty() const { return kept_.empty(); }
  const std::vector<std::string>& kept() const { return kept_; }
  /// The kept messages as errors (without a JSON pointer).
  ConfigErrors Errors() const {
    ConfigErrors errors;
    for (const std::string& message : kept_) errors.push_back({"", message});
    return errors;
  }

 private:
  std::string source_;
  size_t kept_at_most_;
  std::vector<std::string> kept_;
};

/// The bytes of a file; errors name the path.
inline Result<std::string> ReadTextFile(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    return Result<std::string>(ConfigErrors{{"", path + ": is a directory, not a file"}}, path);
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    const int error = errno;
    return Result<std::string>(
        ConfigErrors{{"", path + ": cannot open (" + std::strerror(error) + ")"}}, path);
  }
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) return Result<std::string>(ConfigErrors{{"", path + ": read error"}}, path);
  return Result<std::string>(text.str());
}

}  // namespace slam::io
