#include "server/http_server.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <httplib.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <thread>
#include <utility>

#include "engine/cell_encoding.hpp"
#include "engine/io/map_image.hpp"
#include "engine/io/params_json.hpp"
#include "engine/io/tum.hpp"
#include "engine/ray_cast.hpp"
#include "hw_link/status_json.hpp"
#include "server/state_store.hpp"

#ifndef SLAMD_VERSION
#define SLAMD_VERSION "0"
#endif

namespace slam::server {
namespace {

using json = nlohmann::json;
using Clock = std::chrono::steady_clock;

constexpr const char* kJson = "application/json; charset=utf-8";
constexpr const char* kProblem = "application/problem+json";
constexpr auto kStreamWake = std::chrono::milliseconds(250);  // <= 0.5 s: disconnects noticed
constexpr double kTilesEverySeconds = 0.5;
constexpr double kPoseEverySeconds = 0.25;
constexpr double kPingEverySeconds = 10.0;

double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

std::string Lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

/// The media type of a Content-Type header, lower case, without parameters.
std::string MediaType(const std::string& content_type) {
  std::string type = content_type.substr(0, content_type.find(';'));
  type.erase(0, type.find_first_not_of(" \t"));
  type.erase(type.find_last_not_of(" \t") + 1);
  return Lower(type);
}

/// JSON text of `body`; bytes that are not UTF-8 (a client's path or parameter echoed in an
/// error, say) become U+FFFD instead of throwing.
std::string Dump(const json& body) {
  return body.dump(-1, ' ', false, json::error_handler_t::replace);
}

void SendJson(httplib::Response& res, const json& body, int status = 200) {
  res.status = status;
  res.set_content(Dump(body), kJson);
}

void SendProblem(httplib::Response& res, int status, const std::string& title,
                 const std::string& detail, const ConfigErrors& errors = {}) {
  json body = {{"type", "about:blank"}, {"title", title}, {"status", status}, {"detail", detail}};
  if (!errors.empty()) {
    json list = json::array();
    for (const ConfigError& e : errors)
      list.push_back({{"pointer", e.pointer}, {"detail", e.detail}});
    body["errors"] = std::move(list);
  }
  res.status = status;
  res.set_content(Dump(body), kProblem);
}

json PoseJson(const TimedPose& p) {
  return {{"t", p.t}, {"x", p.pose.x}, {"y", p.pose.y}, {"theta", p.pose.theta}};
}

json BudgetJson(const BudgetSettings& b) {
  return {{"mode", ToString(b.mode)},
          {"rays_per_scan", b.rays_per_scan},
          {"cpu_share", b.cpu_share},
          {"policy", ToString(b.policy)},
          {"max_particles", b.max_particles}};
}

/// A whole budget object: every key required (PUT, and a PATCH after merging onto the
/// current object), no other key, right types; then the ranges of Validate.
ConfigErrors BudgetFromJson(const json& body, BudgetSettings& out) {
  ConfigErrors errors;
  if (!body.is_object()) return {{"", "must be a JSON object", 0}};
  static const std::vector<std::string> kKeys{"mode", "rays_per_scan", "cpu_share", "policy",
                                              "max_particles"};
  for (const auto& [key, value] : body.items()) {
    if (std::find(kKeys.begin(), kKeys.end(), key) == kKeys.end()) {
      errors.push_back({"/" + key, "unknown field", 0});
    }
  }
  bool missing = false;
  for (const std::string& key : kKeys) {
    if (!body.contains(key)) {
      errors.push_back({"/" + key, "required", 0});
      missing = true;
    }
  }
  if (missing) return errors;
  const size_t unknown = errors.size();
  BudgetSettings b;
  const auto mode =
      body["mode"].is_string() ? ParseQuotaMode(body["mode"].get<std::string>()) : std::nullopt;
  if (!mode) {
    errors.push_back({"/mode", "must be \"rays\" or \"cpu_share\"", 0});
  } else {
    b.mode = *mode;
  }
  const auto policy = body["policy"].is_string()
                          ? ParseBudgetPolicy(body["policy"].get<std::string>())
                          : std::nullopt;
  if (!policy) {
    errors.push_back({"/policy", "must be \"fixed\" or \"adaptive\"", 0});
  } else {
    b.policy = *policy;
  }
  const json& rays = body["rays_per_scan"];
  if (!rays.is_number_integer()) {
    errors.push_back({"/rays_per_scan", "must be an integer", 0});
  } else {
    b.rays_per_scan = rays.get<int64_t>();
  }
  const json& share = body["cpu_share"];
  if (!share.is_number()) {
    errors.push_back({"/cpu_share", "must be a number", 0});
  } else {
    b.cpu_share = share.get<double>();
  }
  const json& particles = body["max_particles"];
  if (!particles.is_number_integer()) {
    errors.push_back({"/max_particles", "must be an integer", 0});
  } else {
    const auto n = particles.get<int64_t>();
    b.max_particles = static_cast<int>(std::clamp<int64_t>(n, -1, 1 << 30));
  }
  // Ranges of the values whose type was right (a mistyped value has no range to check).
  std::vector<std::string> mistyped;
  for (size_t i = unknown; i < errors.size(); ++i) mistyped.push_back(errors[i].pointer);
  for (ConfigError& e : Validate(b)) {
    if (std::find(mistyped.begin(), mistyped.end(), e.pointer) == mistyped.end()) {
      errors.push_back(std::move(e));
    }
  }
  if (errors.empty()) out = b;
  return errors;
}

json MetricsEventJson(const SlamSnapshot& s) {
  const ScanMetrics& m = *s.last;
  return {{"scan", m.scan},
          {"t", s.pose.t},
          {"rays_planned", m.rays_planned},
          {"rays_used", m.rays_used},
          {"quota", m.quota},
          {"latency_ms", m.latency_s * 1e3},
          {"cpu_share", m.cpu_share},
          {"realtime_ratio", m.realtime_ratio},
          {"particles", m.particles},
          {"candidates", m.candidates},
          {"ess", m.ess},
          {"pose_error_m", m.pose_error_m ? json(*m.pose_error_m) : json(nullptr)}};
}

json PoseEventJson(const SlamSnapshot& s) {
  json j = PoseJson(s.pose);
  j["scan"] = s.last ? s.last->scan : 0;
  j["truth"] = s.truth ? json{{"x", s.truth->x}, {"y", s.truth->y}, {"theta", s.truth->theta}}
                       : json(nullptr);
  return j;
}

std::string Event(const std::string& name, uint64_t id, const json& data) {
  return "event: " + name + "\nid: " + std::to_string(id) + "\ndata: " + Dump(data) + "\n\n";
}

struct TileKey {
  int32_t x, y;
  friend bool operator<(const TileKey& a, const TileKey& b) {
    return a.x != b.x ? a.x < b.x : a.y < b.y;
  }
};

// ---------------------------------------------------------------------------------------------
// Connections with bounded requests
//
// cpp-httplib 0.11 bounds each header line (8 KiB) but not their number, nor the time a request
// may take to arrive: a client streaming header lines grew slamd by 1.2 GB in 8 s (measured), and
// one sending a byte every few seconds held a pool thread for ever. BoundedServer replaces the
// library's connection loop with the same loop over BoundedStream, which gives each request a
// byte budget (head plus the largest body allowed) and a deadline; past either, reads fail and
// the library answers 400 and closes the connection.

using SteadyTime = Clock::time_point;

class BoundedStream final : public httplib::Stream {
 public:
  /// `received`: bytes of the connection already read from the socket (by the gate), read first.
  BoundedStream(int fd, std::string received, std::chrono::milliseconds read_timeout,
                std::chrono::milliseconds write_timeout)
      : fd_(fd),
        read_timeout_(read_timeout),
        write_timeout_(write_timeout),
        buffer_(std::move(received)) {}

  /// The next request may read `bytes` more bytes, until `deadline`.
  void StartRequest(size_t bytes, SteadyTime deadline) {
    budget_ = bytes;
    deadline_ = deadline;
    exhausted_ = false;
    head_.clear();
    head_done_ = false;
  }
  /// The request's head as received (request line and header lines, up to the blank line;
  /// what has arrived so far while it is incomplete): the request guard checks its framing,
  /// which httplib's parser does not show as it was sent.
  const std::string& head() const { return head_; }
  /// True once a read was refused for the budget or the deadline.
  bool Exhausted() const { return exhausted_; }
  /// Bytes already received and not yet read (a pipelined request).
  bool HasBuffered() const { return begin_ < buffer_.size(); }
  /// Those bytes, taken out of the stream.
  std::string TakeBuffered() {
    std::string rest = buffer_.substr(begin_);
    buffer_.clear();
    begin_ = 0;
    return rest;
  }

  bool is_readable() const override { return HasBuffered() || Wait(POLLIN, ReadLimit()); }
  bool is_writable() const override { return Wait(POLLOUT, write_timeout_) && PeerOpen(); }

  ssize_t read(char* ptr, size_t size) override {
    if (budget_ == 0 || Clock::now() >= deadline_) {
      exhausted_ = true;
      return -1;
    }
    if (!HasBuffered()) {
      if (!Wait(POLLIN, ReadLimit())) {
        exhausted_ = Clock::now() >= deadline_;
        return -1;
      }
      char chunk[4096];
      ssize_t n;
      do {
        n = ::recv(fd_, chunk, sizeof chunk, 0);
      } while (n < 0 && errno == EINTR);
      if (n <= 0) return n;
      buffer_.assign(chunk, static_cast<size_t>(n));
      begin_ = 0;
    }
    const size_t n = std::min({size, buffer_.size() - begin_, budget_});
    std::memcpy(ptr, buffer_.data() + begin_, n);
    begin_ += n;
    budget_ -= n;
    if (!head_done_) {
      const size_t from = head_.size() >= 3 ? head_.size() - 3 : 0;
      head_.append(ptr, n);
      if (const size_t end = head_.find("\r\n\r\n", from); end != std::string::npos) {
        head_.resize(end + 2);
        head_done_ = true;
      }
    }
    return static_cast<ssize_t>(n);
  }

