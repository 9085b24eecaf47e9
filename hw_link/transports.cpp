// The candump log replay. The live transports live beside it: slcan_source.cpp, udp_source.cpp
// and socketcan_source.cpp.

#include "hw_link/transports.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <optional>
#include <string_view>
#include <thread>
#include <utility>

#include "hw_link/candump.hpp"
#include "hw_link/fd_util.hpp"

namespace slam::hw {
namespace {

constexpr size_t kMaxFramesPerRead = 256;    // one batch of an unpaced replay
constexpr size_t kMaxLinesPerRead = 4096;    // bounds one Read on a file of garbage
constexpr size_t kReadChunk = 64 * 1024;     // bytes read from the file at a time
constexpr size_t kMaxLineBytes = 64 * 1024;  // longer lines are bad lines, not memory
constexpr size_t kKeptErrors = 5;            // first bad lines kept for Describe()
constexpr double kMaxOffsetNs = 1e18;        // paced: ~30 years, keeps the cast defined
// candump stamps frames with the wall clock, which NTP or a user can step. A step back, or a
// silence longer than kMaxGapUs (the marXbot's bus is never quiet that long while logging), is
// a clock jump: the replay's time goes on kJumpGapUs after the previous frame instead, a silence
// the scan assembler sees as one (it abandons the scan in progress) rather than an hour to wait
// through or a stretch of frames out of order.
constexpr int64_t kMaxGapUs = 5'000'000;
constexpr int64_t kJumpGapUs = 1'000'000;
// A pipe or terminal that goes quiet, or a file without line ends (/dev/zero), must not hold a
// Read: it waits at most this long for bytes, and reads at most this many chunks per call, so
// that the link thread sees a stop request within a second.
constexpr int kWaitForBytesMs = 100;
constexpr int kMaxChunksPerCall = 64;

// Splits a file into lines ('\n'-terminated; the last line may lack it), reading it in chunks.
class LineReader {
 public:
  explicit LineReader(UniqueFd fd) : fd_(std::move(fd)) {}

  // The next line without its '\n' (valid until the next call), or nothing at the end of the
  // file, on a read error (see error()), or when no line was complete after waiting
  // kWaitForBytesMs for bytes or reading kMaxChunksPerCall chunks (ended() tells which). An
  // over-long line comes back truncated with `overlong` set.
  std::optional<std::string_view> Next(bool& overlong) {
    overlong = false;
    int chunks = 0;
    while (true) {
      const size_t newline = buffer_.find('\n', scan_from_);
      if (newline != std::string::npos) {
        const std::string_view line(buffer_.data() + start_, newline - start_);
        start_ = scan_from_ = newline + 1;
        if (skipping_) {  // the tail of an over-long line: already reported
          skipping_ = false;
          continue;
        }
        return line;
      }
      if (buffer_.size() - start_ > kMaxLineBytes) {
        const std::string_view line(buffer_.data() + start_, kMaxLineBytes);
        start_ = scan_from_ = buffer_.size();
        const bool report = !skipping_;
        skipping_ = true;
        if (report) {
          overlong = true;
          return line;
        }
        continue;
      }
      scan_from_ = buffer_.size();
      if (eof_) {
        if (start_ == buffer_.size() || skipping_) return std::nullopt;
        const std::string_view line(buffer_.data() + start_, buffer_.size() - start_);
        start_ = scan_from_ = buffer_.size();
        return line;
      }
      if (chunks++ == kMaxChunksPerCall || !Fill()) return std::nullopt;  // not yet
    }
  }

  // True once the file has ended (or failed): nothing more will come.
  bool ended() const { return eof_; }
  int error() const { return error_; }

 private:
  // Drops consumed bytes and appends the next chunk of the file. False when no byte came within
  // kWaitForBytesMs (a quiet pipe or terminal: the descriptor is non-blocking).
  bool Fill() {
    pollfd p{fd_.get(), POLLIN, 0};
    int ready;
    do {
      ready = ::poll(&p, 1, kWaitForBytesMs);
    } while (ready < 0 && errno == EINTR);
    if (ready == 0) return false;
    buffer_.erase(0, start_);
    scan_from_ -= start_;
    start_ = 0;
    const size_t old_size = buffer_.size();
    buffer_.resize(old_size + kReadChunk);
    ssize_t n;
    do {
      n = ::read(fd_.get(), buffer_.data() + old_size, kReadChunk);
    } while (n < 0 && errno == EINTR);
    buffer_.resize(old_size + (n > 0 ? static_cast<size_t>(n) : 0));
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) return false;
    if (n <= 0) {
      eof_ = true;
      if (n < 0) error_ = errno;
    }
    return true;
  }

