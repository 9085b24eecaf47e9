#include "engine/io/tum.hpp"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "engine/io/text_fields.hpp"

namespace slam::io {

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

Result<std::vector<TimedPose>> ParseTum(std::string_view text, const std::string& source,
                                        const PositionBound& bound) {
  std::vector<TimedPose> poses;
  LineProblems problems(source);
  ForEachLine(text, [&](size_t line_number, std::string_view line) {
    const auto fields = SplitFields(line);
    if (fields.empty() || fields[0].front() == '#') return;
    if (fields.size() != 8) {
      problems.Add(line_number, "expected 8 fields \"t x y z qx qy qz qw\", found " +
                                    std::to_string(fields.size()));
      return;
    }
    double v[8];
    bool numbers = true;
    for (size_t i = 0; i < 8; ++i) numbers = numbers && ParseFiniteDouble(fields[i], v[i]);
    if (!numbers) {
      problems.Add(line_number, "not a finite number");
      return;
    }
    const auto inside = [&](double m) { return m >= bound.lo_m && m < bound.hi_m; };
    if (!inside(v[1]) || !inside(v[2])) {
      char detail[200];
      std::snprintf(detail, sizeof(detail), "position (%.6g, %.6g) is outside %s (%.6g to %.6g m)",
                    v[1], v[2], bound.name.c_str(), bound.lo_m, bound.hi_m);
      problems.Add(line_number, detail);
      return;
    }
    const double norm = std::sqrt(v[4] * v[4] + v[5] * v[5] + v[6] * v[6] + v[7] * v[7]);
    if (std::abs(norm - 1.0) > 1e-3) {
      problems.Add(line_number, "quaternion is not of unit length");
      return;
    }
    if (!poses.empty() && !(v[0] > poses.back().t)) {
      problems.Add(line_number,
                   "time " + std::string(fields[0]) + " is not after the previous line's");
      return;
    }
    // Planar: the rotation about z (qx, qy are expected to be 0 and are ignored).
    poses.push_back({v[0], Pose2{v[1], v[2], NormalizeAngle(2.0 * std::atan2(v[6], v[7]))}});
  });
  if (!problems.empty()) return Result<std::vector<TimedPose>>(problems.Errors(), source);
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
