#include "engine/io/json_locate.hpp"

#include <cstddef>
#include <limits>
#include <string>
#include <vector>

namespace slam::io {
namespace {

/// The unescaped reference tokens of an RFC 6901 pointer; nullopt when it is malformed.
std::optional<std::vector<std::string>> SplitPointer(std::string_view pointer) {
  std::vector<std::string> tokens;
  if (pointer.empty()) return tokens;
  if (pointer[0] != '/') return std::nullopt;
  tokens.emplace_back();
  for (std::size_t i = 1; i < pointer.size(); ++i) {
    const char c = pointer[i];
    if (c == '/') {
      tokens.emplace_back();
    } else if (c != '~') {
      tokens.back() += c;
    } else if (i + 1 < pointer.size() && (pointer[i + 1] == '0' || pointer[i + 1] == '1')) {
      tokens.back() += pointer[++i] == '0' ? '~' : '/';
    } else {
      return std::nullopt;  // "~" must be followed by 0 or 1
    }
  }
  return tokens;
}

/// Appends `code_point` to `out` as UTF-8.
void AppendUtf8(unsigned code_point, std::string& out) {
  if (code_point < 0x80) {
    out += static_cast<char>(code_point);
  } else if (code_point < 0x800) {
    out += static_cast<char>(0xC0 | (code_point >> 6));
    out += static_cast<char>(0x80 | (code_point & 0x3F));
  } else if (code_point < 0x10000) {
    out += static_cast<char>(0xE0 | (code_point >> 12));
    out += static_cast<char>(0x80 | ((code_point >> 6) & 0x3F));
    out += static_cast<char>(0x80 | (code_point & 0x3F));
  } else {
    out += static_cast<char>(0xF0 | (code_point >> 18));
    out += static_cast<char>(0x80 | ((code_point >> 12) & 0x3F));
    out += static_cast<char>(0x80 | ((code_point >> 6) & 0x3F));
    out += static_cast<char>(0x80 | (code_point & 0x3F));
  }
}

/// One pass over the text with an explicit stack of open containers, following the values whose
/// path is a prefix of the pointer's tokens and recording the line where each one starts.
class Locator {
 public:
  Locator(std::string_view text, const std::vector<std::string>& tokens)
      : text_(text), tokens_(tokens), lines_(tokens.size() + 1, 0) {}

  /// Walks the whole text; false when it is not well-formed JSON.
  bool Run() {
    if (text_.substr(0, 3) == "\xEF\xBB\xBF") pos_ = 3;  // a UTF-8 byte order mark, as nlohmann
    Expect expect = Expect::kValue;
    while (true) {
      SkipWhitespace();
      if (pos_ == text_.size()) return expect == Expect::kCommaOrClose && kinds_.empty();
      const char c = text_[pos_];
      switch (expect) {
        case Expect::kValueOrClose:
          if (c == ']') {
            Close();
            expect = Expect::kCommaOrClose;
            break;
          }
          [[fallthrough]];
        case Expect::kValue: {
          const std::optional<Expect> next = Value();
          if (!next) return false;
          expect = *next;
          break;
        }
        case Expect::kKeyOrClose:
          if (c == '}') {
            Close();
            expect = Expect::kCommaOrClose;
            break;
          }
          [[fallthrough]];
        case Expect::kKey:
          if (c != '"' || !Key()) return false;
          expect = Expect::kColon;
          break;
        case Expect::kColon:
          if (c != ':') return false;
          ++pos_;
          expect = Expect::kValue;
          break;
        case Expect::kCommaOrClose:
          if (kinds_.empty()) return false;  // text after the root value
          if (c == ',') {
            ++pos_;
            NextMember();
            expect = kinds_.back() == '{' ? Expect::kKey : Expect::kValue;
          } else if (c == (kinds_.back() == '{' ? '}' : ']')) {
            Close();
          } else {
            return false;
          }
          break;
      }
    }
  }

  /// How many tokens of the pointer the deepest value found matches (after a successful Run).
  std::size_t matched_tokens() const { return matched_; }
  /// The line where that value starts.
  int line() const { return lines_[matched_]; }