  ssize_t write(const char* ptr, size_t size) override {
    if (!Wait(POLLOUT, write_timeout_)) return -1;
    ssize_t n;
    do {
      n = ::send(fd_, ptr, size, MSG_NOSIGNAL);
    } while (n < 0 && errno == EINTR);
    return n;
  }

  void get_remote_ip_and_port(std::string& ip, int& port) const override {
    Address(::getpeername, ip, port);
  }
  void get_local_ip_and_port(std::string& ip, int& port) const override {
    Address(::getsockname, ip, port);
  }
  socket_t socket() const override { return fd_; }

 private:
  std::chrono::milliseconds ReadLimit() const {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline_ - Clock::now());
    return std::clamp(left, std::chrono::milliseconds(0), read_timeout_);
  }

  bool Wait(short events, std::chrono::milliseconds timeout) const {
    pollfd p{fd_, events, 0};
    int n;
    do {
      n = ::poll(&p, 1, static_cast<int>(timeout.count()));
    } while (n < 0 && errno == EINTR);
    return n > 0 && (p.revents & events) != 0;
  }

  // False once the peer has closed (an event stream's client went away).
  bool PeerOpen() const {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, 0) <= 0) return true;
    if ((p.revents & (POLLERR | POLLHUP | POLLNVAL)) != 0) return false;
    char byte;
    return ::recv(fd_, &byte, 1, MSG_PEEK | MSG_DONTWAIT) != 0;
  }

  template <typename Getter>
  void Address(Getter getter, std::string& ip, int& port) const {
    sockaddr_storage address{};
    socklen_t length = sizeof address;
    ip.clear();
    port = 0;
    if (getter(fd_, reinterpret_cast<sockaddr*>(&address), &length) != 0) return;
    char text[INET6_ADDRSTRLEN] = {};
    if (address.ss_family == AF_INET) {
      const auto* in = reinterpret_cast<const sockaddr_in*>(&address);
      ::inet_ntop(AF_INET, &in->sin_addr, text, sizeof text);
      port = ntohs(in->sin_port);
    } else if (address.ss_family == AF_INET6) {
      const auto* in = reinterpret_cast<const sockaddr_in6*>(&address);
      ::inet_ntop(AF_INET6, &in->sin6_addr, text, sizeof text);
      port = ntohs(in->sin6_port);
    }
    ip = text;
  }

  int fd_;
  std::chrono::milliseconds read_timeout_, write_timeout_;
  size_t budget_ = 0;
  SteadyTime deadline_{};
  bool exhausted_ = false;
  std::string buffer_;  // received and not yet read from begin_ on
  size_t begin_ = 0;
  std::string head_;
  bool head_done_ = false;
};

/// A request in memory and its response (HttpServer::HandleRaw): reads from the request bytes,
/// writes into a string until `cap` bytes, then reports itself unwritable (which ends an event
/// stream at its next wake-up).
class MemoryStream final : public httplib::Stream {
 public:
  MemoryStream(std::string_view request, size_t cap) : request_(request), cap_(cap) {}

  bool is_readable() const override { return read_ < request_.size(); }
  bool is_writable() const override { return response_.size() < cap_; }
  ssize_t read(char* ptr, size_t size) override {
    const size_t n = std::min(size, request_.size() - read_);
    if (n == 0) return 0;
    std::memcpy(ptr, request_.data() + read_, n);
    read_ += n;
    return static_cast<ssize_t>(n);
  }
  ssize_t write(const char* ptr, size_t size) override {
    if (!is_writable()) return -1;
    const size_t n = std::min(size, cap_ - response_.size());
    response_.append(ptr, n);
    return static_cast<ssize_t>(n);
  }
  void get_remote_ip_and_port(std::string& ip, int& port) const override {
    ip = "127.0.0.1";
    port = 40000;
  }
  void get_local_ip_and_port(std::string& ip, int& port) const override {
    ip = "127.0.0.1";
    port = 8080;
  }
  socket_t socket() const override { return INVALID_SOCKET; }

  std::string& response() { return response_; }

 private:
  std::string_view request_;
  size_t read_ = 0;
  size_t cap_;
  std::string response_;
};

/// Set by a handler of this thread that answered without reading the request's body: the
/// connection cannot carry another request (the unread body would be parsed as the next one).
/// httplib 0.11 closes a connection only when the request asks for it, whatever the response's
/// Connection header says, so the connection loop looks at this after each request.
thread_local bool t_close_connection = false;

/// The head of the request this thread is processing, as received (BoundedStream::head, or the
/// in-memory request), for the request guard; nullptr when unknown.
thread_local const std::string* t_request_head = nullptr;

/// Calls `visit(line)` for each field line of a request head as received (the lines after the
/// request line, up to the blank line or the end of what arrived), until it returns false.
template <typename Visit>
void ForEachFieldLine(std::string_view head, Visit visit) {
  size_t line_end = head.find("\r\n");
  if (line_end == std::string_view::npos) return;
  for (size_t at = line_end + 2; at < head.size(); at = line_end + 2) {
    line_end = head.find("\r\n", at);
    if (line_end == std::string_view::npos) line_end = head.size();
    const std::string_view line = head.substr(at, line_end - at);
    if (line.empty() || !visit(line)) return;
  }
}

/// Whether a field line names `name` (case-insensitive), with the colon right after it.
bool FieldNameIs(std::string_view line, std::string_view name) {
  return line.size() > name.size() && line[name.size()] == ':' &&
         std::equal(name.begin(), name.end(), line.begin(), [](char a, char b) {
           return std::tolower(static_cast<unsigned char>(a)) ==
                  std::tolower(static_cast<unsigned char>(b));
         });
}

/// Whether the request head as received has a `name` field: httplib drops fields whose value is
/// empty ("If-Match:" must still fail the precondition, not skip it).
bool HeadHasField(const httplib::Request& req, std::string_view name) {
  if (req.has_header(std::string(name).c_str())) return true;
  if (t_request_head == nullptr) return false;
  bool found = false;
  ForEachFieldLine(*t_request_head, [&](std::string_view line) {
    found = FieldNameIs(line, name);
    return !found;
  });
  return found;
}

// ---------------------------------------------------------------------------------------------
// The gate: connections wait there, not on a worker, until a whole request has arrived
//
// httplib gives each connection a pool thread from accept to close. 24 connections trickling
// their headers delayed a normal GET by 8 s, 240 idle ones by 19.5 s, and 64 keep-alive clients
// at full speed saw p99 1.4 s (a connection kept its thread for all its requests). Now one
// thread polls every waiting connection, reads what arrives without blocking, and hands a
// connection to a worker only once its buffer holds a whole request (head and announced body,
// or as much as a request may be); after the response it comes back to the gate, so workers
// serve requests in arrival order, each to the end. A connection that does not complete its
// request in time is closed; beyond kMaxWaitingPerAddress waiting connections of one address,
// or kMaxWaiting in all, the one waiting longest is closed: no number of slow or idle
// connections keeps a normal client waiting.

struct Connection {
  int fd = -1;
  std::string peer;       // the client's address
  std::string received;   // read from the socket, not yet by a request
  SteadyTime since{};     // began waiting (accepted, or its last response sent)
  SteadyTime deadline{};  // closed if no whole request by then
  size_t requests = 0;    // served on it so far
};

/// Whether `received` holds a whole request (the head and the body its Content-Length
/// announces), or as much as a request may hold, or something the parser or the guard refuses
/// at once: a worker can then serve it without waiting on the client.
bool RequestReady(const std::string& received, size_t max_head, size_t max_body) {
  const size_t end = received.find("\r\n\r\n");
  if (end == std::string::npos) return received.size() >= max_head;
  // The first Content-Length (a second one is refused by the guard, whatever the body).
  std::optional<size_t> length;
  bool refused = false;
  ForEachFieldLine(std::string_view(received).substr(0, end + 2), [&](std::string_view line) {
    if (!FieldNameIs(line, "content-length")) return true;
    std::string_view value = line.substr(sizeof("content-length:") - 1);
    while (!value.empty() && (value.front() == ' ' || value.front() == '\t'))
      value.remove_prefix(1);
    if (value.empty() || !std::isdigit(static_cast<unsigned char>(value.front()))) {
      refused = true;  // the parser refuses it at once
      return false;
    }
    size_t n = 0;
    for (size_t i = 0; i < value.size() && std::isdigit(static_cast<unsigned char>(value[i]));
         ++i) {
      n = n * 10 + static_cast<size_t>(value[i] - '0');
      if (n > max_body) {
        refused = true;  // refused before its body is read
        return false;
      }
    }
    length = n;
    return false;
  });
  return refused || received.size() - (end + 4) >= length.value_or(0);
}

class Gate {
 public:
  using Dispatch = std::function<void(Connection)>;
  static constexpr size_t kMaxWaiting = 512;
  static constexpr size_t kMaxWaitingPerAddress = 64;

  Gate(Dispatch dispatch, size_t max_head, size_t max_body)
      : dispatch_(std::move(dispatch)), max_head_(max_head), max_body_(max_body) {
    if (::pipe2(wake_, O_CLOEXEC | O_NONBLOCK) != 0) wake_[0] = wake_[1] = -1;
  }
  ~Gate() {
    Stop();
    for (const int fd : wake_) {
      if (fd >= 0) ::close(fd);
    }
  }

  void Start() {
    if (!thread_.joinable()) {
      thread_ = std::thread([this] {
        pthread_setname_np(pthread_self(), "http-gate");
        Run();
      });
    }
  }
  /// Closes every waiting connection; later ones are closed as they come.
  void Stop() {
    stop_ = true;
    Wake();
    if (thread_.joinable()) thread_.join();
    const std::lock_guard lock(mutex_);
    for (Connection& c : incoming_) Close(c);
    incoming_.clear();
  }
  /// A connection to wait on (from any thread).
  void Add(Connection connection) {
    {
      const std::lock_guard lock(mutex_);
      if (stop_) {
        Close(connection);
        return;
      }
      incoming_.push_back(std::move(connection));
    }
    Wake();
  }

