// The definitions of the slamd black-box harness (tests/slamd_harness.hpp).

#include "tests/slamd_harness.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>

namespace slamd_test {

// ---------------------------------------------------------------------------------------------
// Small utilities

std::string SlamdBinary() {
  const char* from_env = std::getenv("SLAMD_BIN");
  return from_env != nullptr && *from_env != '\0' ? std::string(from_env) : std::string(SLAMD_BIN);
}

std::string SlamSimBinary() {
  const char* from_env = std::getenv("SLAM_SIM_BIN");
  if (from_env != nullptr && *from_env != '\0') return from_env;
  return (fs::path(SlamdBinary()).parent_path() / ".." / "tools" / "slam-sim").string();
}

Clock::time_point After(double seconds) {
  return Clock::now() + std::chrono::microseconds(static_cast<int64_t>(seconds * 1e6));
}

double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

void Nap() { std::this_thread::sleep_for(std::chrono::milliseconds(50)); }

std::string Lower(std::string text) {
  std::transform(text.begin(), text.end(), text.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return text;
}

bool StartsWith(const std::string& text, const std::string& prefix) {
  return text.compare(0, prefix.size(), prefix) == 0;
}

std::string ReadFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream out;
  out << in.rdbuf();
  return out.str();
}

void WriteFile(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

ScratchDir::ScratchDir(const std::string& name)
    : path_(fs::path(::testing::TempDir()) /
            ("slamd_http_" + std::to_string(::getpid()) + "_" + name)) {
  fs::remove_all(path_);
  fs::create_directories(path_);
}

ScratchDir::~ScratchDir() {
  std::error_code ec;
  fs::remove_all(path_, ec);
}

// ---------------------------------------------------------------------------------------------
// The slamd child process

int FreeTcpPort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return 0;
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t length = sizeof address;
  int port = 0;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0 &&
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length) == 0) {
    port = ntohs(address.sin_port);
  }
  ::close(fd);
  return port;
}

int SlamdProcess::spawn_counter_ = 0;

SlamdProcess::~SlamdProcess() {
  Stop();
  std::error_code ec;
  if (!stderr_path_.empty()) fs::remove(stderr_path_, ec);
}

void SlamdProcess::set_speed(double speed) { speed_ = std::to_string(speed); }