 private:
  enum class Expect { kValue, kValueOrClose, kKeyOrClose, kKey, kColon, kCommaOrClose };

  // An open container on the pointer's path: which member is current and whether it matches.
  struct PathFrame {
    std::size_t index = 0;  // current element, in an array
    bool matches = false;   // the current member is the one the next token names
  };

  void SkipWhitespace() {
    for (; pos_ < text_.size(); ++pos_) {
      const char c = text_[pos_];
      if (c == '\n') {
        if (line_ < std::numeric_limits<int>::max()) ++line_;
      } else if (c != ' ' && c != '\t' && c != '\r') {
        return;
      }
    }
  }

  /// Reads one value at pos_ (of a container, only the opening bracket); what may follow it.
  std::optional<Expect> Value() {
    const std::size_t depth = kinds_.size();
    const bool on_path =
        depth == path_.size() && (depth == 0 || path_.back().matches);  // its path is a prefix
    if (on_path) {
      // A later occurrence of a duplicate key replaces what an earlier one recorded.
      lines_[depth] = line_;
      matched_ = depth;
    }
    const char c = text_[pos_];
    if (c == '{' || c == '[') {
      kinds_ += c;
      if (on_path && depth < tokens_.size()) {
        path_.push_back({0, c == '[' && tokens_[depth] == "0"});
      }
      ++pos_;
      return c == '{' ? Expect::kKeyOrClose : Expect::kValueOrClose;
    }
    bool ok = false;
    if (c == '"') {
      ok = String(nullptr);
    } else if (c == '-' || (c >= '0' && c <= '9')) {
      ok = Number();
    } else {
      ok = Literal("true") || Literal("false") || Literal("null");
    }
    if (!ok) return std::nullopt;
    return Expect::kCommaOrClose;
  }

  /// Reads an object key at pos_, matching it against the pointer when the object is on path.
  bool Key() {
    if (path_.size() != kinds_.size()) return String(nullptr);
    std::string key;
    if (!String(&key)) return false;
    path_.back().matches = key == tokens_[kinds_.size() - 1];
    return true;
  }

  /// After a ',' in the innermost container.
  void NextMember() {
    if (path_.size() != kinds_.size()) return;
    PathFrame& frame = path_.back();
    if (kinds_.back() == '[') {
      ++frame.index;
      frame.matches = tokens_[kinds_.size() - 1] == std::to_string(frame.index);
    } else {
      frame.matches = false;  // until the next key
    }
  }

  /// Consumes the closing bracket of the innermost container.
  void Close() {
    ++pos_;
    kinds_.pop_back();
    if (path_.size() > kinds_.size()) path_.pop_back();
  }

  /// Consumes `word` when the text continues with it.
  bool Literal(std::string_view word) {
    if (text_.compare(pos_, word.size(), word) != 0) return false;
    pos_ += word.size();
    return true;
  }

  bool Digit() const { return pos_ < text_.size() && text_[pos_] >= '0' && text_[pos_] <= '9'; }

  /// Consumes one or more digits.
  bool Digits() {
    if (!Digit()) return false;
    while (Digit()) ++pos_;
    return true;
  }

  /// -?(0|[1-9][0-9]*)(\.[0-9]+)?([eE][+-]?[0-9]+)? (RFC 8259 section 6).
  bool Number() {
    if (text_[pos_] == '-') ++pos_;
    if (pos_ < text_.size() && text_[pos_] == '0') {
      ++pos_;
    } else if (!Digits()) {
      return false;
    }
    if (pos_ < text_.size() && text_[pos_] == '.') {
      ++pos_;
      if (!Digits()) return false;
    }
    if (pos_ < text_.size() && (text_[pos_] == 'e' || text_[pos_] == 'E')) {
      ++pos_;
      if (pos_ < text_.size() && (text_[pos_] == '+' || text_[pos_] == '-')) ++pos_;
      if (!Digits()) return false;
    }
    return true;
  }

