#pragma once
// SLAM parameters (paper Table II, docs/design.md section 3) <-> JSON: files, and merge patches
// (RFC 7396) as the HTTP API's PATCH /api/v1/params sends them.

#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "engine/params.hpp"
#include "engine/result.hpp"

namespace slam::io {

/// Reads parameters from a JSON object (every key optional, defaults from SlamParams; unknown
/// keys, wrong types and non-integral integers are errors) and validates them.
Result<SlamParams> ParamsFromJson(const nlohmann::json& json);

/// Reads and validates a parameters file; errors name the path and, when known, the
/// line (syntax errors also the column).
Result<SlamParams> LoadParams(const std::string& path);

/// The JSON object of the parameters (every key written).
nlohmann::json ParamsToJson(const SlamParams& params);

/// Validates and writes `params` to `path` atomically (temporary file in the same directory,
/// then rename); nullopt on success, else why nothing was written.
Result<void> SaveParams(const std::string& path, const SlamParams& params);

/// Applies an RFC 7396 merge patch to `base` and validates the result; a null member resets
/// that parameter to its value in `defaults`.
Result<SlamParams> ApplyParamsPatch(const SlamParams& base, const nlohmann::json& merge_patch,
                                    const SlamParams& defaults = SlamParams{});

}  // namespace slam::io