  UniqueFd fd_;
  std::string buffer_;
  size_t start_ = 0;      // first byte of the next line
  size_t scan_from_ = 0;  // where to look for the next '\n'
  bool skipping_ = false;
  bool eof_ = false;
  int error_ = 0;
};

class CandumpReplay final : public FrameSource {
 public:
  CandumpReplay(std::string path, UniqueFd fd, const CandumpReplayOptions& options)
      : path_(std::move(path)), lines_(std::move(fd)), options_(options) {}

  ReadOutcome Read(std::vector<TimedFrame>& out, std::chrono::milliseconds timeout) override {
    return options_.paced ? ReadPaced(out, timeout) : ReadUnpaced(out);
  }

  std::string Describe() const override {
    std::string text = "candump:" + path_;
    if (!errors_.empty()) text += " (" + errors_.front() + ")";
    return text;
  }

  SourceCounters Counters() const override {
    return {{"lines", lines_read_},
            {"frames", frames_},
            {"ignored_lines", ignored_},
            {"bad_lines", bad_},
            {"first_bad_line", first_bad_line_},
            {"clock_jumps", clock_jumps_}};
  }

 private:
  struct Pending {
    TimedFrame frame;
    int64_t time_us = 0;
  };

  // Reads lines up to the next frame; nothing at the end of the file or after too many lines.
  std::optional<Pending> NextFrame() {
    for (size_t lines = 0; lines < kMaxLinesPerRead; ++lines) {
      bool overlong = false;
      const std::optional<std::string_view> line = lines_.Next(overlong);
      if (!line) {
        ended_ = lines_.ended();  // otherwise nothing yet: the next Read goes on
        return std::nullopt;
      }
      ++lines_read_;
      if (overlong) {
        NoteBadLine("line too long");
        continue;
      }
      CandumpLine parsed = ParseCandumpLine(*line);
      switch (parsed.kind) {
        case CandumpLineKind::kIgnored:
          ++ignored_;
          break;
        case CandumpLineKind::kError:
          NoteBadLine(parsed.error);
          break;
        case CandumpLineKind::kFrame: {
          ++frames_;
          Pending pending;
          pending.time_us = Continuous(parsed.time_us);
          pending.frame.frame = parsed.frame;
          pending.frame.t = static_cast<double>(pending.time_us) * 1e-6;
          pending.frame.source_t = static_cast<double>(parsed.time_us) * 1e-6;  // as logged
          pending.frame.after_gap = std::exchange(bad_since_frame_, false);
          return pending;
        }
      }
    }
    return std::nullopt;
  }

  // The log's time with clock jumps taken out (see kMaxGapUs).
  // Each frame moves time on by at most kMaxGapUs, so it cannot overflow in any real log.
  int64_t Continuous(int64_t logged_us) {
    int64_t out_us = logged_us;
    if (last_logged_us_) {
      const int64_t step = logged_us - *last_logged_us_;  // both >= 0: cannot overflow
      if (step < 0 || step > kMaxGapUs) ++clock_jumps_;
      out_us = last_out_us_ + (step < 0 || step > kMaxGapUs ? kJumpGapUs : step);
    }
    last_logged_us_ = logged_us;
    last_out_us_ = out_us;
    return out_us;
  }

  void NoteBadLine(const std::string& reason) {
    ++bad_;
    bad_since_frame_ = true;
    if (first_bad_line_ == 0) first_bad_line_ = lines_read_;
    if (errors_.size() < kKeptErrors) {
      errors_.push_back("bad line " + std::to_string(lines_read_) + ": " + reason);
    }
  }

  // What to return once the file gave no more frames in this call: a read error is reported
  // once, then the log has ended.
  ReadOutcome EndOutcome(bool appended) {
    if (lines_.error() != 0 && !error_reported_) {
      error_reported_ = true;
      return {ReadStatus::kError,
              "candump:" + path_ + ": read error: " + ErrnoText(lines_.error())};
    }
    return {appended ? ReadStatus::kOk : ReadStatus::kEnd, {}};
  }

