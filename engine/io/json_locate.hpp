#pragma once
// Where a JSON pointer (RFC 6901) points in JSON text: the line to show next to a ConfigError.
// A small tokenizer of its own (nlohmann's DOM keeps no positions); linear time, no recursion.

#include <optional>
#include <string_view>

namespace slam::io {

/// The 1-based line where the value at `pointer` starts in `json_text` ("" is the root value).
/// For an object member this is the line of its value, which is the line of its key unless a
/// line break separates the two. A key that occurs twice resolves to its last occurrence, the
/// one JSON parsers (nlohmann included) keep. nullopt when the pointer is malformed or names
/// nothing, or when the text is not well-formed JSON (strings are not checked for UTF-8).
std::optional<int> LineOfPointer(std::string_view json_text, std::string_view pointer);

/// Like LineOfPointer, but when `pointer` names nothing, the line of its nearest enclosing value
/// that exists (for a missing member: the object that lacks it). nullopt only when the pointer
/// is malformed or the text is not well-formed JSON.
std::optional<int> LineOfNearestValue(std::string_view json_text, std::string_view pointer);

}  // namespace slam::io
