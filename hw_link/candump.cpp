#include "hw_link/candump.hpp"

#include <algorithm>
#include <cstddef>
#include <limits>
#include <optional>
#include <utility>

// Decisions beyond the header's contract:
// - The timestamp is "(" 1+ decimal digits "." 1..6 decimal digits ")", read exactly as integers:
//   candump writes 6 fraction digits; fewer are read as a decimal fraction ("(1.5)" = 1.500000 s),
//   more than 6, signs, blanks inside, or seconds overflowing int64 microseconds are errors.
// - At least one blank must follow the ')' and the interface. The interface is any run of
//   non-blank characters without '#' or control characters.
// - Hex digits may be upper or lower case. A remote frame's length digit is 0..8 ("123#R" =
//   length 0). The FD flags digit is read and dropped (CanFrame keeps no FD flags); FD data must
//   have a valid FD length (0..8, 12, 16, 20, 24, 32, 48 or 64 bytes).
// - Error frames (can_id with 0x20000000 set) do not fit in 29 bits: they are kError. can-utils'
//   '.' data separators and "_<dlc>" suffixes are not written by `candump -l`: kError.

namespace slam::hw {
namespace {

constexpr int64_t kMicrosPerSecond = 1'000'000;
constexpr int kFractionDigits = 6;
// Largest whole-second count accepted: 2^40 s (34 800 years), far beyond any clock, and far
// enough below int64 microseconds that the replay's timeline (each frame moves it on by at most
// a second) cannot overflow: that would take 8e12 frames.
constexpr int64_t kMaxSeconds = int64_t{1} << 40;
constexpr size_t kStandardIdDigits = 3;
constexpr size_t kExtendedIdDigits = 8;

bool IsBlank(char c) { return c == ' ' || c == '\t'; }

bool IsDigit(char c) { return c >= '0' && c <= '9'; }

bool IsControl(char c) {
  const auto u = static_cast<unsigned char>(c);
  return u < 0x20 || u == 0x7F;
}

// The value of one hex digit (either case), or -1.
int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

bool IsValidFdLength(size_t n) {
  return n <= 8 || n == 12 || n == 16 || n == 20 || n == 24 || n == 32 || n == 48 || n == 64;
}

CandumpLine Error(std::string reason) {
  CandumpLine out;
  out.kind = CandumpLineKind::kError;
  out.error = std::move(reason);
  return out;
}

// A printable, bounded copy of a field for error messages (keeps the reason on one line).
std::string Quote(std::string_view field) {
  constexpr size_t kMaxShown = 32;
  std::string out = "'";
  for (size_t i = 0; i < field.size() && i < kMaxShown; ++i) {
    out += IsControl(field[i]) ? '?' : field[i];
  }
  if (field.size() > kMaxShown) out += "...";
  out += "'";
  return out;
}

// Reads "(SECONDS.FRACTION)" at the start of `text`; returns microseconds and the rest of the
// text, or nothing when it is malformed.
std::optional<std::pair<int64_t, std::string_view>> ParseTime(std::string_view text) {
  size_t pos = 0;
  if (pos >= text.size() || text[pos] != '(') return std::nullopt;
  ++pos;
  int64_t seconds = 0;
  const size_t seconds_begin = pos;
  while (pos < text.size() && IsDigit(text[pos])) {
    const int digit = text[pos] - '0';
    if (seconds > (kMaxSeconds - digit) / 10) return std::nullopt;
    seconds = seconds * 10 + digit;
    ++pos;
  }
  if (pos == seconds_begin || pos >= text.size() || text[pos] != '.') return std::nullopt;
  ++pos;
  int64_t micros = 0;
  int digits = 0;
  while (pos < text.size() && IsDigit(text[pos])) {
    if (digits == kFractionDigits) return std::nullopt;
    micros = micros * 10 + (text[pos] - '0');
    ++digits;
    ++pos;
  }
  if (digits == 0 || pos >= text.size() || text[pos] != ')') return std::nullopt;
  for (int i = digits; i < kFractionDigits; ++i) micros *= 10;
  return std::make_pair(seconds * kMicrosPerSecond + micros, text.substr(pos + 1));
}

// Reads hex digits into `value`; false if any is not a hex digit.
bool ParseHex(std::string_view digits, uint32_t& value) {
  value = 0;
  for (const char c : digits) {
    const int v = HexValue(c);
    if (v < 0) return false;
    value = (value << 4) | static_cast<uint32_t>(v);
  }
  return true;
}

// Reads pairs of hex digits into frame.data; returns the reason when they are not.
std::optional<std::string> ParseData(std::string_view hex, size_t max_bytes, CanFrame& frame) {
  if (hex.size() % 2 != 0) return "odd number of data hex digits";
  const size_t n = hex.size() / 2;
  if (n > max_bytes) return "too many data bytes (" + std::to_string(n) + ")";
  for (size_t i = 0; i < n; ++i) {
    const int hi = HexValue(hex[2 * i]);
    const int lo = HexValue(hex[2 * i + 1]);
    if (hi < 0 || lo < 0) return "non-hex data " + Quote(hex);
    frame.data[i] = static_cast<uint8_t>((hi << 4) | lo);
  }
  frame.len = static_cast<uint8_t>(n);
  return std::nullopt;
}

// Parses the compact frame text ("ID#DATA", "ID#R[L]", "ID##FDATA"); returns the reason on error.
std::optional<std::string> ParseFrame(std::string_view text, CanFrame& frame) {
  const size_t hash = text.find('#');
  if (hash == std::string_view::npos) return "no '#' in frame " + Quote(text);
  const std::string_view id_text = text.substr(0, hash);
  if (id_text.size() != kStandardIdDigits && id_text.size() != kExtendedIdDigits) {
    return "id must have 3 or 8 hex digits: " + Quote(id_text);
  }
  frame.extended = id_text.size() == kExtendedIdDigits;
  if (!ParseHex(id_text, frame.id)) return "non-hex id " + Quote(id_text);
  if (frame.id > (frame.extended ? kCanExtendedIdMax : kCanStandardIdMax)) {
    return "id out of range: " + Quote(id_text);
  }

  std::string_view rest = text.substr(hash + 1);
  if (!rest.empty() && (rest[0] == 'R' || rest[0] == 'r')) {
    frame.remote = true;
    if (rest.size() == 1) return std::nullopt;
    const int len = rest.size() == 2 ? HexValue(rest[1]) : -1;
    if (len < 0 || len > kCanMaxData) return "bad remote length " + Quote(rest.substr(1));
    frame.len = static_cast<uint8_t>(len);
    return std::nullopt;
  }
  if (!rest.empty() && rest[0] == '#') {
    frame.fd = true;
    if (rest.size() < 2 || HexValue(rest[1]) < 0) return "missing FD flags digit";
    if (auto reason = ParseData(rest.substr(2), kCanFdMaxData, frame)) return reason;
    if (!IsValidFdLength(frame.len)) {
      return "invalid FD length " + std::to_string(frame.len);
    }
    return std::nullopt;
  }
  return ParseData(rest, kCanMaxData, frame);
}

size_t SkipBlanks(std::string_view text, size_t pos) {
  while (pos < text.size() && IsBlank(text[pos])) ++pos;
  return pos;
}

size_t SkipField(std::string_view text, size_t pos) {
  while (pos < text.size() && !IsBlank(text[pos])) ++pos;
  return pos;
}

}  // namespace

CandumpLine ParseCandumpLine(std::string_view line) {
  if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
  const size_t start = SkipBlanks(line, 0);
  if (start == line.size() || line[start] != '(') return CandumpLine{};  // kIgnored

  const auto time = ParseTime(line.substr(start));
  if (!time) return Error("bad timestamp, expected (seconds.microseconds)");
  const std::string_view rest = time->second;

  if (rest.empty() || !IsBlank(rest[0])) return Error("missing blank after the timestamp");
  const size_t iface_begin = SkipBlanks(rest, 0);
  const size_t iface_end = SkipField(rest, iface_begin);
  const std::string_view iface = rest.substr(iface_begin, iface_end - iface_begin);
  const size_t frame_begin = SkipBlanks(rest, iface_end);
  const size_t frame_end = SkipField(rest, frame_begin);
  const std::string_view frame_text = rest.substr(frame_begin, frame_end - frame_begin);
  if (iface.empty() || frame_text.empty() || iface.find('#') != std::string_view::npos) {
    return Error("missing interface or frame");
  }
  if (std::any_of(iface.begin(), iface.end(), IsControl)) {
    return Error("control character in interface " + Quote(iface));
  }
  if (SkipBlanks(rest, frame_end) != rest.size()) {
    return Error("trailing garbage " + Quote(rest.substr(SkipBlanks(rest, frame_end))));
  }

  CandumpLine out;
  if (auto reason = ParseFrame(frame_text, out.frame)) return Error(std::move(*reason));
  out.kind = CandumpLineKind::kFrame;
  out.time_us = time->first;
  out.interface = std::string(iface);
  return out;
}

std::string FormatCandumpLine(int64_t time_us, std::string_view interface, const CanFrame& frame) {
  const int64_t t = std::max<int64_t>(time_us, 0);  // precondition; never print a sign
  std::string seconds = std::to_string(t / kMicrosPerSecond);
  std::string micros = std::to_string(t % kMicrosPerSecond);
  std::string out = "(";
  if (seconds.size() < 10) out.append(10 - seconds.size(), '0');
  out += seconds;
  out += '.';
  out.append(static_cast<size_t>(kFractionDigits) - micros.size(), '0');
  out += micros;
  out += ") ";
  out += interface;
  out += ' ';
  out += FormatCompact(frame);
  // can-utils writes a remote frame's non-zero length after the 'R'; FormatCompact does not.
  if (frame.remote && frame.len > 0 && frame.len <= kCanMaxData) {
    out += static_cast<char>('0' + frame.len);
  }
  return out;
}

}  // namespace slam::hw
