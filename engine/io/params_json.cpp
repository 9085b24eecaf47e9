#include "engine/io/params_json.hpp"

#include <utility>

#include "engine/io/atomic_file.hpp"
#include "engine/io/json_reader.hpp"

namespace slam::io {
namespace {

using detail::Json;

// The single list of JSON keys: calls visit(key, member) for every parameter.
template <typename Params, typename Visit>
void ForEachParam(Params& params, Visit&& visit) {
  visit("dist_error_ratio", params.dist_error_ratio);
  visit("dist_error_const_m", params.dist_error_const_m);
  visit("angle_error_ratio", params.angle_error_ratio);
  visit("angle_error_const_deg", params.angle_error_const_deg);
  visit("min_pos_uncertainty_m", params.min_pos_uncertainty_m);
  visit("min_angle_uncertainty_deg", params.min_angle_uncertainty_deg);
  visit("resampling_period_scans", params.resampling_period_scans);
  visit("angle_between_scans_deg", params.angle_between_scans_deg);
  visit("particles", params.particles);
}

}  // namespace

Result<SlamParams> ParamsFromJson(const nlohmann::json& json) {
  ConfigErrors errors;
  SlamParams params;
  detail::ObjectReader object(json, "", errors);
  ForEachParam(params, [&](const char* key, auto& member) { object.Read(key, member, false); });
  object.Finish();
  // Members that failed to read keep their (valid) defaults, so range errors can be reported
  // alongside type errors in one answer.
  for (ConfigError& error : Validate(params)) errors.push_back(std::move(error));
  if (!errors.empty()) return errors;
  return params;
}

Result<SlamParams> LoadParams(const std::string& path) {
  return detail::LoadJsonFile<SlamParams>(path, ParamsFromJson);
}

nlohmann::json ParamsToJson(const SlamParams& params) {
  Json json = Json::object();
  ForEachParam(params, [&](const char* key, const auto& member) { json[key] = member; });
  return json;
}

Result<void> SaveParams(const std::string& path, const SlamParams& params) {
  const ConfigErrors errors = Validate(params);
  if (!errors.empty())
    return Error("refusing to write invalid parameters:\n" + FormatErrors(errors));
  return WriteFileAtomic(path, ParamsToJson(params).dump(2) + "\n");
}

Result<SlamParams> ApplyParamsPatch(const SlamParams& base, const nlohmann::json& merge_patch,
                                    const SlamParams& defaults) {
  Json document = ParamsToJson(base);
  document.merge_patch(merge_patch);
  // A member the patch nulled takes its default.
  Json full = ParamsToJson(defaults);
  full.merge_patch(document);
  return ParamsFromJson(full);
}

}  // namespace slam::io
