#pragma once
// robot.json (docs/design.md section 5) <-> RobotDescription. Strict: unknown keys, missing keys
// and wrong types are errors with the JSON pointer of the culprit; the result is validated.

#include <nlohmann/json.hpp>
#include <string>

#include "engine/result.hpp"
#include "engine/robot.hpp"

namespace slam::io {

/// Reads a robot description from parsed JSON and validates it.
Result<RobotDescription> RobotFromJson(const nlohmann::json& json);

/// Reads and validates a robot.json file; errors name the path and, when known, the
/// line (syntax errors also the column).
Result<RobotDescription> LoadRobot(const std::string& path);

/// The robot.json document of a description (every key written, sigma_m included).
nlohmann::json RobotToJson(const RobotDescription& robot);

}  // namespace slam::io