  uint64_t timed_out() const { return timed_out_; }
  uint64_t evicted() const { return evicted_; }

 private:
  static void Close(Connection& c) {
    if (c.fd < 0) return;
    ::shutdown(c.fd, SHUT_RDWR);
    ::close(c.fd);
    c.fd = -1;
  }
  void Wake() {
    const char byte = 1;
    if (wake_[1] >= 0) {
      [[maybe_unused]] const ssize_t n = ::write(wake_[1], &byte, 1);
    }
  }

  // Closes the waiting connection that has waited longest among those `pick` selects.
  template <typename Pick>
  void EvictOldest(Pick pick) {
    size_t oldest = waiting_.size();
    for (size_t i = 0; i < waiting_.size(); ++i) {
      if (pick(waiting_[i]) &&
          (oldest == waiting_.size() || waiting_[i].since < waiting_[oldest].since)) {
        oldest = i;
      }
    }
    if (oldest == waiting_.size()) return;
    Close(waiting_[oldest]);
    waiting_.erase(waiting_.begin() + static_cast<std::ptrdiff_t>(oldest));
    ++evicted_;
  }

  void Admit(Connection c) {
    size_t same = 0;
    for (const Connection& w : waiting_) same += w.peer == c.peer;
    if (same >= kMaxWaitingPerAddress) {
      EvictOldest([&](const Connection& w) { return w.peer == c.peer; });
    }
    if (waiting_.size() >= kMaxWaiting) EvictOldest([](const Connection&) { return true; });
    if (RequestReady(c.received, max_head_, max_body_) && !c.received.empty()) {
      dispatch_(std::move(c));  // a pipelined request already here
      return;
    }
    waiting_.push_back(std::move(c));
  }

  // Reads what the connection has (without blocking); false when it closed or failed.
  bool Receive(Connection& c) {
    const size_t cap = max_head_ + max_body_ + 1;
    char chunk[16384];
    while (c.received.size() < cap) {
      const ssize_t n =
          ::recv(c.fd, chunk, std::min(sizeof chunk, cap - c.received.size()), MSG_DONTWAIT);
      if (n > 0) {
        // A request has begun: it has request_deadline from its first byte.
        if (c.received.empty()) c.deadline = Clock::now() + request_deadline;
        c.received.append(chunk, static_cast<size_t>(n));
        continue;
      }
      if (n < 0 && errno == EINTR) continue;
      return n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK);
    }
    return true;
  }

  void Run() {
    std::vector<pollfd> fds;
    while (!stop_) {
      {
        std::vector<Connection> arrived;
        {
          const std::lock_guard lock(mutex_);
          arrived.swap(incoming_);
        }
        for (Connection& c : arrived) Admit(std::move(c));
      }
      fds.assign(1, pollfd{wake_[0], POLLIN, 0});
      for (const Connection& c : waiting_) fds.push_back(pollfd{c.fd, POLLIN, 0});
      const int ready = ::poll(fds.data(), fds.size(), 100);
      if (ready < 0 && errno != EINTR) break;
      if (fds[0].revents != 0) {
        char drain[256];
        while (::read(wake_[0], drain, sizeof drain) > 0) {
        }
      }
      const SteadyTime now = Clock::now();
      std::vector<Connection> keep;
      keep.reserve(waiting_.size());
      for (size_t i = 0; i < waiting_.size(); ++i) {
        Connection& c = waiting_[i];
        const size_t had = c.received.size();
        if (fds[i + 1].revents != 0 && !Receive(c)) {
          Close(c);  // the client went away (or the socket failed)
          continue;
        }
        // Only new bytes can complete a request (Admit checked what a connection came with).
        if (c.received.size() != had && RequestReady(c.received, max_head_, max_body_)) {
          dispatch_(std::move(c));
          continue;
        }
        if (now >= c.deadline) {
          Close(c);
          ++timed_out_;
          continue;
        }
        keep.push_back(std::move(c));
      }
      waiting_.swap(keep);
    }
    for (Connection& c : waiting_) Close(c);
    waiting_.clear();
  }

 public:
  std::chrono::seconds request_deadline{10};

 private:
  Dispatch dispatch_;
  size_t max_head_, max_body_;
  int wake_[2] = {-1, -1};
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::mutex mutex_;
  std::vector<Connection> incoming_;
  std::vector<Connection> waiting_;  // the gate thread's own
  std::atomic<uint64_t> timed_out_{0};
  std::atomic<uint64_t> evicted_{0};
};

class BoundedServer final : public httplib::Server {
 public:
  ~BoundedServer() override { Shutdown(); }

  /// One request through the parser, the pre-routing guard, routing, the handlers and the
  /// logger, as on a connection that closes after it; the response bytes.
  std::string ProcessInMemory(std::string_view request, size_t max_response_bytes) {
    MemoryStream stream(request, max_response_bytes);
    bool closed = false;
    const size_t end = request.find("\r\n\r\n");
    const std::string head(
        request.substr(0, end == std::string_view::npos ? request.size() : end + 2));
    t_request_head = &head;
    process_request(stream, /*close_connection=*/true, closed, nullptr);
    t_request_head = nullptr;
    return std::move(stream.response());
  }

  /// httplib listens with a backlog of 5: when the 8 viewers of the load test opened their tile
  /// connections at once while the SLAM kept both cores busy, the kernel dropped SYNs
  /// (TcpExtListenOverflows) and those requests waited for the 1 s SYN retransmission. Linux
  /// takes a second listen() on a listening socket as a new backlog.
  void WidenListenBacklog() {
    const socket_t sock = svr_sock_;
    if (sock != INVALID_SOCKET) ::listen(sock, 256);
  }

  /// Starts the gate and `workers` threads that serve whole requests (event streams hold one
  /// each for their lifetime). Before listen_after_bind.
  void StartServing(size_t workers) {
    gate_ = std::make_unique<Gate>([this](Connection c) { Dispatch(std::move(c)); }, max_head_bytes,
                                   max_body_bytes);
    gate_->request_deadline = request_deadline;
    workers_ = std::make_unique<httplib::ThreadPool>(workers);
    gate_->Start();
  }
  /// After listen_after_bind returned (stop()): closes the waiting connections and waits for
  /// the workers (event streams end within their wake-up interval once the server stops).
  void Shutdown() {
    if (gate_) gate_->Stop();
    if (workers_) {
      workers_->shutdown();
      workers_.reset();
    }
  }

  uint64_t connections_timed_out() const { return gate_ ? gate_->timed_out() : 0; }
  uint64_t connections_evicted() const { return gate_ ? gate_->evicted() : 0; }

  size_t max_head_bytes = 64 * 1024;
  size_t max_body_bytes = 64 * 1024;
  std::chrono::seconds request_deadline{10};

 private:
  // httplib hands each accepted connection to this on one of its pool threads: it goes to the
  // gate at once (without a gate, as in HandleInMemory's users, it is closed).
  bool process_and_close_socket(socket_t sock) override {
    Connection c;
    c.fd = sock;
    c.since = Clock::now();
    c.deadline = c.since + request_deadline;
    sockaddr_storage address{};
    socklen_t length = sizeof address;
    if (::getpeername(sock, reinterpret_cast<sockaddr*>(&address), &length) == 0) {
      char text[INET6_ADDRSTRLEN] = {};
      if (address.ss_family == AF_INET) {
        ::inet_ntop(AF_INET, &reinterpret_cast<const sockaddr_in*>(&address)->sin_addr, text,
                    sizeof text);
      } else if (address.ss_family == AF_INET6) {
        ::inet_ntop(AF_INET6, &reinterpret_cast<const sockaddr_in6*>(&address)->sin6_addr, text,
                    sizeof text);
      }
      c.peer = text;
    }
    if (!gate_ || svr_sock_ == INVALID_SOCKET) {
      ::close(sock);
      return false;
    }
    gate_->Add(std::move(c));
    return true;
  }

  void Dispatch(Connection c) {
    auto held = std::make_shared<Connection>(std::move(c));
    workers_->enqueue([this, held] { Serve(std::move(*held)); });
  }

  // One request of a connection whose buffer holds it (httplib's loop of 0.11 for one turn,
  // over a BoundedStream); then the connection goes back to the gate, or closes.
  void Serve(Connection c) {
    BoundedStream stream(c.fd, std::move(c.received), std::chrono::seconds(read_timeout_sec_),
                         std::chrono::seconds(write_timeout_sec_));
    stream.StartRequest(max_head_bytes + max_body_bytes, Clock::now() + request_deadline);
    const bool last = ++c.requests >= keep_alive_max_count_;
    bool closed = false;
    t_close_connection = false;
    t_request_head = &stream.head();
    const bool ok = process_request(stream, last, closed, nullptr);
    t_request_head = nullptr;
    // The rest of a cut request is garbage; so is the unread body of a refused one.
    if (!ok || closed || last || stream.Exhausted() || t_close_connection ||
        svr_sock_ == INVALID_SOCKET) {
      ::shutdown(c.fd, SHUT_RDWR);
      ::close(c.fd);
      return;
    }
    c.received = stream.TakeBuffered();
    c.since = Clock::now();
    c.deadline = c.since + (c.received.empty() ? std::chrono::seconds(keep_alive_timeout_sec_)
                                               : request_deadline);
    gate_->Add(std::move(c));
  }

  std::unique_ptr<Gate> gate_;
  std::unique_ptr<httplib::ThreadPool> workers_;
};

}  // namespace

bool IsLoopback(const std::string& address) {
  if (address == "localhost" || address == "::1") return true;
  in_addr v4{};
  if (inet_pton(AF_INET, address.c_str(), &v4) == 1) return (ntohl(v4.s_addr) >> 24) == 127;
  return false;
}

