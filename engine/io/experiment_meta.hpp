#pragma once
// meta.json of a recorded experiment (docs/design.md section 5): {"name", "world", "duration_s",
// "source": "sim"|"robot", "seed"}. Only "name" is required. Unlike robot.json and parameters,
// unknown keys are allowed: meta.json is a record that recorders may extend, not configuration.

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "engine/result.hpp"

namespace slam::io {

struct ExperimentMeta {
  std::string name;
  std::string world;
  std::optional<double> duration_s;
  std::string source;  // "sim", "robot", or empty when not given
  std::optional<uint64_t> seed;
};

/// Reads meta.json from parsed JSON; wrong types and an unknown "source" are errors.
Result<ExperimentMeta> ExperimentMetaFromJson(const nlohmann::json& json);

/// Reads a meta.json file; errors name the path and the line.
Result<ExperimentMeta> LoadExperimentMeta(const std::string& path);

}  // namespace slam::io
