#pragma once
// Validation errors that a server or a tool can show: where (a JSON pointer) and what is wrong.

#include <string>
#include <vector>

namespace slam {

struct ConfigError {
  std::string pointer;  // JSON pointer of the offending value, e.g. "/particles"
  std::string detail;   // human-readable explanation
};

using ConfigErrors = std::vector<ConfigError>;

/// "pointer: detail" lines, one per error.
std::string FormatErrors(const ConfigErrors& errors);

}  // namespace slam
