#include "engine/io/tum.hpp"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

namespace slam::io {
namespace {

constexpr int kMaxErrors = 20;  // a garbled file should not produce megabytes of errors

bool ParseDouble(std::string_view field, double& value) {
  const std::string text(field);
  char* end = nullptr;
  value = std::strtod(text.c_str(), &end);
  return end != text.c_str() && *end == '\0' && std::isfinite(value);
}

std::vector<std::string_view> Fields(std::string_view line) {
  std::vector<std::string_view> fields;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t' || line[i] == '\r')) ++i;
    const size_t start = i;
    while (i < line.size() && line[i] != ' ' && line[i] != '\t' && line[i] != '\r') ++i;
    if (i > start) fields.push_back(line.substr(start, i - start));
  }
  return fields;
}

}  // namespace

std::string FormatTum(const std::vector<TimedPose>& trajectory) {
  std::string text;
  char line[160];
  for (const TimedPose& p : trajectory) {
    std::snprintf(line, sizeof(line), "%.6f %.6f %.6f 0 0 0 %.9f %.9f\n", p.t, p.pose.x, p.pose.y,
                  std::sin(p.pose.theta / 2.0), std::cos(p.pose.theta / 2.0));
    text += line;
  }
  return text;
}

Result<std::vector<TimedPose>> ParseTum(std::string_view text, const std::string& source) {
  std::vector<TimedPose> poses;
  ConfigErrors errors;
  const auto fail = [&](size_t line_number, const std::string& detail) {
    if (errors.size() < kMaxErrors) {
      errors.push_back({"", source + ":" + std::to_string(line_number) + ": " + detail});
    }
  };
  size_t line_number = 0;
  size_t pos = 0;
  while (pos < text.size()) {
    const size_t end = std::min(text.find('\n', pos), text.size());
    const std::string_view line = text.substr(pos, end - pos);
    pos = end + 1;
    ++line_number;
    const auto fields = Fields(line);
    if (fields.empty() || fields[0].front() == '#') continue;
    if (fields.size() != 8) {
      fail(line_number,
           "expected 8 fields \"t x y z qx qy qz qw\", found " + std::to_string(fields.size()));
      continue;
    }
    double v[8];
    bool numbers = true;
    for (size_t i = 0; i < 8; ++i) numbers = numbers && ParseDouble(fields[i], v[i]);
    if (!numbers) {
      fail(line_number, "not a finite number");
      continue;
    }
    const double norm = std::sqrt(v[4] * v[4] + v[5] * v[5] + v[6] * v[6] + v[7] * v[7]);
    if (std::abs(norm - 1.0) > 1e-3) {
      fail(line_number, "quaternion is not of unit length");
      continue;
    }
    if (!poses.empty() && !(v[0] > poses.back().t)) {
      fail(line_number, "time " + std::string(fields[0]) + " is not after the previous line's");
      continue;
    }
    // Planar: the rotation about z (qx, qy are expected to be 0 and are ignored).
    poses.push_back({v[0], Pose2{v[1], v[2], NormalizeAngle(2.0 * std::atan2(v[6], v[7]))}});
  }
  if (!errors.empty()) return Result<std::vector<TimedPose>>(std::move(errors), source);
  return poses;
}

Result<std::vector<TimedPose>> LoadTum(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return Result<std::vector<TimedPose>>(ConfigErrors{{"", path + ": cannot be read"}}, path);
  }
  std::ostringstream text;
  text << in.rdbuf();
  return ParseTum(text.str(), path);
}

}  // namespace slam::io
