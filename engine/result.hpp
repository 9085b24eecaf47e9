#pragma once
// The one error type of the project's boundaries: a value, or the errors explaining why there
// is none (std::expected-like). Result<void> is a success or its errors. Each error has a JSON
// pointer where one applies (configuration files, request bodies) and a detail; an error
// without a pointer (Error("...")) is a message that names its source itself.

#include <cassert>
#include <optional>
#include <string>
#include <type_traits>
#include <utility>

#include "engine/config_error.hpp"

namespace slam {

template <typename T>
class [[nodiscard]] Result {
 public:
  // Implicit on purpose, like absl::StatusOr: `return value;` and `return errors;` both work.

  /// A successful result, from anything T is made from (a std::unique_ptr of a derived class
  /// for a Result of a base class pointer, say).
  template <typename U = T,
            typename = std::enable_if_t<std::is_constructible_v<T, U&&> &&
                                        !std::is_same_v<std::decay_t<U>, Result> &&
                                        !std::is_same_v<std::decay_t<U>, ConfigErrors>>>
  Result(U&& value)  // NOLINT(google-explicit-constructor)
      : value_(std::in_place, std::forward<U>(value)) {}
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

/// A success (default-constructed) or its errors (never empty for a failure: a Result<void>
/// made from empty errors is a success).
template <>
class [[nodiscard]] Result<void> {
 public:
  /// A success.
  Result() = default;
  /// A failed result (a success if `errors` is empty); `context` names where the input came from.
  Result(ConfigErrors errors, std::string context = {})  // NOLINT(google-explicit-constructor)
      : errors_(std::move(errors)), error_context_(std::move(context)) {}

  bool ok() const { return errors_.empty(); }
  const ConfigErrors& errors() const { return errors_; }
  const std::string& error_context() const { return error_context_; }
  /// One line per error, as Result<T>::Message.
  std::string Message() const { return FormatErrors(errors_, error_context_); }

 private:
  ConfigErrors errors_;
  std::string error_context_;
};

/// An error that is a message naming its source itself (no JSON pointer), for `return Error(...)`
/// from a function returning any Result.
inline ConfigErrors Error(std::string message) { return {{"", std::move(message)}}; }

}  // namespace slam