std::string HostName(const std::string& host_header) {
  if (!host_header.empty() && host_header.front() == '[') {
    const size_t close = host_header.find(']');
    return close == std::string::npos ? host_header : host_header.substr(1, close - 1);
  }
  const size_t colon = host_header.find(':');
  // More than one colon: an IPv6 address without brackets (no port can be told from it).
  if (colon == std::string::npos || host_header.find(':', colon + 1) != std::string::npos) {
    return host_header;
  }
  return host_header.substr(0, colon);
}

bool IsIpAddress(const std::string& host) {
  in_addr v4{};
  in6_addr v6{};
  return inet_pton(AF_INET, host.c_str(), &v4) == 1 || inet_pton(AF_INET6, host.c_str(), &v6) == 1;
}

bool IsPublicWebPath(std::string_view path) {
  size_t at = 0;
  while (at < path.size()) {
    while (at < path.size() && path[at] == '/') ++at;
    const size_t end = std::min(path.find('/', at), path.size());
    const std::string_view segment = path.substr(at, end - at);
    if (segment.starts_with('.') || segment == "node_modules" || segment == "package.json" ||
        segment == "package-lock.json") {
      return false;
    }
    at = end;
  }
  return true;
}

bool EntityTagListMatches(std::string_view list, std::string_view etag, bool weak) {
  const auto trim = [](std::string_view s) {
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
    return s;
  };
  const auto opaque = [](std::string_view tag, bool& is_weak) {
    is_weak = tag.starts_with("W/");
    if (is_weak) tag.remove_prefix(2);
    return tag;
  };
  bool etag_weak = false;
  const std::string_view ours = opaque(etag, etag_weak);
  for (size_t at = 0; at <= list.size();) {
    const size_t comma = std::min(list.find(',', at), list.size());
    const std::string_view item = trim(list.substr(at, comma - at));
    at = comma + 1;
    if (item.empty()) continue;
    if (item == "*") return true;
    bool item_weak = false;
    const std::string_view theirs = opaque(item, item_weak);
    if (theirs == ours && (weak || (!item_weak && !etag_weak))) return true;
  }
  return false;
}

std::optional<std::string> AmbiguousFraming(std::string_view head) {
  const auto is_token_char = [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) != 0 ||
           std::string_view("!#$%&'*+-.^_`|~").find(c) != std::string_view::npos;
  };
  const size_t line_end = head.find("\r\n");
  if (line_end == std::string_view::npos) return std::nullopt;  // the parser judges it
  const std::string_view request_line = head.substr(0, line_end);
  const bool http11 = request_line.ends_with(" HTTP/1.1");
  int content_lengths = 0, hosts = 0;
  std::optional<std::string> problem;
  ForEachFieldLine(head, [&](std::string_view line) {
    if (line.front() == ' ' || line.front() == '\t') {
      problem = "a header line folded onto the previous one (obsolete line folding)";
      return false;
    }
    const size_t colon = line.find(':');
    if (colon == std::string_view::npos) {
      problem = "a header line without a colon";
      return false;
    }
    const std::string_view name = line.substr(0, colon);
    if (name.empty() || !std::all_of(name.begin(), name.end(), is_token_char)) {
      problem = "the header name '" + std::string(name.substr(0, 64)) +
                "' is not a token (no whitespace before the colon)";
      return false;
    }
    content_lengths += FieldNameIs(line, "content-length");
    hosts += FieldNameIs(line, "host");
    return true;
  });
  if (problem) return problem;
  if (content_lengths > 1) return "more than one Content-Length";
  if (http11 && hosts != 1) {
    return hosts == 0 ? "a request of HTTP version 1.1 needs a Host header"
                      : "more than one Host header";
  }
  return std::nullopt;
}

bool ConstantTimeEquals(const std::string& a, const std::string& b) {
  // Walk the longer length whatever the contents, so that the time reveals nothing but it.
  const size_t n = std::max(a.size(), b.size());
  unsigned char diff = a.size() == b.size() ? 0 : 1;
  for (size_t i = 0; i < n; ++i) {
    const unsigned char x = i < a.size() ? static_cast<unsigned char>(a[i]) : 0;
    const unsigned char y = i < b.size() ? static_cast<unsigned char>(b[i]) : 0;
    diff = static_cast<unsigned char>(diff | (x ^ y));
  }
  return diff == 0;
}

struct HttpServer::Impl {
  SlamService& service;
  hw::Link& link;
  JobManager& jobs;
  HttpOptions options;
  BoundedServer server;
  Clock::time_point started = Clock::now();
  // Tells one run of slamd from the next (the page reloads everything when it changes).
  std::string instance = std::to_string(std::chrono::system_clock::now().time_since_epoch() /
                                        std::chrono::microseconds(1));
  std::atomic<bool> stopping{false};
  std::atomic<int> streams{0};
  std::atomic<uint64_t> streams_rejected{0};

  // Revisions of the budget and the parameters (the ETags), bumped by every change.
  std::mutex revision_mutex;  // also serialises read-modify-write of budget and params
  uint64_t budget_revision = 1;
  uint64_t params_revision = 1;

  std::mutex save_mutex;  // one save at a time
  // The last save that succeeded (guarded by save_mutex): when it was started and its answer.
  // A request that waited for a save started after it arrived shares that save's answer.
  struct LastSave {
    bool valid = false;
    Clock::time_point started;
    json answer;
  } last_save;
  std::atomic<uint64_t> saves_made{0};
  // A reset request waiting for the SLAM thread to apply its reset (at most one: see HandleReset).
  std::atomic<bool> reset_waiting{false};

  // Whole-map exports and the trajectory cost time in proportion to the map and the run: each
  // kind is made at most once per published snapshot, one at a time; requests that come while
  // one is being made wait for it and share its bytes. Their CPU cost is thus bounded by the scan
  // rate, whatever the request rate. (Keys are made in Setup; the map is not resized later.)
  struct Export {
    std::mutex mutex;
    bool valid = false;
    uint64_t sequence = 0;  // of the snapshot it was made from
    std::string body;
    std::string type;
    std::atomic<uint64_t> renders{0};
  };
  std::map<std::string, Export> exports;
  template <typename Make>
  void ServeExport(const std::string& kind, httplib::Response& res, Make make);

  std::mutex tile_cache_mutex;
  std::map<TileKey, std::pair<uint64_t, std::string>> tile_cache;  // version, PNG

  std::mutex requests_mutex;
  std::map<std::pair<std::string, int>, uint64_t> requests;  // (method, code) -> count

  Impl(SlamService& s, hw::Link& l, JobManager& j, const HttpOptions& o)
      : service(s), link(l), jobs(j), options(o) {}

  std::string BudgetEtag() const { return "\"b" + std::to_string(budget_revision) + "\""; }
  std::string ParamsEtag() const { return "\"p" + std::to_string(params_revision) + "\""; }

  void Setup();
  httplib::Server::HandlerResponse Guard(httplib::Request& req, httplib::Response& res);
  bool ParseBody(const httplib::Request& req, httplib::Response& res, const char* media, json& out);
  void HandleBudgetChange(const httplib::Request& req, httplib::Response& res, bool patch);
  void HandleParamsPatch(const httplib::Request& req, httplib::Response& res);
  void HandleTile(const httplib::Request& req, httplib::Response& res);
  void HandleEvents(const httplib::Request& req, httplib::Response& res);
  void HandleSave(httplib::Response& res);
  /// Saves the newest snapshot into --state-dir (save_mutex held); sets last_save on success.
  SaveOutcome SaveLocked();
  void HandleReset(httplib::Response& res);
  json StatusJson();
  json SourceJson(const std::string& description) {
    return {{"spec", options.source_spec},
            {"description", description},
            {"simulated", service.simulated()}};
  }
  std::string MetricsText();
};

