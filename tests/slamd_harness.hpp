#pragma once
// The black-box harness of the slamd process tests (slamd_http_test.cpp, faults_test.cpp,
// security_test.cpp): spawning slamd as a child process and reading its serving line, HTTP through
// httplib's client and through raw sockets, an event-stream reader, /metrics parsing, bounded
// waits, and the fixture that shares one slamd per suite. Declarations only: the definitions are
// in slamd_harness.cpp, compiled once into the slamd_test_support library.
//
// The slamd binary is `$SLAMD_BIN` if set (to run the tests against another build), else the one
// built with the tests (SLAMD_BIN); slam-sim is `$SLAM_SIM_BIN`, else `tools/slam-sim` of
// slamd's build tree.

#include <gtest/gtest.h>
#include <httplib.h>
#include <sys/types.h>

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <ostream>
#include <set>
#include <string>
#include <thread>
#include <vector>

// SLAMD_RSS_UNMEASURABLE: resident memory measures slamd's own memory only without a
// sanitizer's allocator: under AddressSanitizer freed memory sits in quarantine (up to 256 MB),
// and under ThreadSanitizer every byte the program touches maps several bytes of shadow and
// history besides. The Release run checks memory; the sanitized runs check everything else.
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)  // GCC
#define SLAMD_RSS_UNMEASURABLE 1
#elif defined(__has_feature)  // Clang
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define SLAMD_RSS_UNMEASURABLE 1
#endif
#endif

namespace slamd_test {

namespace fs = std::filesystem;
using json = nlohmann::json;
using Clock = std::chrono::steady_clock;

// ---------------------------------------------------------------------------------------------
// Small utilities

std::string SlamdBinary();

/// slam-sim sits in the build tree next to slamd: <build>/server/slamd -> <build>/tools/slam-sim.
std::string SlamSimBinary();

Clock::time_point After(double seconds);

double SecondsSince(Clock::time_point start);

void Nap();

std::string Lower(std::string text);

bool StartsWith(const std::string& text, const std::string& prefix);

std::string ReadFile(const fs::path& path);

/// A loopback TCP port free at the time of the call (for a server whose port 0 means "off").
int FreeTcpPort();

void WriteFile(const fs::path& path, const std::string& text);

/// A fresh directory under the test temp dir, removed by the destructor.
class ScratchDir {
 public:
  explicit ScratchDir(const std::string& name);
  ~ScratchDir();
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

// ---------------------------------------------------------------------------------------------
// The slamd child process

class SlamdProcess {
 public:
  SlamdProcess() = default;
  SlamdProcess(const SlamdProcess&) = delete;
  SlamdProcess& operator=(const SlamdProcess&) = delete;
  ~SlamdProcess();

  /// The --speed of the next Spawn (sim and candump sources; default 4).
  void set_speed(double speed);

  /// Spawns slamd with the common flags plus `extra_args`; does not wait for anything.
  bool Spawn(const std::vector<std::string>& extra_args, std::string* error);

  /// Spawns slamd and waits (bounded) for its "serving" line and a healthy /api/v1/health.
  bool Start(const std::vector<std::string>& extra_args, std::string* error);

  /// Waits (bounded) for the process to exit by itself; its exit code, or 128 + signal.
  std::optional<int> WaitExit(double timeout_s);

  /// SIGTERM, then SIGKILL after 5 s; reaps the process. Returns its exit status (idempotent).
  std::optional<int> Stop();

  std::string Stderr() const;
  std::string Stdout();
  const std::string& host() const { return host_; }
  int port() const { return port_; }
  const std::string& url() const { return url_; }
  const std::string& serving_line() const { return serving_line_; }
  pid_t pid() const { return pid_; }

 private:
  /// Reaps the child if it has exited; true once it has.
  bool Exited();

  void DrainStdout();

  static int spawn_counter_;
  std::string speed_ = "4";
  pid_t pid_ = -1;
  std::optional<int> exit_status_;
  int stdout_fd_ = -1;
  std::thread drain_thread_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::string stdout_text_;
  bool stdout_closed_ = false;
  fs::path stderr_path_;
  std::string command_line_;
  std::string host_;
  int port_ = 0;
  std::string url_;
  std::string serving_line_;
};

// ---------------------------------------------------------------------------------------------
// HTTP through httplib's client

struct Reply {
  int status = -1;  // -1: transport failure (see `error`)
  std::string error;
  httplib::Headers headers;
  std::string body;

  std::string Header(const std::string& name) const;
  bool HasHeader(const std::string& name) const;
  std::string ContentType() const;
  json Json() const;
};

std::ostream& operator<<(std::ostream& out, const Reply& reply);

class Http {
 public:
  Http(const std::string& host, int port);

  Reply Get(const std::string& path, const httplib::Headers& headers = {});

  /// Any method; `content_type` empty sends no Content-Type.
  Reply Send(const std::string& method, const std::string& path, const std::string& body,
             const std::string& content_type, const httplib::Headers& headers = {});

  Reply PostJson(const std::string& path, const std::string& body,
                 const httplib::Headers& headers = {});
  Reply MergePatch(const std::string& path, const std::string& body,
                   const httplib::Headers& headers = {});
  Reply PutJson(const std::string& path, const std::string& body,
                const httplib::Headers& headers = {});

