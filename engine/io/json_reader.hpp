#pragma once
// Internal to engine/io: strict reading of JSON documents shared by the robot and params
// adapters. Unknown keys, duplicate keys, missing keys and wrong types become ConfigErrors that
// carry the JSON pointer of the offending value (and, read from a file, its line); nothing throws.

#include <cerrno>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "engine/config_error.hpp"
#include "engine/io/json_locate.hpp"
#include "engine/io/text_fields.hpp"
#include "engine/result.hpp"

namespace slam::io::detail {

using Json = nlohmann::json;

/// `parent` extended by one reference token, escaped as RFC 6901 requires.
inline std::string Child(const std::string& parent, const std::string& token) {
  std::string pointer = parent + '/';
  for (char c : token) {
    if (c == '~') {
      pointer += "~0";
    } else if (c == '/') {
      pointer += "~1";
    } else {
      pointer += c;
    }
  }
  return pointer;
}

/// `parent` extended by an array index.
inline std::string Child(const std::string& parent, std::size_t index) {
  return parent + '/' + std::to_string(index);
}

/// "expected X, got Y" for a value of the wrong type.
inline ConfigError WrongType(const std::string& pointer, const char* expected, const Json& got) {
  return {pointer, std::string("expected ") + expected + ", got " + got.type_name()};
}

/// Reads a number into `out`; false (with an error) when `value` is not a number.
inline bool ReadNumber(const Json& value, const std::string& pointer, double& out,
                       ConfigErrors& errors) {
  if (!value.is_number()) {
    errors.push_back(WrongType(pointer, "a number", value));
    return false;
  }
  out = value.get<double>();
  return true;
}

/// Reads an integral number (3 or 3.0, not 3.5) that fits an int into `out`.
inline bool ReadInt(const Json& value, const std::string& pointer, int& out, ConfigErrors& errors) {
  if (!value.is_number()) {
    errors.push_back(WrongType(pointer, "an integer", value));
    return false;
  }
  constexpr double kMin = std::numeric_limits<int>::min();
  constexpr double kMax = std::numeric_limits<int>::max();
  double number = 0.0;
  if (value.is_number_unsigned()) {
    number = static_cast<double>(value.get<std::uint64_t>());
  } else if (value.is_number_integer()) {
    number = static_cast<double>(value.get<std::int64_t>());
  } else {
    number = value.get<double>();
  }
  if (number != std::floor(number)) {
    errors.push_back({pointer, "expected an integer, got " + value.dump()});
    return false;
  }
  if (number < kMin || number > kMax) {
    errors.push_back({pointer, value.dump() + " does not fit an int"});
    return false;
  }
  out = static_cast<int>(number);
  return true;
}

/// Reads a string into `out`.
inline bool ReadString(const Json& value, const std::string& pointer, std::string& out,
                       ConfigErrors& errors) {
  if (!value.is_string()) {
    errors.push_back(WrongType(pointer, "a string", value));
    return false;
  }
  out = value.get<std::string>();
  return true;
}

/// True when `value` is an array (of exactly `size` elements unless size is 0); else an error.
inline bool ExpectArray(const Json& value, const std::string& pointer, std::size_t size,
                        ConfigErrors& errors) {
  if (!value.is_array()) {
    errors.push_back(WrongType(pointer, "an array", value));
    return false;
  }
  if (size != 0 && value.size() != size) {
    errors.push_back({pointer, "expected " + std::to_string(size) + " elements, got " +
                                   std::to_string(value.size())});
    return false;
  }
  return true;
}

/// Reads the members of one JSON object; Finish() reports every key nobody asked for.
class ObjectReader {
 public:
  /// Reports an error at `pointer` when `value` is not an object.
  ObjectReader(const Json& value, std::string pointer, ConfigErrors& errors)
      : value_(value), pointer_(std::move(pointer)), errors_(errors) {
    if (!value_.is_object()) errors_.push_back(WrongType(pointer_, "an object", value_));
  }

  /// True when the value is an object (members can be read).
  bool is_object() const { return value_.is_object(); }
  /// The pointer of the object.
  const std::string& pointer() const { return pointer_; }
  /// The pointer of one member.
  std::string Member(const std::string& key) const { return Child(pointer_, key); }

  /// The member `key`, or nullptr when absent (an error when `required`). Marks the key known.
  const Json* Get(const std::string& key, bool required) {
    known_.insert(key);
    if (!value_.is_object()) return nullptr;
    const auto it = value_.find(key);
    if (it == value_.end()) {
      if (required) errors_.push_back({Member(key), "missing required key"});
      return nullptr;
    }
    return &*it;
  }

  /// Reads a number member; leaves `out` unchanged when absent or wrong.
  void Read(const std::string& key, double& out, bool required) {
    if (const Json* member = Get(key, required)) ReadNumber(*member, Member(key), out, errors_);
  }
  /// Reads an integer member; leaves `out` unchanged when absent or wrong.
  void Read(const std::string& key, int& out, bool required) {
    if (const Json* member = Get(key, required)) ReadInt(*member, Member(key), out, errors_);
  }
  /// Reads a string member; leaves `out` unchanged when absent or wrong.
  void Read(const std::string& key, std::string& out, bool required) {
    if (const Json* member = Get(key, required)) ReadString(*member, Member(key), out, errors_);
  }

