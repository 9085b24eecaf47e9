#include "hw_link/slcan.hpp"

#include <algorithm>
#include <cstddef>
#include <utility>

// Decisions beyond the header's contract:
// - '\r' and '\n' end a line, but a '\n' right after a '\r' (also across Feed calls) is part of
//   that line end: "\r\n" is one line end, never an extra empty line (= ack). "\n\r" is two.
// - '\a' is a complete reply on its own (no '\r' needed): one nack. A partial line before it is
//   counted as a bad line and dropped. A '\r' after the bell is a separate empty line (an ack).
// - An empty line, "z" and "Z" are acks. Any other line must be a frame line; other adapter
//   replies (version "V....", status "F..", ...) are bad lines: we never send those queries.
// - Hex digits may be upper or lower case; the length digit is 0..8 (also for remote frames);
//   the optional time stamp is 4 hex digits below 60000.
// - A line longer than the longest valid line (30 characters: extended frame, 8 bytes, time
//   stamp) is counted once as a bad line when its 31st character arrives; the rest of it is
//   skipped up to the next line end or bell.

namespace slam::hw {
namespace {

constexpr size_t kStandardIdDigits = 3;
constexpr size_t kExtendedIdDigits = 8;
constexpr size_t kTimestampDigits = 4;
constexpr size_t kMaxLineLength = 1 + kExtendedIdDigits + 1 + 2 * kCanMaxData + kTimestampDigits;
constexpr uint32_t kTimestampModulo = 60000;

// The value of one hex digit (either case), or -1.
int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

// Reads hex digits; nothing if any is not one.
std::optional<uint32_t> ParseHex(std::string_view digits) {
  uint32_t value = 0;
  for (const char c : digits) {
    const int v = HexValue(c);
    if (v < 0) return std::nullopt;
    value = (value << 4) | static_cast<uint32_t>(v);
  }
  return value;
}

// Parses a frame line (without its line end); nothing if it is not a valid one.
std::optional<SlcanFrame> ParseFrameLine(std::string_view line) {
  if (line.empty()) return std::nullopt;
  const char kind = line[0];
  if (kind != 't' && kind != 'T' && kind != 'r' && kind != 'R') return std::nullopt;
  SlcanFrame out;
  CanFrame& frame = out.frame;
  frame.extended = kind == 'T' || kind == 'R';
  frame.remote = kind == 'r' || kind == 'R';
  const size_t id_digits = frame.extended ? kExtendedIdDigits : kStandardIdDigits;
  if (line.size() < 1 + id_digits + 1) return std::nullopt;

  const auto id = ParseHex(line.substr(1, id_digits));
  if (!id || *id > (frame.extended ? kCanExtendedIdMax : kCanStandardIdMax)) return std::nullopt;
  frame.id = *id;
  const int len = HexValue(line[1 + id_digits]);
  if (len < 0 || len > kCanMaxData) return std::nullopt;
  frame.len = static_cast<uint8_t>(len);

  const size_t data_begin = 2 + id_digits;
  const size_t data_digits = frame.remote ? 0 : 2 * frame.len;
  const size_t frame_chars = data_begin + data_digits;
  if (line.size() != frame_chars && line.size() != frame_chars + kTimestampDigits) {
    return std::nullopt;
  }
  for (size_t i = 0; i < data_digits / 2; ++i) {
    const int hi = HexValue(line[data_begin + 2 * i]);
    const int lo = HexValue(line[data_begin + 2 * i + 1]);
    if (hi < 0 || lo < 0) return std::nullopt;
    frame.data[i] = static_cast<uint8_t>((hi << 4) | lo);
  }
  if (line.size() > frame_chars) {
    const auto stamp = ParseHex(line.substr(frame_chars));
    if (!stamp || *stamp >= kTimestampModulo) return std::nullopt;
    out.timestamp_ms = static_cast<uint16_t>(*stamp);
  }
  return out;
}

void AppendHex(std::string& out, uint32_t value, int digits) {
  static constexpr char kHex[] = "0123456789ABCDEF";
  for (int i = digits - 1; i >= 0; --i) out += kHex[(value >> (4 * i)) & 0xF];
}

}  // namespace

void SlcanParser::Feed(std::string_view bytes, std::vector<SlcanFrame>& out) {
  counters_.bytes += bytes.size();
  for (const char c : bytes) {
    const bool lf_after_cr = c == '\n' && after_cr_;
    after_cr_ = c == '\r';
    if (lf_after_cr) continue;

    if (c == '\r' || c == '\n') {
      if (overlong_) {
        overlong_ = false;  // already counted
      } else if (line_.empty() || line_ == "z" || line_ == "Z") {
        ++counters_.acks;
      } else if (auto frame = ParseFrameLine(line_)) {
        ++counters_.frames;
        frame->after_bad_line = std::exchange(bad_since_frame_, false);
        out.push_back(*frame);
      } else {
        ++counters_.bad_lines;
        bad_since_frame_ = true;
      }
      line_.clear();
    } else if (c == '\a') {
      if (!line_.empty()) {  // an unfinished line: cut off
        ++counters_.bad_lines;
        bad_since_frame_ = true;
      }
      line_.clear();
      overlong_ = false;
      ++counters_.nacks;
    } else if (overlong_) {
      // skipping the rest of a line already counted as too long
    } else if (line_.size() == kMaxLineLength) {
      ++counters_.bad_lines;
      bad_since_frame_ = true;
      line_.clear();
      overlong_ = true;
    } else {
      line_ += c;
    }
  }
}

std::string FormatSlcanFrame(const CanFrame& frame, std::optional<uint16_t> timestamp_ms) {
  const int len = std::min<int>(frame.len, kCanMaxData);  // precondition: classic frame
  std::string out;
  out += frame.extended ? (frame.remote ? 'R' : 'T') : (frame.remote ? 'r' : 't');
  if (frame.extended) {
    AppendHex(out, frame.id & kCanExtendedIdMax, static_cast<int>(kExtendedIdDigits));
  } else {
    AppendHex(out, frame.id & kCanStandardIdMax, static_cast<int>(kStandardIdDigits));
  }
  AppendHex(out, static_cast<uint32_t>(len), 1);
  if (!frame.remote) {
    for (int i = 0; i < len; ++i) AppendHex(out, frame.data[static_cast<size_t>(i)], 2);
  }
  if (timestamp_ms) AppendHex(out, *timestamp_ms % kTimestampModulo, 4);
  out += '\r';
  return out;
}

std::string SlcanOpenCommands() { return "C\rS8\rO\r"; }

}  // namespace slam::hw