 private:
  httplib::Client client_;
};

/// GET `path` and its JSON body (fails the test if it is not 200 JSON).
json GetJson(Http& http, const std::string& path);

/// Checks an RFC 9457 problem with `status` and returns it (null json if it is not one).
json ExpectProblem(const Reply& reply, int status);

/// The JSON pointers of a 422 problem's `errors` (each error must have a pointer and a detail).
std::multiset<std::string> ErrorPointers(const json& problem);

/// A 422 whose errors point exactly at `pointers` (one error per problem).
void Expect422At(const Reply& reply, const std::multiset<std::string>& pointers);

// ---------------------------------------------------------------------------------------------
// Raw sockets: requests httplib's client cannot send, and the event stream

int ConnectTo(int port);

bool SendAll(int fd, const std::string& data);

/// Reads what is available within `timeout_s`; 0 on EOF or error, -1 on timeout.
ssize_t ReadSome(int fd, std::string& into, double timeout_s);

struct RawReply {
  int status = -1;
  std::map<std::string, std::string> headers;  // lower-case names
  std::string body;
  double seconds = 0.0;
  std::string raw;

  std::string Header(const std::string& name) const;
};

std::ostream& operator<<(std::ostream& out, const RawReply& reply);

/// Sends `request` verbatim and reads one response (until its Content-Length, or EOF).
RawReply RawExchange(int port, const std::string& request, double timeout_s = 5.0);

struct SseEvent {
  std::string name = "message";
  std::string id;
  bool has_id = false;
  std::string data;
  json Json() const;
  int64_t Id() const;
};

/// A minimal text/event-stream reader over a plain socket (handles chunked framing).
class EventStream {
 public:
  EventStream() = default;
  EventStream(const EventStream&) = delete;
  EventStream& operator=(const EventStream&) = delete;
  ~EventStream();

  /// Connects and reads the response head; the HTTP status (or -1).
  int Open(int port, const std::string& last_event_id = "", double timeout_s = 5.0);

  /// The next event (comments are counted, not returned); nullopt on timeout or end of stream.
  std::optional<SseEvent> Next(double timeout_s);

  /// The next event called `name`, skipping others; nullopt if none within `timeout_s`.
  std::optional<SseEvent> WaitFor(const std::string& name, double timeout_s);

  void Close();

  std::string Header(const std::string& name) const;
  int status() const { return status_; }
  bool ended() const { return ended_; }

 private:
  /// Moves complete bytes from the wire buffer to the text buffer, undoing chunked framing.
  void Decode();

  std::optional<SseEvent> ParseEvent();

  int fd_ = -1;
  int status_ = -1;
  std::map<std::string, std::string> headers_;
  bool chunked_ = false;
  bool ended_ = false;
  std::string wire_;
  std::string text_;
};

// ---------------------------------------------------------------------------------------------
// Prometheus text format

struct MetricSample {
  std::string name;
  std::map<std::string, std::string> labels;
  double value = 0.0;
};

std::vector<MetricSample> ParseMetrics(const std::string& text);

/// The sum of every sample of `name` whose labels include `labels`; nullopt if none.
std::optional<double> Metric(const std::vector<MetricSample>& samples, const std::string& name,
                             const std::map<std::string, std::string>& labels = {});

std::vector<MetricSample> GetMetrics(Http& http);

/// Polls /metrics until `name` satisfies `done`; its last value.
template <typename Predicate>
inline std::optional<double> PollMetric(Http& http, const std::string& name, double timeout_s,
                                        Predicate done) {
  const auto deadline = After(timeout_s);
  std::optional<double> value;
  while (true) {
    value = Metric(GetMetrics(http), name);
    if (value && done(*value)) return value;
    if (Clock::now() >= deadline) return value;
    Nap();
  }
}

// ---------------------------------------------------------------------------------------------
// Map helpers

/// Resident memory of `pid` in MiB (VmRSS), or -1.
double RssMib(pid_t pid);

/// Polls GET /api/v1/map until it lists at least `min_tiles` tiles; the last index.
json WaitForTiles(Http& http, size_t min_tiles, double timeout_s = 15.0);

/// Polls the JSON trajectory until its SLAM part has at least `min_poses` poses.
json WaitForTrajectory(Http& http, size_t min_poses, double timeout_s = 15.0);

int64_t MapVersion(Http& http);

/// Big-endian 32-bit integer at `at` (PNG header fields).
uint32_t BigEndian32(const std::string& bytes, size_t at);

extern const std::string kPngSignature;

/// TUM lines "t x y z qx qy qz qw" (comments skipped).
std::vector<std::vector<double>> ParseTum(const std::string& text);

extern const std::string kBudgetPath;
extern const std::string kParamsPath;
extern const std::string kMergePatch;

// ---------------------------------------------------------------------------------------------
// Fixtures

/// One slamd for a whole suite: the derived fixture's SetUpTestSuite calls StartShared with its
/// flags (added to the command line) and TearDownTestSuite StopShared.
class SlamdSuite : public ::testing::Test {
 protected:
  static void StartShared(const std::vector<std::string>& flags);
  static void StopShared();
  void SetUp() override;
  int port() const { return slamd_->port(); }
  Http& http() { return *http_; }

  static std::unique_ptr<SlamdProcess> slamd_;
  static std::string start_error_;
  std::unique_ptr<Http> http_;
};

}  // namespace slamd_test