httplib::Server::HandlerResponse HttpServer::Impl::Guard(httplib::Request& req,
                                                         httplib::Response& res) {
  using R = httplib::Server::HandlerResponse;
  // Brotli at maximum quality costs far more CPU than it saves on loopback or a robot's Wi-Fi;
  // gzip is cheap. (docs/design.md appendix C, point 7)
  if (auto it = req.headers.find("Accept-Encoding"); it != req.headers.end()) {
    if (Lower(it->second).find("br") != std::string::npos) it->second = "gzip";
  }
  // Ranges: httplib builds a multipart answer to many ranges whole in memory (4000 ranges in an
  // 8 KB header made 600 MB of one 150 KB file), and answers a range of a handler's response
  // with 200 and a truncated body. The page's files honour one range; more than one, or a range
  // of anything else, is ignored and the whole answer sent (a server may, RFC 9110 14.2).
  if (!req.ranges.empty() &&
      (req.ranges.size() > 1 || req.path.rfind("/api/", 0) == 0 || req.path == "/metrics")) {
    req.ranges.clear();
    req.headers.erase("Range");
  }
  // The trajectory is made once per snapshot (ServeExport) but httplib would compress its TUM
  // text again for every request, at a cost growing with the run: it goes out as it is.
  if (req.path == "/api/v1/trajectory") req.headers.erase("Accept-Encoding");
  const bool mutating = req.method == "POST" || req.method == "PUT" || req.method == "PATCH" ||
                        req.method == "DELETE";
  const bool bodied = req.method == "POST" || req.method == "PUT" || req.method == "PATCH";
  const auto refuse = [&](int status, const std::string& title, const std::string& detail) {
    SendProblem(res, status, title, detail);
    // The body (if any) is not read: the connection cannot carry another request. Both are
    // needed: the header tells the client, the flag makes the connection loop close.
    res.set_header("Connection", "close");
    t_close_connection = true;
    return R::Handled;
  };
  // A request whose framing parsers may read differently: 400, and the connection closes (what
  // follows on it may be a request hidden in this one).
  if (t_request_head != nullptr) {
    if (const auto problem = AmbiguousFraming(*t_request_head)) {
      return refuse(400, "Bad Request", *problem);
    }
  }
  // slamd answers only to loopback names, IP addresses and --allow-host names, with a token or
  // without: a page whose own name an attacker makes resolve to slamd's address (DNS rebinding)
  // is same-origin with itself, so the Origin check below lets it through, and the token guards
  // only changes: it would read the map, the trajectory and the events. Its requests name its
  // host, which is none of these. (An address cannot be rebound: a page at http://192.168.1.5/
  // is one the user opened.)
  if (req.has_header("Host")) {
    const std::string host = Lower(HostName(req.get_header_value("Host")));
    if (!IsLoopback(host) && !IsIpAddress(host) &&
        std::find(options.allowed_hosts.begin(), options.allowed_hosts.end(), host) ==
            options.allowed_hosts.end()) {
      return refuse(403, "Forbidden",
                    "slamd answers only to loopback names (localhost, 127.0.0.1, [::1]), IP "
                    "addresses and --allow-host names, not to '" +
                        host + "'");
    }
  }
  // A path that decodes to a control character (a NUL: /index.html%00.js served index.html as
  // JavaScript) names no file of ours; nor do the page's npm folder and manifests, or hidden
  // files (GET /node_modules/... served the page's development tools).
  if (std::any_of(req.path.begin(), req.path.end(),
                  [](char c) { return static_cast<unsigned char>(c) < 0x20 || c == 0x7f; })) {
    return refuse(400, "Bad Request", "the path holds a control character");
  }
  if (req.path.rfind("/api/", 0) != 0 && !IsPublicWebPath(req.path)) {
    SendProblem(res, 404, "Not Found", "no such page file");
    return R::Handled;
  }
  // Body limits before the body is read: the library's own limit does not bound chunked or
  // compressed bodies (notes point 5), and a POST without a length would hang (point 6).
  if (req.has_header("Transfer-Encoding")) {
    return refuse(411, "Length Required",
                  "request bodies must have a Content-Length; chunked bodies are refused");
  }
  if (req.has_header("Content-Encoding")) {
    return refuse(415, "Unsupported Media Type", "compressed request bodies are refused");
  }
  if (bodied && !req.has_header("Content-Length")) {
    return refuse(411, "Length Required", "a request body with a Content-Length is required");
  }
  if (req.has_header("Content-Length")) {
    const std::string value = req.get_header_value("Content-Length");
    char* end = nullptr;
    const unsigned long long length = std::strtoull(value.c_str(), &end, 10);
    if (value.empty() || *end != '\0' || value[0] == '-') {
      return refuse(400, "Bad Request", "bad Content-Length");
    }
    // httplib reads the body of POST, PUT, PATCH and DELETE only: another method's body would
    // be parsed as the next request on the connection.
    if (length > 0 && !bodied && req.method != "DELETE") {
      return refuse(400, "Bad Request", "a " + req.method + " request may not have a body");
    }
    if (length > options.max_body_bytes) {
      return refuse(
          413, "Content Too Large",
          "request bodies are limited to " + std::to_string(options.max_body_bytes) + " bytes");
    }
  }
  if (mutating) {
    if (!options.token.empty()) {
      const std::string auth = req.get_header_value("Authorization");
      const std::string prefix = "Bearer ";
      if (auth.empty()) {
        res.set_header("WWW-Authenticate", "Bearer realm=\"slamd\"");
        return refuse(401, "Unauthorized", "this route needs Authorization: Bearer <token>");
      }
      // The scheme is case-insensitive (RFC 7235); the token is compared in constant time.
      if (Lower(auth.substr(0, prefix.size())) != "bearer " ||
          !ConstantTimeEquals(auth.substr(std::min(prefix.size(), auth.size())), options.token)) {
        res.set_header("WWW-Authenticate", "Bearer realm=\"slamd\", error=\"invalid_token\"");
        return refuse(401, "Unauthorized", "wrong token");
      }
    }
    // A page from another site must not drive the robot through the user's browser.
    if (req.has_header("Origin")) {
      std::string origin = req.get_header_value("Origin");
      const size_t scheme = origin.find("://");
      if (scheme != std::string::npos) origin = origin.substr(scheme + 3);
      if (Lower(origin) != Lower(req.get_header_value("Host"))) {
        return refuse(403, "Forbidden", "cross-origin requests may not change slamd");
      }
    }
  }
  return R::Unhandled;
}

bool HttpServer::Impl::ParseBody(const httplib::Request& req, httplib::Response& res,
                                 const char* media, json& out) {
  const std::string type = MediaType(req.get_header_value("Content-Type"));
  if (type != media) {
    SendProblem(res, 415, "Unsupported Media Type",
                std::string("the body must be ") + media +
                    (type.empty() ? std::string(" (no Content-Type given)") : ", not " + type));
    return false;
  }
  // Parsing is iterative, but copying and comparing nested values recurse in nlohmann-json: a
  // 64 KiB body of brackets nests 32 000 deep, one stack frame (or more) per level. No body of
  // slamd's nests deeper than a few levels.
  constexpr int kMaxDepth = 32;
  bool too_deep = false;
  out = json::parse(
      req.body,
      [&](int depth, json::parse_event_t, json&) {
        if (depth > kMaxDepth) too_deep = true;
        return !too_deep;
      },
      false);
  if (too_deep) {
    out = json();
    SendProblem(res, 400, "Bad Request",
                "the body nests deeper than " + std::to_string(kMaxDepth) + " levels");
    return false;
  }
  if (out.is_discarded()) {
    SendProblem(res, 400, "Bad Request", "the body is not valid JSON");
    return false;
  }
  return true;
}

void HttpServer::Impl::HandleBudgetChange(const httplib::Request& req, httplib::Response& res,
                                          bool patch) {
  json body;
  if (!ParseBody(req, res, patch ? "application/merge-patch+json" : "application/json", body)) {
    return;
  }
  const std::lock_guard lock(revision_mutex);
  const std::string if_match = req.get_header_value("If-Match");
  if (HeadHasField(req, "If-Match") && !EntityTagListMatches(if_match, BudgetEtag(), false)) {
    res.set_header("ETag", BudgetEtag());
    SendProblem(res, 412, "Precondition Failed",
                "the budget changed since " + if_match + "; it is now " + BudgetEtag());
    return;
  }
  json target = body;
  if (patch) {
    if (!body.is_object()) {
      SendProblem(res, 422, "Invalid budget", "a merge patch of the budget must be an object",
                  {{"", "must be a JSON object", 0}});
      return;
    }
    target = BudgetJson(service.Budget());
    // RFC 7396: null removes a member; a removed member takes its default.
    target.merge_patch(body);
    const json defaults = BudgetJson(BudgetSettings{});
    for (const auto& [key, value] : defaults.items()) {
      if (!target.contains(key)) target[key] = value;
    }
  }
  BudgetSettings settings;
  const ConfigErrors errors = BudgetFromJson(target, settings);
  if (!errors.empty()) {
    SendProblem(res, 422, "Invalid budget", "the budget was not changed", errors);
    return;
  }
  if (!(settings == service.Budget())) {
    service.SetBudget(settings);
    ++budget_revision;
  }
  res.set_header("ETag", BudgetEtag());
  SendJson(res, BudgetJson(settings));
}

void HttpServer::Impl::HandleParamsPatch(const httplib::Request& req, httplib::Response& res) {
  json body;
  if (!ParseBody(req, res, "application/merge-patch+json", body)) return;
  const std::lock_guard lock(revision_mutex);
  const std::string if_match = req.get_header_value("If-Match");
  if (HeadHasField(req, "If-Match") && !EntityTagListMatches(if_match, ParamsEtag(), false)) {
    res.set_header("ETag", ParamsEtag());
    SendProblem(res, 412, "Precondition Failed",
                "the parameters changed since " + if_match + "; they are now " + ParamsEtag());
    return;
  }
  if (!body.is_object()) {
    SendProblem(res, 422, "Invalid parameters", "a merge patch of the parameters must be an object",
                {{"", "must be a JSON object", 0}});
    return;
  }
  auto result = io::ApplyParamsPatch(service.Params(), body);
  if (!result.ok()) {
    SendProblem(res, 422, "Invalid parameters", "the parameters were not changed", result.errors());
    return;
  }
  if (!(result.value() == service.Params())) {
    service.SetParams(result.value());
    ++params_revision;
  }
  res.set_header("ETag", ParamsEtag());
  SendJson(res, io::ParamsToJson(result.value()));
}

void HttpServer::Impl::HandleTile(const httplib::Request& req, httplib::Response& res) {
  int x = 0, y = 0;
  try {
    x = std::stoi(req.matches[1].str());
    y = std::stoi(req.matches[2].str());
  } catch (const std::exception&) {
    SendProblem(res, 404, "Not Found", "no such tile");
    return;
  }
  const auto snapshot = service.Snapshot();
  const auto it = std::find_if(snapshot->tiles.begin(), snapshot->tiles.end(),
                               [&](const TileRef& t) { return t.index.x == x && t.index.y == y; });
  if (it == snapshot->tiles.end()) {
    SendProblem(res, 404, "Not Found",
                "no tile (" + std::to_string(x) + ", " + std::to_string(y) + ")");
    return;
  }
  const uint64_t version = snapshot->ReportedVersion(*it->tile);
  const std::string etag = "\"" + std::to_string(version) + "\"";
  res.set_header("ETag", etag);
  res.set_header("Cache-Control", "no-cache");
  if (req.has_header("If-None-Match") &&
      EntityTagListMatches(req.get_header_value("If-None-Match"), etag, true)) {
    res.status = 304;
    return;
  }
  std::string png;
  {
    const std::lock_guard lock(tile_cache_mutex);
    const auto cached = tile_cache.find({x, y});
    if (cached != tile_cache.end() && cached->second.first == version) png = cached->second.second;
  }
  if (png.empty()) {
    const io::PngBytes bytes = io::EncodeGrayPng(kTileSize, kTileSize, io::TileGray(*it->tile));
    if (!bytes.ok()) {
      SendProblem(res, 500, "Internal Server Error", bytes.error);
      return;
    }
    png.assign(bytes.bytes.begin(), bytes.bytes.end());
    const std::lock_guard lock(tile_cache_mutex);
    tile_cache[{x, y}] = {version, png};
  }
  res.set_content(png, "image/png");
}

