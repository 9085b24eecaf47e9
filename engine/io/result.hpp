#pragma once
// A value or the configuration errors explaining why there is none (std::expected-like).

#include <cassert>
#include <optional>
#include <string>
#include <utility>

#include "engine/config_error.hpp"

namespace slam::io {

template <typename T>
class Result {
 public:
  // Implicit on purpose, like absl::StatusOr: `return value;` and `return errors;` both work.

  /// A successful result.
  Result(T value) : value_(std::move(value)) {}  // NOLINT(google-explicit-constructor)
  /// A failed result; `context` names where the input came from (e.g. a file path).
  Result(ConfigErrors errors, std::string context = {})  // NOLINT(google-explicit-constructor)
      : errors_(std::move(errors)), error_context_(std::move(context)) {}

  /// True when the result holds a value (and no errors).
  bool ok() const { return value_.has_value(); }

  /// The value; precondition: ok().
  const T& value() const& {
    assert(ok());
    return *value_;
  }
  /// The value; precondition: ok().
  T& value() & {
    assert(ok());
    return *value_;
  }
  /// The value, moved out; precondition: ok().
  T&& value() && {
    assert(ok());
    return std::move(*value_);
  }

  /// The errors; empty when ok().
  const ConfigErrors& errors() const { return errors_; }
  /// Where the input came from, when known (a file path); empty otherwise.
  const std::string& error_context() const { return error_context_; }

  /// One line per error (FormatErrors): "context:line: pointer: detail" when the line is known,
  /// else "context#pointer: detail"; errors without a pointer name their source themselves.
  std::string Message() const { return FormatErrors(errors_, error_context_); }

 private:
  std::optional<T> value_;
  ConfigErrors errors_;
  std::string error_context_;
};

}  // namespace slam::io
