#include "engine/config_error.hpp"

namespace slam {

std::string FormatError(const ConfigError& error, std::string_view context) {
  std::string text;
  if (error.line > 0) {
    text = context.empty() ? "line " + std::to_string(error.line)
                           : std::string(context) + ':' + std::to_string(error.line);
    text += ": ";
    if (!error.pointer.empty()) text += error.pointer + ": ";
  } else if (!error.pointer.empty()) {
    // An empty pointer is the whole document (e.g. a file that does not parse).
    if (!context.empty()) text = std::string(context) + '#';
    text += error.pointer + ": ";
  }
  return text + error.detail;
}

std::string FormatErrors(const ConfigErrors& errors, std::string_view context) {
  std::string text;
  for (const ConfigError& error : errors) {
    if (!text.empty()) text += '\n';
    text += FormatError(error, context);
  }
  return text;
}

}  // namespace slam
