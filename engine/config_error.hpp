#pragma once
// Validation errors that a server or a tool can show: where (a JSON pointer, and the line of the
// file when known) and what is wrong.

#include <string>
#include <string_view>
#include <vector>

namespace slam {

struct ConfigError {
  std::string pointer;  // JSON pointer of the offending value, e.g. "/particles"
  std::string detail;   // human-readable explanation
  int line = 0;         // 1-based line of the value in the file it came from; 0 when unknown
};

using ConfigErrors = std::vector<ConfigError>;

/// One error as text: "context:line: pointer: detail" when the line is known (just "line L: ..."
/// without a context), else "context#pointer: detail" ("pointer: detail" without a context).
/// Errors without a pointer name their source themselves: only "context:line: " (when the line
/// is known) precedes their detail.
std::string FormatError(const ConfigError& error, std::string_view context = {});

/// FormatError lines, one per error.
std::string FormatErrors(const ConfigErrors& errors, std::string_view context = {});

}  // namespace slam