bool SlamdProcess::Spawn(const std::vector<std::string>& extra_args, std::string* error) {
  std::vector<std::string> args = {SlamdBinary(), "--port", "0", "--speed", speed_, "--quiet"};
  // The Foxglove server's default port is fixed (8765): tests running side by side would take
  // it from one another. Off unless a test asks for a port.
  if (std::find(extra_args.begin(), extra_args.end(), "--foxglove-port") == extra_args.end()) {
    args.insert(args.end(), {"--foxglove-port", "0"});
  }
  args.insert(args.end(), extra_args.begin(), extra_args.end());
  command_line_.clear();
  for (const auto& arg : args) command_line_ += arg + " ";
  stderr_path_ = fs::path(::testing::TempDir()) / ("slamd_stderr_" + std::to_string(::getpid()) +
                                                   "_" + std::to_string(++spawn_counter_) + ".txt");
  int pipe_fds[2];
  if (::pipe2(pipe_fds, O_CLOEXEC) != 0) {
    *error = std::string("pipe2: ") + std::strerror(errno);
    return false;
  }
  // Everything the child needs is prepared before fork: only async-signal-safe calls after.
  std::vector<char*> argv;
  for (auto& arg : args) argv.push_back(arg.data());
  argv.push_back(nullptr);
  const std::string stderr_path = stderr_path_.string();
  const pid_t parent = ::getpid();
  const pid_t pid = ::fork();
  if (pid < 0) {
    *error = std::string("fork: ") + std::strerror(errno);
    ::close(pipe_fds[0]);
    ::close(pipe_fds[1]);
    return false;
  }
  if (pid == 0) {
    // A crashed test binary must not leave slamd behind.
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (::getppid() != parent) ::_exit(127);
    ::dup2(pipe_fds[1], STDOUT_FILENO);
    const int err_fd = ::open(stderr_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (err_fd >= 0) ::dup2(err_fd, STDERR_FILENO);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  ::close(pipe_fds[1]);
  pid_ = pid;
  exit_status_.reset();
  stdout_fd_ = pipe_fds[0];
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stdout_text_.clear();
    stdout_closed_ = false;
  }
  // The pipe is drained continuously so that slamd can never block on its stdout.
  drain_thread_ = std::thread([this] { DrainStdout(); });
  return true;
}

bool SlamdProcess::Start(const std::vector<std::string>& extra_args, std::string* error) {
  if (!Spawn(extra_args, error)) return false;
  const std::string marker = "slamd: serving http://";
  std::string line;
  {
    std::unique_lock<std::mutex> lock(mutex_);
    const bool got = cv_.wait_until(lock, After(20.0), [&] {
      const size_t at = stdout_text_.find(marker);
      return stdout_closed_ ||
             (at != std::string::npos && stdout_text_.find('\n', at) != std::string::npos);
    });
    const size_t at = stdout_text_.find(marker);
    if (!got || at == std::string::npos) {
      *error = "no 'slamd: serving' line from `" + command_line_ + "`; stdout: " + stdout_text_ +
               "; stderr: " + Stderr();
      return false;
    }
    line = stdout_text_.substr(at, stdout_text_.find('\n', at) - at);
  }
  // "slamd: serving http://127.0.0.1:PORT/ (source ...)"
  const std::string rest = line.substr(marker.size());
  const size_t colon = rest.find(':');
  const size_t slash = rest.find('/');
  if (colon == std::string::npos || slash == std::string::npos || slash < colon) {
    *error = "cannot parse the serving line: " + line;
    return false;
  }
  host_ = rest.substr(0, colon);
  port_ = std::atoi(rest.substr(colon + 1, slash - colon - 1).c_str());
  url_ = "http://" + rest.substr(0, slash + 1);
  serving_line_ = line;
  if (port_ <= 0) {
    *error = "bad port in: " + line;
    return false;
  }
  httplib::Client client(host_, port_);
  client.set_connection_timeout(1);
  client.set_read_timeout(2);
  const auto deadline = After(10.0);
  while (Clock::now() < deadline) {
    auto result = client.Get("/api/v1/health");
    if (result && result->status == 200) return true;
    if (Exited()) break;
    Nap();
  }
  *error = "slamd did not become healthy: " + line + "; stderr: " + Stderr();
  return false;
}

std::optional<int> SlamdProcess::WaitExit(double timeout_s) {
  const auto deadline = After(timeout_s);
  while (true) {
    if (Exited()) return exit_status_;
    if (Clock::now() >= deadline) return std::nullopt;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

std::optional<int> SlamdProcess::Stop() {
  if (pid_ > 0 && !Exited()) {
    ::kill(pid_, SIGTERM);
    if (!WaitExit(5.0)) {
      ::kill(pid_, SIGKILL);
      WaitExit(5.0);
    }
  }
  if (drain_thread_.joinable()) drain_thread_.join();
  if (stdout_fd_ >= 0) {
    ::close(stdout_fd_);
    stdout_fd_ = -1;
  }
  return exit_status_;
}

std::string SlamdProcess::Stderr() const { return ReadFile(stderr_path_); }

std::string SlamdProcess::Stdout() {
  std::lock_guard<std::mutex> lock(mutex_);
  return stdout_text_;
}

bool SlamdProcess::Exited() {
  if (exit_status_) return true;
  if (pid_ <= 0) return true;
  int status = 0;
  const pid_t got = ::waitpid(pid_, &status, WNOHANG);
  if (got == pid_) {
    exit_status_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    return true;
  }
  return false;
}

void SlamdProcess::DrainStdout() {
  char buffer[4096];
  while (true) {
    const ssize_t n = ::read(stdout_fd_, buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    std::lock_guard<std::mutex> lock(mutex_);
    if (n <= 0) {
      stdout_closed_ = true;
      cv_.notify_all();
      return;
    }
    stdout_text_.append(buffer, static_cast<size_t>(n));
    cv_.notify_all();
  }
}

// ---------------------------------------------------------------------------------------------
// HTTP through httplib's client

std::string Reply::Header(const std::string& name) const {
  for (const auto& [key, value] : headers) {
    if (Lower(key) == Lower(name)) return value;
  }
  return "";
}

bool Reply::HasHeader(const std::string& name) const {
  for (const auto& entry : headers) {
    if (Lower(entry.first) == Lower(name)) return true;
  }
  return false;
}

std::string Reply::ContentType() const { return Header("Content-Type"); }

json Reply::Json() const {
  json parsed = json::parse(body, nullptr, /*allow_exceptions=*/false);
  return parsed;
}

std::ostream& operator<<(std::ostream& out, const Reply& reply) {
  out << "HTTP " << reply.status << " " << reply.error << " [" << reply.ContentType() << "] "
      << reply.body.substr(0, 400);
  return out;
}

Http::Http(const std::string& host, int port) : client_(host, port) {
  client_.set_connection_timeout(2);
  client_.set_read_timeout(10);
  client_.set_write_timeout(5);
}

Reply Http::Get(const std::string& path, const httplib::Headers& headers) {
  return Send("GET", path, "", "", headers);
}

Reply Http::Send(const std::string& method, const std::string& path, const std::string& body,
                 const std::string& content_type, const httplib::Headers& headers) {
  httplib::Request request;
  request.method = method;
  request.path = path;
  request.headers = headers;
  request.body = body;
  if (!content_type.empty()) request.headers.emplace("Content-Type", content_type);
  auto result = client_.send(request);
  Reply reply;
  if (!result) {
    reply.error = httplib::to_string(result.error());
    return reply;
  }
  reply.status = result->status;
  reply.headers = result->headers;
  reply.body = result->body;
  return reply;
}

Reply Http::PostJson(const std::string& path, const std::string& body,
                     const httplib::Headers& headers) {
  return Send("POST", path, body, "application/json", headers);
}

Reply Http::MergePatch(const std::string& path, const std::string& body,
                       const httplib::Headers& headers) {
  return Send("PATCH", path, body, "application/merge-patch+json", headers);
}

Reply Http::PutJson(const std::string& path, const std::string& body,
                    const httplib::Headers& headers) {
  return Send("PUT", path, body, "application/json", headers);
}

json GetJson(Http& http, const std::string& path) {
  const Reply reply = http.Get(path);
  EXPECT_EQ(reply.status, 200) << path << ": " << reply;
  EXPECT_TRUE(StartsWith(reply.ContentType(), "application/json")) << path << ": " << reply;
  json parsed = reply.Json();
  EXPECT_FALSE(parsed.is_discarded()) << path << ": " << reply;
  return parsed.is_discarded() ? json() : parsed;
}

json ExpectProblem(const Reply& reply, int status) {
  EXPECT_EQ(reply.status, status) << reply;
  EXPECT_TRUE(StartsWith(reply.ContentType(), "application/problem+json")) << reply;
  json problem = reply.Json();
  EXPECT_TRUE(problem.is_object()) << reply;
  if (!problem.is_object()) return json();
  EXPECT_EQ(problem.value("status", -1), status) << reply;
  EXPECT_TRUE(problem.contains("title") && problem["title"].is_string()) << reply;
  EXPECT_TRUE(problem.contains("type") && problem["type"].is_string()) << reply;
  return problem;
}

std::multiset<std::string> ErrorPointers(const json& problem) {
  std::multiset<std::string> pointers;
  if (!problem.is_object() || !problem.contains("errors") || !problem["errors"].is_array()) {
    ADD_FAILURE() << "no errors[] in " << problem.dump();
    return pointers;
  }
  for (const auto& error : problem["errors"]) {
    EXPECT_TRUE(error.contains("pointer") && error["pointer"].is_string()) << error.dump();
    EXPECT_TRUE(error.contains("detail") && error["detail"].is_string()) << error.dump();
    if (error.contains("pointer") && error["pointer"].is_string()) {
      pointers.insert(error["pointer"].get<std::string>());
    }
  }
  return pointers;
}

void Expect422At(const Reply& reply, const std::multiset<std::string>& pointers) {
  const json problem = ExpectProblem(reply, 422);
  EXPECT_EQ(ErrorPointers(problem), pointers) << reply;
}

// ---------------------------------------------------------------------------------------------
// Raw sockets: requests httplib's client cannot send, and the event stream

namespace {

/// Parses "HTTP/1.1 CODE ...\r\nName: value\r\n...\r\n\r\n"; false if incomplete.
bool ParseHead(const std::string& raw, int* status, std::map<std::string, std::string>* headers,
               size_t* body_start) {
  const size_t end = raw.find("\r\n\r\n");
  if (end == std::string::npos) return false;
  std::istringstream head(raw.substr(0, end));
  std::string line;
  std::getline(head, line);
  *status = -1;
  if (StartsWith(line, "HTTP/1.") && line.size() >= 12) *status = std::atoi(line.c_str() + 9);
  while (std::getline(head, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const size_t colon = line.find(':');
    if (colon == std::string::npos) continue;
    std::string value = line.substr(colon + 1);
    while (!value.empty() && value.front() == ' ') value.erase(0, 1);
    (*headers)[Lower(line.substr(0, colon))] = value;
  }
  *body_start = end + 4;
  return true;
}

}  // namespace

int ConnectTo(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return -1;
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = htons(static_cast<uint16_t>(port));
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

bool SendAll(int fd, const std::string& data) {
  size_t sent = 0;
  while (sent < data.size()) {
    const ssize_t n = ::send(fd, data.data() + sent, data.size() - sent, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    sent += static_cast<size_t>(n);
  }
  return true;
}

ssize_t ReadSome(int fd, std::string& into, double timeout_s) {
  pollfd waiter{fd, POLLIN, 0};
  const int timeout_ms = std::max(0, static_cast<int>(timeout_s * 1000.0));
  const int ready = ::poll(&waiter, 1, timeout_ms);
  if (ready == 0) return -1;
  if (ready < 0) return errno == EINTR ? -1 : 0;
  char buffer[8192];
  const ssize_t n = ::recv(fd, buffer, sizeof buffer, 0);
  if (n <= 0) return 0;
  into.append(buffer, static_cast<size_t>(n));
  return n;
}

std::string RawReply::Header(const std::string& name) const {
  const auto it = headers.find(Lower(name));
  return it == headers.end() ? "" : it->second;
}

std::ostream& operator<<(std::ostream& out, const RawReply& reply) {
  out << "raw HTTP " << reply.status << " after " << reply.seconds
      << " s: " << reply.raw.substr(0, 400);
  return out;
}

RawReply RawExchange(int port, const std::string& request, double timeout_s) {
  RawReply reply;
  const auto start = Clock::now();
  const int fd = ConnectTo(port);
  if (fd < 0) return reply;
  SendAll(fd, request);  // the server may answer and close before reading everything
  const auto deadline = After(timeout_s);
  size_t body_start = 0;
  bool have_head = false;
  while (Clock::now() < deadline) {
    if (!have_head) {
      reply.headers.clear();
      have_head = ParseHead(reply.raw, &reply.status, &reply.headers, &body_start);
    }
    if (have_head && !reply.Header("Content-Length").empty()) {
      const size_t length = static_cast<size_t>(std::atol(reply.Header("Content-Length").c_str()));
      if (reply.raw.size() >= body_start + length) break;
    }
    const double left = std::chrono::duration<double>(deadline - Clock::now()).count();
    if (ReadSome(fd, reply.raw, left) == 0) break;
  }
  ::close(fd);
  if (!have_head) {
    reply.headers.clear();
    have_head = ParseHead(reply.raw, &reply.status, &reply.headers, &body_start);
  }
  if (have_head) reply.body = reply.raw.substr(body_start);
  if (!have_head) reply.status = -1;
  reply.seconds = SecondsSince(start);
  return reply;
}

json SseEvent::Json() const { return json::parse(data, nullptr, false); }

int64_t SseEvent::Id() const { return std::atoll(id.c_str()); }

EventStream::~EventStream() { Close(); }

int EventStream::Open(int port, const std::string& last_event_id, double timeout_s) {
  Close();
  fd_ = ConnectTo(port);
  if (fd_ < 0) return -1;
  std::string request = "GET /api/v1/events HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(port) +
                        "\r\nAccept: text/event-stream\r\nCache-Control: no-cache\r\n";
  if (!last_event_id.empty()) request += "Last-Event-ID: " + last_event_id + "\r\n";
  request += "\r\n";
  if (!SendAll(fd_, request)) return -1;
  const auto deadline = After(timeout_s);
  std::string raw;
  size_t body_start = 0;
  while (!ParseHead(raw, &status_, &headers_, &body_start)) {
    const double left = std::chrono::duration<double>(deadline - Clock::now()).count();
    if (left <= 0 || ReadSome(fd_, raw, left) <= 0) return -1;
  }
  chunked_ = Lower(Header("Transfer-Encoding")).find("chunked") != std::string::npos;
  wire_ = raw.substr(body_start);
  Decode();
  return status_;
}

std::optional<SseEvent> EventStream::Next(double timeout_s) {
  const auto deadline = After(timeout_s);
  while (true) {
    if (auto event = ParseEvent()) return event;
    if (ended_ || fd_ < 0) return std::nullopt;
    const double left = std::chrono::duration<double>(deadline - Clock::now()).count();
    if (left <= 0) return std::nullopt;
    const ssize_t n = ReadSome(fd_, wire_, left);
    if (n == 0) ended_ = true;
    Decode();
  }
}

std::optional<SseEvent> EventStream::WaitFor(const std::string& name, double timeout_s) {
  const auto deadline = After(timeout_s);
  while (Clock::now() < deadline) {
    const double left = std::chrono::duration<double>(deadline - Clock::now()).count();
    auto event = Next(left);
    if (!event) return std::nullopt;
    if (event->name == name) return event;
  }
  return std::nullopt;
}

void EventStream::Close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  wire_.clear();
  text_.clear();
  headers_.clear();
  ended_ = false;
}

std::string EventStream::Header(const std::string& name) const {
  const auto it = headers_.find(Lower(name));
  return it == headers_.end() ? "" : it->second;
}

void EventStream::Decode() {
  if (!chunked_) {
    text_ += wire_;
    wire_.clear();
    return;
  }
  while (true) {
    const size_t line_end = wire_.find("\r\n");
    if (line_end == std::string::npos) return;
    const size_t size = std::strtoul(wire_.substr(0, line_end).c_str(), nullptr, 16);
    if (size == 0) {
      ended_ = true;
      wire_.clear();
      return;
    }
    if (wire_.size() < line_end + 2 + size + 2) return;
    text_ += wire_.substr(line_end + 2, size);
    wire_.erase(0, line_end + 2 + size + 2);
  }
}

std::optional<SseEvent> EventStream::ParseEvent() {
  while (true) {
    // Events end with a blank line; accept \n\n and \r\n\r\n.
    size_t end = text_.find("\n\n");
    size_t skip = 2;
    const size_t end_crlf = text_.find("\r\n\r\n");
    if (end_crlf != std::string::npos && (end == std::string::npos || end_crlf < end)) {
      end = end_crlf;
      skip = 4;
    }
    if (end == std::string::npos) return std::nullopt;
    const std::string block = text_.substr(0, end);
    text_.erase(0, end + skip);
    SseEvent event;
    bool has_field = false;
    std::istringstream lines(block);
    std::string line;
    while (std::getline(lines, line)) {
      if (!line.empty() && line.back() == '\r') line.pop_back();
      if (line.empty()) continue;
      if (line.front() == ':') continue;  // a comment (keep-alive ping)
      const size_t colon = line.find(':');
      const std::string field = line.substr(0, colon);
      std::string value = colon == std::string::npos ? "" : line.substr(colon + 1);
      if (!value.empty() && value.front() == ' ') value.erase(0, 1);
      has_field = true;
      if (field == "event") event.name = value;
      if (field == "id") {
        event.id = value;
        event.has_id = true;
      }
      if (field == "data") event.data += (event.data.empty() ? "" : "\n") + value;
    }
    if (has_field) return event;
  }
}

// ---------------------------------------------------------------------------------------------
// Prometheus text format

std::vector<MetricSample> ParseMetrics(const std::string& text) {
  std::vector<MetricSample> samples;
  std::istringstream lines(text);
  std::string line;
  while (std::getline(lines, line)) {
    if (line.empty() || line.front() == '#') continue;
    MetricSample sample;
    size_t at = line.find_first_of("{ ");
    if (at == std::string::npos) continue;
    sample.name = line.substr(0, at);
    if (line[at] == '{') {
      const size_t close = line.find('}', at);
      if (close == std::string::npos) continue;
      const std::string labels = line.substr(at + 1, close - at - 1);
      size_t pos = 0;
      while (pos < labels.size()) {
        const size_t equal = labels.find('=', pos);
        const size_t open_quote = labels.find('"', equal);
        const size_t close_quote = labels.find('"', open_quote + 1);
        if (equal == std::string::npos || open_quote == std::string::npos ||
            close_quote == std::string::npos) {
          break;
        }
        std::string key = labels.substr(pos, equal - pos);
        key.erase(0, key.find_first_not_of(" ,"));
        sample.labels[key] = labels.substr(open_quote + 1, close_quote - open_quote - 1);
        pos = close_quote + 1;
      }
      at = close + 1;
    }
    sample.value = std::strtod(line.c_str() + at, nullptr);
    samples.push_back(sample);
  }
  return samples;
}

std::optional<double> Metric(const std::vector<MetricSample>& samples, const std::string& name,
                             const std::map<std::string, std::string>& labels) {
  std::optional<double> sum;
  for (const auto& sample : samples) {
    if (sample.name != name) continue;
    bool match = true;
    for (const auto& [key, value] : labels) {
      const auto it = sample.labels.find(key);
      if (it == sample.labels.end() || it->second != value) match = false;
    }
    if (match) sum = sum.value_or(0.0) + sample.value;
  }
  return sum;
}

std::vector<MetricSample> GetMetrics(Http& http) {
  const Reply reply = http.Get("/metrics");
  EXPECT_EQ(reply.status, 200) << reply;
  return ParseMetrics(reply.body);
}

// ---------------------------------------------------------------------------------------------
// Map helpers

double RssMib(pid_t pid) {
  std::istringstream lines(ReadFile("/proc/" + std::to_string(pid) + "/status"));
  std::string line;
  while (std::getline(lines, line)) {
    if (StartsWith(line, "VmRSS:")) return std::atof(line.c_str() + 6) / 1024.0;
  }
  return -1.0;
}

json WaitForTiles(Http& http, size_t min_tiles, double timeout_s) {
  const auto deadline = After(timeout_s);
  json map;
  while (true) {
    map = GetJson(http, "/api/v1/map");
    if (map.contains("tiles") && map["tiles"].is_array() && map["tiles"].size() >= min_tiles) {
      return map;
    }
    if (Clock::now() >= deadline) {
      ADD_FAILURE() << "fewer than " << min_tiles << " tiles after " << timeout_s
                    << " s: " << map.dump().substr(0, 300);
      return map;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
}

json WaitForTrajectory(Http& http, size_t min_poses, double timeout_s) {
  const auto deadline = After(timeout_s);
  json trajectory;
  while (true) {
    trajectory = GetJson(http, "/api/v1/trajectory");
    if (trajectory.contains("slam") && trajectory["slam"].is_array() &&
        trajectory["slam"].size() >= min_poses) {
      return trajectory;
    }
    if (Clock::now() >= deadline) {
      ADD_FAILURE() << "fewer than " << min_poses << " poses after " << timeout_s << " s";
      return trajectory;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
}

int64_t MapVersion(Http& http) {
  return GetJson(http, "/api/v1/map").value("version", int64_t{-1});
}

uint32_t BigEndian32(const std::string& bytes, size_t at) {
  uint32_t value = 0;
  for (size_t i = 0; i < 4; ++i) {
    value = (value << 8) | static_cast<uint32_t>(static_cast<unsigned char>(bytes[at + i]));
  }
  return value;
}

const std::string kPngSignature = "\x89PNG\r\n\x1a\n";

std::vector<std::vector<double>> ParseTum(const std::string& text) {
  std::vector<std::vector<double>> rows;
  std::istringstream lines(text);
  std::string line;
  while (std::getline(lines, line)) {
    if (line.empty() || line.front() == '#') continue;
    std::istringstream fields(line);
    std::vector<double> row;
    double value = 0.0;
    while (fields >> value) row.push_back(value);
    rows.push_back(row);
  }
  return rows;
}

const std::string kBudgetPath = "/api/v1/budget";
const std::string kParamsPath = "/api/v1/params";
const std::string kMergePatch = "application/merge-patch+json";

// ---------------------------------------------------------------------------------------------
// Fixtures

std::unique_ptr<SlamdProcess> SlamdSuite::slamd_;
std::string SlamdSuite::start_error_;

void SlamdSuite::StartShared(const std::vector<std::string>& flags) {
  slamd_ = std::make_unique<SlamdProcess>();
  std::string error;
  if (!slamd_->Start(flags, &error)) start_error_ = error;
}

void SlamdSuite::StopShared() {
  if (slamd_) slamd_->Stop();
  slamd_.reset();
  start_error_.clear();
}

void SlamdSuite::SetUp() {
  ASSERT_TRUE(slamd_ != nullptr);
  ASSERT_TRUE(start_error_.empty()) << start_error_;
  http_ = std::make_unique<Http>(slamd_->host(), slamd_->port());
}

}  // namespace slamd_test
