#include "engine/config_error.hpp"

namespace slam {

std::string FormatErrors(const ConfigErrors& errors) {
  std::string text;
  for (const ConfigError& error : errors) {
    if (!text.empty()) text += '\n';
    // An empty pointer is the whole document (e.g. a file that does not parse).
    if (!error.pointer.empty()) text += error.pointer + ": ";
    text += error.detail;
  }
  return text;
}

}  // namespace slam