template <typename Make>
void HttpServer::Impl::ServeExport(const std::string& kind, httplib::Response& res, Make make) {
  Export& e = exports.at(kind);
  const std::lock_guard lock(e.mutex);
  const auto snapshot = service.Snapshot();
  if (!e.valid || e.sequence != snapshot->sequence) {
    e.valid = false;
    std::string error;
    if (!make(*snapshot, e.body, e.type, error)) {
      SendProblem(res, 500, "Internal Server Error", error);
      return;
    }
    e.valid = true;
    e.sequence = snapshot->sequence;
    e.renders.fetch_add(1);
  }
  res.set_content(e.body, e.type.c_str());
}

void HttpServer::Impl::HandleEvents(const httplib::Request& req, httplib::Response& res) {
  if (streams.fetch_add(1) >= options.max_streams) {
    streams.fetch_sub(1);
    streams_rejected.fetch_add(1);
    res.set_header("Retry-After", "5");
    SendProblem(res, 503, "Service Unavailable",
                "too many event streams (" + std::to_string(options.max_streams) + ")");
    return;
  }
  // Per-connection state, owned by the provider.
  struct Stream {
    bool hello_sent = false;
    uint64_t last_event_id = 0;
    // Every event's id: the map version up to which this client has been told every tile, so
    // that a reconnect with Last-Event-ID resumes exactly there.
    uint64_t covered = 0;
    uint64_t sequence = 0;
    uint64_t epoch = 0;
    std::map<TileKey, uint64_t> sent;  // tile versions the client has been told
    Clock::time_point last_tiles{};
    Clock::time_point last_pose{};
    Clock::time_point last_write = Clock::now();
    int64_t last_pose_scan = -1;
    uint64_t budget_revision = 0, params_revision = 0, job_revision = 0;
    std::string link_state, slam_state;
  };
  auto stream = std::make_shared<Stream>();
  if (req.has_header("Last-Event-ID")) {
    try {
      stream->last_event_id = std::stoull(req.get_header_value("Last-Event-ID"));
      stream->covered = stream->last_event_id;
    } catch (const std::exception&) {
      stream->last_event_id = 0;  // a garbled id: start afresh
    }
  }
  res.set_header("Cache-Control", "no-cache");
  res.set_header("X-Accel-Buffering", "no");
  res.set_chunked_content_provider(
      "text/event-stream",
      [this, stream](size_t, httplib::DataSink& sink) {
        if (stopping || !sink.is_writable()) return false;
        Stream& s = *stream;
        std::string out;
        auto snapshot =
            s.hello_sent ? service.WaitNewer(s.sequence, kStreamWake) : service.Snapshot();
        if (stopping) return false;
        const auto now = Clock::now();
        if (!s.hello_sent) {
          s.hello_sent = true;
          if (s.last_event_id > snapshot->map_version) {
            // An id from another run of slamd (its versions went further): start afresh.
            s.last_event_id = 0;
            s.covered = 0;
          }
          s.epoch = snapshot->epoch;
          out += Event("hello", s.covered,
                       {{"version", SLAMD_VERSION},
                        {"epoch", snapshot->epoch},
                        {"instance", instance},
                        {"source", SourceJson(link.Status().source)},
                        {"simulated", service.simulated()},
                        {"map_version", snapshot->map_version}});
          // What the client already has (Last-Event-ID) is not resent.
          for (const TileRef& t : snapshot->tiles) {
            const uint64_t v = snapshot->ReportedVersion(*t.tile);
            if (v <= s.last_event_id) s.sent[{t.index.x, t.index.y}] = v;
          }
          s.last_tiles = now - std::chrono::hours(1);
        }
        if (snapshot->epoch != s.epoch) {
          s.epoch = snapshot->epoch;
          s.sent.clear();
          out += Event("reset", s.covered, {{"version", snapshot->map_version}});
        }
        // Tiles: every tile newer than what this client was told, coalesced, at most every
        // half second (a slow client simply gets fewer, larger announcements: latest wins).
        if (Seconds(now - s.last_tiles) >= kTilesEverySeconds) {
          json changed = json::array();
          for (const TileRef& t : snapshot->tiles) {
            const uint64_t v = snapshot->ReportedVersion(*t.tile);
            uint64_t& known = s.sent[{t.index.x, t.index.y}];
            if (v > known) {
              changed.push_back({{"x", t.index.x}, {"y", t.index.y}, {"version", v}});
              known = v;
            }
          }
          s.covered = std::max(s.covered, snapshot->map_version);
          if (!changed.empty()) {
            out += Event("tiles", s.covered,
                         {{"version", snapshot->map_version}, {"tiles", std::move(changed)}});
            s.last_tiles = now;
          }
        }
        if (snapshot->last && snapshot->last->scan != s.last_pose_scan &&
            Seconds(now - s.last_pose) >= kPoseEverySeconds) {
          s.last_pose_scan = snapshot->last->scan;
          s.last_pose = now;
          out += Event("pose", s.covered, PoseEventJson(*snapshot));
          out += Event("metrics", s.covered, MetricsEventJson(*snapshot));
        }
        s.sequence = snapshot->sequence;
        {
          std::lock_guard lock(revision_mutex);
          if (s.budget_revision != budget_revision) {
            if (s.budget_revision != 0) {
              out += Event("budget", s.covered, BudgetJson(service.Budget()));
            }
            s.budget_revision = budget_revision;
          }
          if (s.params_revision != params_revision) {
            if (s.params_revision != 0) {
              out += Event("params", s.covered, io::ParamsToJson(service.Params()));
            }
            s.params_revision = params_revision;
          }
        }
        const uint64_t job_revision = jobs.revision();
        if (job_revision != s.job_revision) {
          s.job_revision = job_revision;
          if (auto job = jobs.Latest()) out += Event("job", s.covered, *job);
        }
        const std::string link_state = hw::ToString(link.Status().state);
        const std::string slam_state = ToString(service.Counters().state);
        if (link_state != s.link_state || slam_state != s.slam_state) {
          s.link_state = link_state;
          s.slam_state = slam_state;
          out += Event("status", s.covered, {{"link", link_state}, {"slam", slam_state}});
        }
        if (out.empty() && Seconds(now - s.last_write) >= kPingEverySeconds) out = ": ping\n\n";
        if (!out.empty()) {
          s.last_write = now;
          if (!sink.write(out.data(), out.size())) return false;
        }
        return true;
      },
      [this](bool) { streams.fetch_sub(1); });
}

void HttpServer::Impl::HandleSave(httplib::Response& res) {
  if (options.state_dir.empty()) {
    SendProblem(res, 409, "Conflict", "slamd was started without --state-dir: nowhere to save");
    return;
  }
  // The snapshot is taken under the lock: saves run one at a time, each of a snapshot at least
  // as new as the one before (taken before the lock, a slower save of an older snapshot could
  // land after a newer one and take the saved state back).
  const Clock::time_point arrived = Clock::now();
  const std::lock_guard lock(save_mutex);
  // A save started after this request arrived saved a snapshot at least as new as the one this
  // request would save: its answer is this request's. Requests piling up on the lock thus make
  // one more save between them, not one each (each holds a server thread while it waits).
  if (last_save.valid && last_save.started >= arrived) {
    SendJson(res, last_save.answer);
    return;
  }
  const SaveOutcome saved = SaveLocked();
  if (saved.error) {
    SendProblem(res, 500, "Internal Server Error", "the map was not saved: " + *saved.error);
    return;
  }
  SendJson(res, last_save.answer);
}

SaveOutcome HttpServer::Impl::SaveLocked() {
  last_save.valid = false;
  last_save.started = Clock::now();
  const auto snapshot = service.Snapshot();
  const OccupancyGrid grid = SnapshotGrid(*snapshot, service.encoded_logodds_limit());
  SaveInputs in;
  in.version = snapshot->map_version;
  in.resolution_m = snapshot->resolution_m;
  in.grid = &grid;
  in.version_base = snapshot->version_base;
  in.trajectory = ScanEndTrajectory(*snapshot);
  SaveOutcome saved = SaveState(options.state_dir, in);
  if (saved.error) return saved;
  saves_made.fetch_add(1);
  last_save.answer = {{"path", std::filesystem::absolute(options.state_dir).string()},
                      {"version", snapshot->map_version},
                      {"tiles", snapshot->tiles.size()},
                      {"warnings", saved.warnings}};
  for (const std::string& warning : saved.warnings) {
    std::fprintf(stderr, "slamd: map saved, but a copy was not written: %s\n", warning.c_str());
  }
  last_save.valid = true;
  return saved;
}

SaveOutcome HttpServer::SaveMap() {
  if (impl_->options.state_dir.empty()) {
    SaveOutcome outcome;
    outcome.error = "slamd was started without --state-dir";
    return outcome;
  }
  const std::lock_guard lock(impl_->save_mutex);
  return impl_->SaveLocked();
}

void HttpServer::Impl::HandleReset(httplib::Response& res) {
  const auto before = service.Snapshot();
  service.RequestReset();
  // The SLAM thread applies it before its next scan. One request waits for it (bounded) so that
  // its answer carries the new map version; requests meanwhile ask for the same reset (requests
  // before it is applied are one reset) and are answered at once, pending: each waiting held a
  // server thread for up to 2 s, and 24 of them stalled the API.
  if (reset_waiting.exchange(true)) {
    SendJson(res, {{"version", before->map_version}, {"pending", true}}, 202);
    return;
  }
  struct Release {
    std::atomic<bool>& flag;
    ~Release() { flag = false; }
  } release{reset_waiting};
  auto snapshot = before;
  const auto deadline = Clock::now() + std::chrono::seconds(2);
  while (snapshot->epoch == before->epoch && Clock::now() < deadline && !stopping) {
    snapshot = service.WaitNewer(snapshot->sequence, std::chrono::milliseconds(100));
  }
  if (snapshot->epoch == before->epoch) {
    SendJson(res, {{"version", before->map_version}, {"pending", true}}, 202);
    return;
  }
  SendJson(res, {{"version", snapshot->map_version}, {"pending", false}});
}