  ReadOutcome ReadUnpaced(std::vector<TimedFrame>& out) {
    const size_t before = out.size();
    const int64_t now_ns = SteadyNowNs();
    while (!ended_ && out.size() - before < kMaxFramesPerRead) {
      std::optional<Pending> next = NextFrame();
      if (!next) {
        if (!ended_) return {};  // a long run of non-frame lines: continue on the next Read
        break;
      }
      next->frame.receive_ns = now_ns;
      out.push_back(next->frame);
    }
    if (ended_) return EndOutcome(out.size() > before);
    return {};
  }

  // Releases each frame when (log time - first log time) / speed of steady time has passed
  // since the first Read.
  ReadOutcome ReadPaced(std::vector<TimedFrame>& out, std::chrono::milliseconds timeout) {
    const size_t before = out.size();
    const int64_t start_ns = SteadyNowNs();
    const int64_t deadline_ns = start_ns + std::max<int64_t>(0, timeout.count()) * 1'000'000;
    if (!started_) {
      started_ = true;
      replay_start_ns_ = start_ns;
    }
    while (out.size() - before < kMaxFramesPerRead) {
      if (!pending_) {
        if (ended_) break;
        pending_ = NextFrame();
        if (!pending_) {
          if (ended_) break;
          return {};  // a long run of non-frame lines
        }
        if (!first_log_us_) first_log_us_ = pending_->time_us;
      }
      const double offset_ns =
          static_cast<double>(pending_->time_us - *first_log_us_) * 1e3 / options_.speed;
      const int64_t due_ns =
          replay_start_ns_ + static_cast<int64_t>(std::clamp(offset_ns, 0.0, kMaxOffsetNs));
      const int64_t now_ns = SteadyNowNs();
      if (due_ns <= now_ns) {
        pending_->frame.receive_ns = now_ns;
        out.push_back(pending_->frame);
        pending_.reset();
        continue;
      }
      if (out.size() > before || now_ns >= deadline_ns) return {};
      std::this_thread::sleep_for(std::chrono::nanoseconds(std::min(due_ns, deadline_ns) - now_ns));
    }
    if (ended_ && !pending_) return EndOutcome(out.size() > before);
    return {};
  }

  std::string path_;
  LineReader lines_;
  CandumpReplayOptions options_;
  bool ended_ = false;
  bool error_reported_ = false;
  uint64_t lines_read_ = 0;
  uint64_t frames_ = 0;
  uint64_t ignored_ = 0;
  uint64_t bad_ = 0;
  bool bad_since_frame_ = false;  // a bad line since the last frame: it may have been one
  uint64_t first_bad_line_ = 0;   // 1-based; 0 = none
  std::vector<std::string> errors_;
  std::optional<int64_t> last_logged_us_;
  int64_t last_out_us_ = 0;  // the previous frame's time with the jumps taken out
  uint64_t clock_jumps_ = 0;
  // Paced replay only.
  bool started_ = false;
  int64_t replay_start_ns_ = 0;
  std::optional<int64_t> first_log_us_;
  std::optional<Pending> pending_;
};

}  // namespace

OpenResult OpenCandumpReplay(const std::string& path, const CandumpReplayOptions& options) {
  if (options.paced && !(std::isfinite(options.speed) && options.speed > 0.0)) {
    return Error("candump replay speed must be a positive number, got " +
                 std::to_string(options.speed));
  }
  UniqueFd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (!fd.valid()) {
    const int err = errno;
    return Error("cannot open candump log '" + path + "': " + ErrnoText(err));
  }
  struct stat info {};
  if (::fstat(fd.get(), &info) == 0 && S_ISDIR(info.st_mode)) {
    return Error("cannot open candump log '" + path + "': " + ErrnoText(EISDIR));
  }
  // A pipe or terminal may go quiet: reads wait in poll() with a timeout instead (LineReader).
  const int flags = ::fcntl(fd.get(), F_GETFL);
  if (flags >= 0) ::fcntl(fd.get(), F_SETFL, flags | O_NONBLOCK);
  return std::make_unique<CandumpReplay>(path, std::move(fd), options);
}

}  // namespace slam::hw