  /// Reports the keys that no Get/Read asked for (typos must not be silently ignored).
  void Finish() {
    if (!value_.is_object()) return;
    for (const auto& [key, member] : value_.items()) {
      if (known_.count(key) == 0) errors_.push_back({Member(key), "unknown key"});
    }
  }

 private:
  const Json& value_;
  std::string pointer_;
  ConfigErrors& errors_;
  std::set<std::string> known_;
};

/// Tracks where the parser is so that duplicate keys can be reported with their pointer.
class DuplicateKeyFinder {
 public:
  explicit DuplicateKeyFinder(ConfigErrors& errors) : errors_(errors) {}

  bool operator()(int /*depth*/, Json::parse_event_t event, Json& parsed) {
    switch (event) {
      case Json::parse_event_t::object_start:
        frames_.push_back({true, {}, {}, 0});
        break;
      case Json::parse_event_t::array_start:
        frames_.push_back({false, {}, {}, 0});
        break;
      case Json::parse_event_t::object_end:
      case Json::parse_event_t::array_end:
        if (!frames_.empty()) frames_.pop_back();
        NextElement();
        break;
      case Json::parse_event_t::key: {
        if (frames_.empty() || !parsed.is_string()) break;
        Frame& frame = frames_.back();
        frame.key = parsed.get<std::string>();
        if (!frame.keys.insert(frame.key).second) {
          errors_.push_back({Pointer(), "duplicate key"});
        }
        break;
      }
      case Json::parse_event_t::value:
        NextElement();
        break;
    }
    return true;
  }

 private:
  struct Frame {
    bool object;
    std::set<std::string> keys;
    std::string key;    // current key, in an object
    std::size_t index;  // current element, in an array
  };

  void NextElement() {
    if (!frames_.empty() && !frames_.back().object) ++frames_.back().index;
  }
  std::string Pointer() const {
    std::string pointer;
    for (const Frame& frame : frames_) {
      pointer = frame.object ? Child(pointer, frame.key) : Child(pointer, frame.index);
    }
    return pointer;
  }

  ConfigErrors& errors_;
  std::vector<Frame> frames_;
};

/// Sets the line of every error that has none from the text its JSON was parsed from: the line of
/// the value at its pointer, or of the nearest enclosing value (for a missing key, its object).
inline void AddLines(ConfigErrors& errors, std::string_view text) {
  for (ConfigError& error : errors) {
    if (error.line > 0) continue;
    if (const std::optional<int> line = LineOfNearestValue(text, error.pointer)) error.line = *line;
  }
}

/// Parses `text`; `source` (a file path, or a description) prefixes syntax errors, which carry
/// nlohmann's "line L, column C" message. Duplicate keys are errors, with their line.
inline Result<Json> ParseJsonText(const std::string& text, const std::string& source) {
  ConfigErrors errors;
  Json json;
  try {
    json = Json::parse(text, DuplicateKeyFinder(errors));
  } catch (const Json::exception& e) {
    std::string what = e.what();
    // "[json.exception.parse_error.101] parse error at line 1, column 2: ..." -> drop the tag.
    const std::size_t tag_end = what.find("] ");
    if (what.rfind("[json.exception.", 0) == 0 && tag_end != std::string::npos) {
      what = what.substr(tag_end + 2);
    }
    return Result<Json>(ConfigErrors{{"", source + ": " + what}}, source);
  }
  if (!errors.empty()) {
    AddLines(errors, text);
    return Result<Json>(std::move(errors), source);
  }
  return Result<Json>(std::move(json));
}

/// A parsed JSON document and the text it was parsed from (to find the lines of errors).
struct JsonDocument {
  Json json;
  std::string text;
};

/// Reads and parses a JSON file; errors name the path.
inline Result<JsonDocument> ReadJsonDocument(const std::string& path) {
  Result<std::string> text = ReadTextFile(path);
  if (!text.ok()) return {text.errors(), path};
  Result<Json> json = ParseJsonText(text.value(), path);
  if (!json.ok()) return {json.errors(), path};
  return JsonDocument{std::move(json).value(), std::move(text).value()};
}

/// Reads and parses a JSON file; errors name the path.
inline Result<Json> ReadJsonFile(const std::string& path) {
  Result<JsonDocument> document = ReadJsonDocument(path);
  if (!document.ok()) return {document.errors(), path};
  return std::move(document.value().json);
}

/// Reads a JSON file and converts it with `convert` (const Json& -> Result<T>); every error names
/// the path and, when it can be found in the text, the line.
template <typename T, typename Convert>
Result<T> LoadJsonFile(const std::string& path, Convert&& convert) {
  Result<JsonDocument> document = ReadJsonDocument(path);
  if (!document.ok()) return {document.errors(), path};
  Result<T> value = convert(document.value().json);
  if (value.ok()) return value;
  ConfigErrors errors = value.errors();
  AddLines(errors, document.value().text);
  return {std::move(errors), path};
}

}  // namespace slam::io::detail