json HttpServer::Impl::StatusJson() {
  const auto snapshot = service.Snapshot();
  const ServiceCounters c = service.Counters();
  const hw::LinkStatus link_status = link.Status();
  json slam = {{"state", ToString(c.state)},
               {"scans", c.scans},
               {"late_scans", c.late_scans},
               {"resets", c.resets},
               {"particles", snapshot->last ? snapshot->last->particles : 0},
               {"map_version", snapshot->map_version},
               {"tiles", snapshot->tiles.size()},
               {"last_latency_ms", snapshot->last ? snapshot->last->latency_s * 1e3 : 0.0},
               {"cpu_share", c.robot_s > 0.0 ? c.cpu_s / c.robot_s : 0.0},
               {"realtime_ratio", c.busy_s > 0.0 ? c.robot_s / c.busy_s : 0.0},
               {"robot_time_s", c.robot_s},
               {"assembler", hw::AssemblerCountersToJson(c.assembler)}};
  const auto job = jobs.Latest();
  return {{"version", SLAMD_VERSION},
          {"uptime_s", Seconds(Clock::now() - started)},
          {"source", SourceJson(link_status.source)},
          {"link", hw::LinkStatusToJson(link_status)},
          {"slam", slam},
          {"pose", snapshot->has_pose ? PoseJson(snapshot->pose) : json(nullptr)},
          {"budget", BudgetJson(service.Budget())},
          {"job", job ? *job : json(nullptr)},
          {"features",
           {{"save", !options.state_dir.empty()},
            {"tuning", jobs.configured()},
            {"experiments", jobs.Experiments()},
            {"ray_kernel", BestWindowKernelName()}}}};
}

std::string HttpServer::Impl::MetricsText() {
  const auto snapshot = service.Snapshot();
  const ServiceCounters c = service.Counters();
  const hw::LinkStatus l = link.Status();
  std::ostringstream o;
  o.precision(9);
  const auto metric = [&](const char* name, const char* type, const char* help, auto value) {
    o << "# HELP slamd_" << name << ' ' << help << "\n# TYPE slamd_" << name << ' ' << type
      << "\nslamd_" << name << ' ' << value << '\n';
  };
  metric("scans_total", "counter", "Scans processed by the SLAM.", c.scans);
  metric("late_scans_total", "counter",
         "Scans whose result came later than one scan period after the scan was complete.",
         c.late_scans);
  metric("rays_planned_total", "counter", "Rays planned by the scheduler.", c.rays_planned);
  metric("rays_used_total", "counter", "Rays cast by the engine.", c.rays_used);
  const ScanMetrics last = snapshot->last.value_or(ScanMetrics{});
  metric("rays_per_scan_planned", "gauge", "Rays planned for the latest scan.", last.rays_planned);
  metric("rays_per_scan_used", "gauge", "Rays cast on the latest scan.", last.rays_used);
  metric("ray_quota", "gauge", "The scheduler's quota for the latest scan, rays.", last.quota);
  o << "# HELP slamd_scan_latency_seconds From a scan's last event to its published result.\n"
       "# TYPE slamd_scan_latency_seconds histogram\n";
  uint64_t cumulative = 0;
  const auto& bounds = LatencyBuckets();
  for (size_t i = 0; i < bounds.size(); ++i) {
    cumulative += c.latency_counts[i];
    o << "slamd_scan_latency_seconds_bucket{le=\"" << bounds[i] << "\"} " << cumulative << '\n';
  }
  cumulative += c.latency_counts.back();
  o << "slamd_scan_latency_seconds_bucket{le=\"+Inf\"} " << cumulative << '\n'
    << "slamd_scan_latency_seconds_sum " << c.latency_sum_s << '\n'
    << "slamd_scan_latency_seconds_count " << cumulative << '\n';
  metric("cpu_share", "gauge", "SLAM thread CPU time over robot time, latest scan.",
         last.cpu_share);
  metric("realtime_ratio", "gauge",
         "Robot time over SLAM processing time, latest scan (above 1: faster than real time).",
         last.realtime_ratio);
  metric("particles", "gauge", "Particles in the filter.", last.particles);
  metric("map_tiles", "gauge", "Tiles of the best particle's map.", snapshot->tiles.size());
  metric("map_version", "gauge", "Largest tile version.", snapshot->map_version);
  metric("link_up", "gauge", "1 when the link is reading its source.",
         l.state == hw::LinkState::kRunning ? 1 : 0);
  metric(
      "link_silent", "gauge",
      "1 when the link is running but has read no frame for a second (robot or transport quiet).",
      l.Silent() ? 1 : 0);
  metric("link_seconds_without_frames", "gauge", "Seconds since the latest CAN frame.",
         l.SecondsWithoutFrames());
  metric("link_frames_total", "counter", "CAN frames read from the source.", l.frames);
  metric("link_frames_rejected_total", "counter", "Frames dropped by reassembly or decoding.",
         l.reassembly.Rejected() + l.decoder.Rejected());
  metric("link_events_total", "counter", "Robot events queued for the SLAM.", l.events_queued);
  metric("link_queue_drops_total", "counter", "Robot events dropped because the queue was full.",
         l.queue_drops);
  metric("link_source_errors_total", "counter", "Errors of the frame source.", l.source_errors);
  o << "# HELP slamd_http_requests_total HTTP requests answered.\n"
       "# TYPE slamd_http_requests_total counter\n";
  {
    const std::lock_guard lock(requests_mutex);
    for (const auto& [key, count] : requests) {
      o << "slamd_http_requests_total{method=\"" << key.first << "\",code=\"" << key.second
        << "\"} " << count << '\n';
    }
  }
  metric("http_connections_timed_out_total", "counter",
         "Connections closed at the gate: no whole request in time.",
         server.connections_timed_out());
  metric("http_connections_evicted_total", "counter",
         "Waiting connections closed to admit newer ones (too many from one address, or in all).",
         server.connections_evicted());
  metric("event_stream_clients", "gauge", "Open event streams.", streams.load());
  metric("event_streams_rejected_total", "counter", "Event streams refused (cap reached).",
         streams_rejected.load());
  metric("jobs_running", "gauge", "Tuning jobs running.", jobs.running());
  metric("map_saves_total", "counter",
         "Saves of the map written (requests waiting for a save share it).", saves_made.load());
  o << "# HELP slamd_exports_made_total Whole-map and trajectory exports made (each at most once "
       "per snapshot and kind).\n# TYPE slamd_exports_made_total counter\n";
  for (const auto& [kind, e] : exports) {
    o << "slamd_exports_made_total{kind=\"" << kind << "\"} " << e.renders.load() << '\n';
  }
  return o.str();
}

