#include "engine/io/params_json.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <utility>

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

// Writes `text` to `path` through a temporary file in the same directory and a rename, so that
// readers see either the old or the new file, never a partial one.
std::optional<std::string> WriteFileAtomically(const std::string& path, const std::string& text) {
  static std::atomic<unsigned> counter{0};
  const std::string temp =
      path + ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter.fetch_add(1));
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) return ErrnoText("cannot create", temp);
  if (!WriteAll(fd, text) || ::fsync(fd) != 0) {
    std::string error = ErrnoText("cannot write", temp);
    ::close(fd);
    ::unlink(temp.c_str());
    return error;
  }
  if (::close(fd) != 0) {
    std::string error = ErrnoText("cannot write", temp);
    ::unlink(temp.c_str());
    return error;
  }
  if (std::rename(temp.c_str(), path.c_str()) != 0) {
    std::string error = ErrnoText("cannot rename " + temp + " to", path);
    ::unlink(temp.c_str());
    return error;
  }
  // Make the rename itself durable (best effort).
  std::string directory = std::filesystem::path(path).parent_path().string();
  if (directory.empty()) directory = ".";
  const int dir_fd = ::open(directory.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir_fd >= 0) {
    ::fsync(dir_fd);
    ::close(dir_fd);
  }
  return std::nullopt;
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
  Result<Json> json = detail::ReadJsonFile(path);
  if (!json.ok()) return {json.errors(), path};
  Result<SlamParams> params = ParamsFromJson(json.value());
  if (!params.ok()) return {params.errors(), path};
  return params;
}

nlohmann::json ParamsToJson(const SlamParams& params) {
  Json json = Json::object();
  ForEachParam(params, [&](const char* key, const auto& member) { json[key] = member; });
  return json;
}

std::optional<std::string> SaveParams(const std::string& path, const SlamParams& params) {
  const ConfigErrors errors = Validate(params);
  if (!errors.empty()) return "refusing to write invalid parameters:\n" + FormatErrors(errors);
  return WriteFileAtomically(path, ParamsToJson(params).dump(2) + "\n");
}

Result<SlamParams> ApplyParamsPatch(const SlamParams& base, const nlohmann::json& merge_patch) {
  Json document = ParamsToJson(base);
  document.merge_patch(merge_patch);
  return ParamsFromJson(document);
}

}  // namespace slam::io
