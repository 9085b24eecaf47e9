#include "engine/io/experiment_meta.hpp"

#include "engine/io/json_reader.hpp"

namespace slam::io {

Result<ExperimentMeta> ExperimentMetaFromJson(const nlohmann::json& json) {
  ConfigErrors errors;
  ExperimentMeta meta;
  detail::ObjectReader object(json, "", errors);  // no Finish(): unknown keys are allowed
  object.Read("name", meta.name, true);
  object.Read("world", meta.world, false);
  object.Read("source", meta.source, false);
  if (!meta.source.empty() && meta.source != "sim" && meta.source != "robot") {
    errors.push_back({"/source", "expected \"sim\" or \"robot\", got \"" + meta.source + "\""});
  }
  if (const detail::Json* duration = object.Get("duration_s", false)) {
    double value = 0.0;
    if (detail::ReadNumber(*duration, "/duration_s", value, errors)) meta.duration_s = value;
  }
  if (const detail::Json* seed = object.Get("seed", false)) {
    if (seed->is_number_unsigned()) {
      meta.seed = seed->get<uint64_t>();
    } else {
      errors.push_back(detail::WrongType("/seed", "a non-negative integer", *seed));
    }
  }
  if (!errors.empty()) return errors;
  return meta;
}

Result<ExperimentMeta> LoadExperimentMeta(const std::string& path) {
  return detail::LoadJsonFile<ExperimentMeta>(path, ExperimentMetaFromJson);
}

}  // namespace slam::io