void HttpServer::Impl::Setup() {
  using httplib::Request;
  using httplib::Response;
  // httplib's own pool only hands accepted connections to the gate (BoundedServer); the
  // workers that serve requests are the server's: every event stream holds one for its
  // lifetime (notes point 2), the others serve whole requests in arrival order.
  server.new_task_queue = [] { return new httplib::ThreadPool(2); };
  // Small responses must not wait for the client's delayed ACK (Nagle: +40 ms per request on
  // a keep-alive connection).
  server.set_tcp_nodelay(true);
  server.set_keep_alive_max_count(1000);
  // Short: an idle keep-alive connection holds a pool thread (stop() no longer waits for it).
  server.set_keep_alive_timeout(2);
  server.set_read_timeout(5);
  server.set_write_timeout(5);
  server.request_deadline = std::chrono::seconds(10);  // a whole request, head and body
  server.set_payload_max_length(options.max_body_bytes);
  server.max_body_bytes = options.max_body_bytes;
  // SO_REUSEADDR only: with SO_REUSEPORT (the default) two slamd could share a port silently.
  server.set_socket_options([](socket_t sock) {
    int yes = 1;
    setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof(yes));
  });
  server.set_pre_routing_handler([this](const Request& req, Response& res) {
    // The library hands a const request, but owns it mutably; Guard rewrites Accept-Encoding.
    return Guard(const_cast<Request&>(req), res);
  });
  server.set_logger([this](const Request& req, const Response& res) {
    // The method as a label only when it is one of HTTP's: whatever else a client sends as a
    // method (httplib answers 400) would grow the counters without bound and go into /metrics
    // unescaped.
    static const std::set<std::string> kMethods{"GET",    "HEAD",    "POST",  "PUT",    "PATCH",
                                                "DELETE", "OPTIONS", "TRACE", "CONNECT"};
    const std::string method = kMethods.count(req.method) ? req.method : "other";
    // A request the library could not parse (a malformed request line or header) is answered
    // 400 without reaching the guard; what follows it on the connection is not a request to
    // trust: it closes (1000 CRLFs once got 1000 answers on one connection).
    if (res.status == 400) t_close_connection = true;
    const std::lock_guard lock(requests_mutex);
    ++requests[{method, res.status}];
  });
  server.set_exception_handler([](const Request&, Response& res, std::exception_ptr ep) {
    std::string what = "unexpected error";
    try {
      std::rethrow_exception(ep);
    } catch (const std::exception& e) {
      what = e.what();
    } catch (...) {
    }
    SendProblem(res, 500, "Internal Server Error", what);
  });

  server.Get("/api/v1/health", [](const Request&, Response& res) {
    SendJson(res, {{"status", "ok"}});
  });
  server.Get("/api/v1/status",
             [this](const Request&, Response& res) { SendJson(res, StatusJson()); });

  server.Get("/api/v1/budget", [this](const Request&, Response& res) {
    const std::lock_guard lock(revision_mutex);
    res.set_header("ETag", BudgetEtag());
    SendJson(res, BudgetJson(service.Budget()));
  });
  server.Patch("/api/v1/budget",
               [this](const Request& req, Response& res) { HandleBudgetChange(req, res, true); });
  server.Put("/api/v1/budget",
             [this](const Request& req, Response& res) { HandleBudgetChange(req, res, false); });

  server.Get("/api/v1/params", [this](const Request&, Response& res) {
    const std::lock_guard lock(revision_mutex);
    res.set_header("ETag", ParamsEtag());
    SendJson(res, io::ParamsToJson(service.Params()));
  });
  server.Patch("/api/v1/params",
               [this](const Request& req, Response& res) { HandleParamsPatch(req, res); });

  server.Get("/api/v1/map", [this](const Request&, Response& res) {
    const auto s = service.Snapshot();
    json tiles = json::array();
    for (const TileRef& t : s->tiles) {
      tiles.push_back(
          {{"x", t.index.x}, {"y", t.index.y}, {"version", s->ReportedVersion(*t.tile)}});
    }
    SendJson(res, {{"resolution_m", s->resolution_m},
                   {"tile_size", kTileSize},
                   {"origin", {0.0, 0.0}},
                   {"version", s->map_version},
                   {"epoch", s->epoch},
                   {"tiles", std::move(tiles)}});
  });
  server.Get(R"(/api/v1/map/tiles/(-?\d{1,9})/(-?\d{1,9})\.png)",
             [this](const Request& req, Response& res) { HandleTile(req, res); });
  for (const char* kind : {"map.pgm", "map.yaml", "map.png", "trajectory.tum", "trajectory.json"}) {
    exports.try_emplace(kind);
  }
  const auto whole_map = [this](const std::string& kind) {
    return [this, kind](const Request&, Response& res) {
      ServeExport(
          "map." + kind, res,
          [&](const SlamSnapshot& s, std::string& body, std::string& type, std::string& error) {
            const OccupancyGrid grid = SnapshotGrid(s, service.encoded_logodds_limit());
            const io::GridImage image = io::MakeGridImage(grid);
            if (kind == "pgm") {
              body = io::EncodePgm(image);
              type = "image/x-portable-graymap";
            } else if (kind == "yaml") {
              body = io::MapYaml("map.pgm", image);
              type = "application/yaml";
            } else {
              const io::PngBytes png = io::EncodeGrayPng(image.width, image.height, image.gray);
              if (!png.ok()) {
                error = png.error;
                return false;
              }
              body.assign(png.bytes.begin(), png.bytes.end());
              type = "image/png";
            }
            return true;
          });
      if (res.status < 300) {
        res.set_header("Content-Disposition", "attachment; filename=\"map." + kind + "\"");
      }
    };
  };
  server.Get("/api/v1/map.pgm", whole_map("pgm"));
  server.Get("/api/v1/map.yaml", whole_map("yaml"));
  server.Get("/api/v1/map.png", whole_map("png"));

  server.Get("/api/v1/trajectory", [this](const Request& req, Response& res) {
    const std::string format = req.has_param("format") ? req.get_param_value("format") : "json";
    if (format != "json" && format != "tum") {
      SendProblem(res, 400, "Bad Request", "format must be json or tum, not \"" + format + "\"");
      return;
    }
    ServeExport("trajectory." + format, res,
                [&](const SlamSnapshot& s, std::string& body, std::string& type, std::string&) {
                  const std::vector<TimedPose> trajectory = ScanEndTrajectory(s);
                  if (format == "tum") {
                    body = io::FormatTum(trajectory);
                    type = "text/plain; charset=utf-8";
                    return true;
                  }
                  const auto rows = [](const std::vector<TimedPose>& poses) {
                    json list = json::array();
                    for (const TimedPose& p : poses) {
                      list.push_back({p.t, p.pose.x, p.pose.y, p.pose.theta});
                    }
                    return list;
                  };
                  json j = {{"slam", rows(trajectory)}};
                  if (service.simulated()) j["ground_truth"] = rows(service.GroundTruth());
                  body = Dump(j);
                  type = kJson;
                  return true;
                });
    if (format == "tum") {
      res.set_header("Content-Disposition", "attachment; filename=\"trajectory.tum\"");
    }
  });

  server.Get("/api/v1/events",
             [this](const Request& req, Response& res) { HandleEvents(req, res); });

  server.Post("/api/v1/map/save", [this](const Request& req, Response& res) {
    json body;
    if (ParseBody(req, res, "application/json", body)) HandleSave(res);
  });
  server.Post("/api/v1/reset", [this](const Request& req, Response& res) {
    json body;
    if (ParseBody(req, res, "application/json", body)) HandleReset(res);
  });

  server.Post("/api/v1/jobs/tune", [this](const Request& req, Response& res) {
    json body;
    if (!ParseBody(req, res, "application/json", body)) return;
    if (!jobs.configured()) {
      SendProblem(res, 409, "Conflict",
                  "slamd was started without --experiments: no recorded experiments to tune on");
      return;
    }
    TuneRequest request;
    const ConfigErrors errors = ParseTuneRequest(body, jobs.Experiments(), request);
    if (!errors.empty()) {
      SendProblem(res, 422, "Invalid tuning job", "no job was started", errors);
      return;
    }
    std::string conflict;
    const auto job = jobs.Start(request, conflict);
    if (!job) {
      SendProblem(res, 409, "Conflict", conflict);
      return;
    }
    res.set_header("Location", "/api/v1/jobs/" + (*job)["id"].get<std::string>());
    SendJson(res, *job, 202);
  });
  server.Get("/api/v1/jobs", [this](const Request&, Response& res) { SendJson(res, jobs.List()); });
  server.Get(R"(/api/v1/jobs/([^/]+))", [this](const Request& req, Response& res) {
    const auto job = jobs.Get(req.matches[1].str());
    if (!job) {
      SendProblem(res, 404, "Not Found", "no job " + req.matches[1].str());
      return;
    }
    SendJson(res, *job);
  });
  server.Delete(R"(/api/v1/jobs/([^/]+))", [this](const Request& req, Response& res) {
    const std::string id = req.matches[1].str();
    const int status = jobs.Delete(id);
    if (status == 404) {
      SendProblem(res, 404, "Not Found", "no job " + id);
      return;
    }
    SendJson(res, {{"id", id}, {"state", status == 202 ? "cancelling" : "deleted"}}, status);
  });

  server.Get("/metrics", [this](const Request&, Response& res) {
    res.set_content(MetricsText(), "text/plain; version=0.0.4; charset=utf-8");
  });

  if (!options.web_root.empty()) {
    const std::string vendor = options.web_root + "/node_modules/uplot/dist";
    if (std::filesystem::is_directory(vendor)) server.set_mount_point("/vendor/uplot", vendor);
    server.set_mount_point("/", options.web_root);
  }

  // Known routes answer 405 to other methods; anything else is 404, as problem+json.
  struct Route {
    std::regex pattern;
    std::string allow;
  };
  static const std::vector<Route> kRoutes = {
      {std::regex(
           R"(/api/v1/(health|status|map|map\.pgm|map\.yaml|map\.png|trajectory|events|jobs))"),
       "GET"},
      {std::regex(R"(/api/v1/budget)"), "GET, PUT, PATCH"},
      {std::regex(R"(/api/v1/params)"), "GET, PATCH"},
      {std::regex(R"(/api/v1/map/tiles/-?\d{1,9}/-?\d{1,9}\.png)"), "GET"},
      {std::regex(R"(/api/v1/(map/save|reset|jobs/tune))"), "POST"},
      {std::regex(R"(/api/v1/jobs/[^/]+)"), "GET, DELETE"},
      {std::regex(R"(/metrics)"), "GET"},
  };
  const auto fallback = [](const Request& req, Response& res) {
    for (const Route& route : kRoutes) {
      if (std::regex_match(req.path, route.pattern)) {
        res.set_header("Allow", route.allow);
        SendProblem(
            res, 405, "Method Not Allowed",
            req.method + " is not allowed on " + req.path + " (allowed: " + route.allow + ")");
        return;
      }
    }
    SendProblem(res, 404, "Not Found", "no route " + req.method + " " + req.path);
  };
  server.Get(".*", fallback);
  server.Post(".*", fallback);
  server.Put(".*", fallback);
  server.Patch(".*", fallback);
  server.Delete(".*", fallback);
  server.Options(".*", fallback);
}

HttpServer::HttpServer(SlamService& service, hw::Link& link, JobManager& jobs,
                       const HttpOptions& options)
    : impl_(std::make_unique<Impl>(service, link, jobs, options)) {
  impl_->Setup();
}

HttpServer::~HttpServer() { Stop(); }

int HttpServer::Bind(std::string& error) {
  auto& s = impl_->server;
  if (impl_->options.port == 0) {
    const int port = s.bind_to_any_port(impl_->options.bind);
    if (port <= 0) error = "cannot listen on " + impl_->options.bind + " (any port)";
    if (port > 0) s.WidenListenBacklog();
    return port > 0 ? port : -1;
  }
  if (!s.bind_to_port(impl_->options.bind, impl_->options.port)) {
    error = "cannot listen on " + impl_->options.bind + ":" + std::to_string(impl_->options.port) +
            " (in use, or not an address of this machine)";
    return -1;
  }
  s.WidenListenBacklog();
  return impl_->options.port;
}

void HttpServer::Run() {
  impl_->server.StartServing(static_cast<size_t>(impl_->options.max_streams) + 8);
  impl_->server.listen_after_bind();
  impl_->server.Shutdown();
}

std::string HttpServer::HandleInMemory(std::string_view request, size_t max_response_bytes) {
  return impl_->server.ProcessInMemory(request, max_response_bytes);
}

void HttpServer::Stop() {
  impl_->stopping = true;
  impl_->server.stop();
}

}  // namespace slam::server