  /// Four hex digits after "\u"; nullopt when they are not.
  std::optional<unsigned> Hex4() {
    if (text_.size() - pos_ < 4) return std::nullopt;
    unsigned value = 0;
    for (int i = 0; i < 4; ++i) {
      const char c = text_[pos_++];
      unsigned digit = 0;
      if (c >= '0' && c <= '9') {
        digit = static_cast<unsigned>(c - '0');
      } else if (c >= 'a' && c <= 'f') {
        digit = static_cast<unsigned>(c - 'a' + 10);
      } else if (c >= 'A' && c <= 'F') {
        digit = static_cast<unsigned>(c - 'A' + 10);
      } else {
        return std::nullopt;
      }
      value = value * 16 + digit;
    }
    return value;
  }

  /// Reads a string at pos_ (an opening quote), decoding it into `out` when not null.
  bool String(std::string* out) {
    ++pos_;
    while (pos_ < text_.size()) {
      const char c = text_[pos_++];
      if (c == '"') return true;
      if (static_cast<unsigned char>(c) < 0x20) return false;  // raw control characters
      if (c != '\\') {
        if (out != nullptr) *out += c;
        continue;
      }
      if (pos_ == text_.size()) return false;
      const char escape = text_[pos_++];
      char decoded = 0;
      switch (escape) {
        case '"':
        case '\\':
        case '/':
          decoded = escape;
          break;
        case 'b':
          decoded = '\b';
          break;
        case 'f':
          decoded = '\f';
          break;
        case 'n':
          decoded = '\n';
          break;
        case 'r':
          decoded = '\r';
          break;
        case 't':
          decoded = '\t';
          break;
        case 'u': {
          std::optional<unsigned> unit = Hex4();
          if (!unit || (*unit >= 0xDC00 && *unit <= 0xDFFF)) return false;  // lone low surrogate
          unsigned code_point = *unit;
          if (*unit >= 0xD800 && *unit <= 0xDBFF) {  // a high surrogate needs its low half
            if (!Literal("\\u")) return false;
            const std::optional<unsigned> low = Hex4();
            if (!low || *low < 0xDC00 || *low > 0xDFFF) return false;
            code_point = 0x10000 + ((*unit - 0xD800) << 10) + (*low - 0xDC00);
          }
          if (out != nullptr) AppendUtf8(code_point, *out);
          continue;
        }
        default:
          return false;
      }
      if (out != nullptr) *out += decoded;
    }
    return false;  // unterminated
  }

  std::string_view text_;
  const std::vector<std::string>& tokens_;
  std::size_t pos_ = 0;
  int line_ = 1;
  std::string kinds_;            // '{' or '[' per open container, outermost first
  std::vector<PathFrame> path_;  // the open containers on the pointer's path (a prefix of kinds_)
  std::vector<int> lines_;       // lines_[d]: where the value matching d tokens starts
  std::size_t matched_ = 0;      // the deepest match of the latest occurrence
};

// The outcome of one walk: how deep the pointer was found, and where.
struct Location {
  std::size_t tokens = 0;   // the pointer's tokens
  std::size_t matched = 0;  // how many of them the deepest value found matches
  int line = 0;             // where that value starts
};

/// The walk shared by both lookups; nullopt for a malformed pointer or text.
std::optional<Location> Locate(std::string_view json_text, std::string_view pointer) {
  const std::optional<std::vector<std::string>> tokens = SplitPointer(pointer);
  if (!tokens) return std::nullopt;
  Locator locator(json_text, *tokens);
  if (!locator.Run()) return std::nullopt;
  return Location{tokens->size(), locator.matched_tokens(), locator.line()};
}

}  // namespace

std::optional<int> LineOfPointer(std::string_view json_text, std::string_view pointer) {
  const std::optional<Location> found = Locate(json_text, pointer);
  if (!found || found->matched != found->tokens) return std::nullopt;
  return found->line;
}

std::optional<int> LineOfNearestValue(std::string_view json_text, std::string_view pointer) {
  const std::optional<Location> found = Locate(json_text, pointer);
  if (!found) return std::nullopt;
  return found->line;
}

}  // namespace slam::io
