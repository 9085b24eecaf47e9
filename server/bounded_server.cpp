#include "server/bounded_server.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <functional>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>
#include <vector>

#include "engine/thread_safety.hpp"
#include "server/request_guard.hpp"

namespace slam::server {
namespace {

using Clock = std::chrono::steady_clock;
using SteadyTime = Clock::time_point;

// A connection's stream for one request at a time, with the request's byte budget and deadline
// (see bounded_server.hpp).
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

/// A request in memory and its response (BoundedServer::ProcessInMemory): reads from the request
/// bytes, writes into a string until `cap` bytes, then reports itself unwritable (which ends an
/// event stream at its next wake-up).
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

}  // namespace

void CloseConnectionAfterResponse() { t_close_connection = true; }

const std::string* RequestHeadAsReceived() { return t_request_head; }

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

namespace {

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

}  // namespace

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
    MutexLock lock(mutex_);
    for (Connection& c : incoming_) Close(c);
    incoming_.clear();
  }
  /// A connection to wait on (from any thread).
  void Add(Connection connection) {
    {
      MutexLock lock(mutex_);
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
          MutexLock lock(mutex_);
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
  Mutex mutex_;
  std::vector<Connection> incoming_ SLAM_GUARDED_BY(mutex_);
  std::vector<Connection> waiting_;  // the gate thread's own
  std::atomic<uint64_t> timed_out_{0};
  std::atomic<uint64_t> evicted_{0};
};

BoundedServer::BoundedServer() = default;

BoundedServer::~BoundedServer() { Shutdown(); }

std::string BoundedServer::ProcessInMemory(std::string_view request, size_t max_response_bytes) {
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

void BoundedServer::WidenListenBacklog() {
  const socket_t sock = svr_sock_;
  if (sock != INVALID_SOCKET) ::listen(sock, 256);
}

void BoundedServer::StartServing(size_t workers) {
  gate_ = std::make_unique<Gate>([this](Connection c) { Dispatch(std::move(c)); }, max_head_bytes,
                                 max_body_bytes);
  gate_->request_deadline = request_deadline;
  workers_ = std::make_unique<httplib::ThreadPool>(workers);
  gate_->Start();
}

void BoundedServer::Shutdown() {
  if (gate_) gate_->Stop();
  if (workers_) {
    workers_->shutdown();
    workers_.reset();
  }
}

uint64_t BoundedServer::connections_timed_out() const { return gate_ ? gate_->timed_out() : 0; }

uint64_t BoundedServer::connections_evicted() const { return gate_ ? gate_->evicted() : 0; }

bool BoundedServer::process_and_close_socket(socket_t sock) {
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

void BoundedServer::Dispatch(Connection c) {
  auto held = std::make_shared<Connection>(std::move(c));
  workers_->enqueue([this, held] { Serve(std::move(*held)); });
}

void BoundedServer::Serve(Connection c) {
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

}  // namespace slam::server
