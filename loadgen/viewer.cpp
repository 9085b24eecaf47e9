#include "loadgen/viewer.hpp"

#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <iterator>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

namespace slam::loadgen {
namespace {

using json = nlohmann::json;

/// A connected TCP socket to `target`, or -1.
int ConnectTo(const Target& target) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  if (::getaddrinfo(target.host.c_str(), std::to_string(target.port).c_str(), &hints, &found) !=
      0) {
    return -1;
  }
  int fd = -1;
  for (addrinfo* a = found; a != nullptr && fd < 0; a = a->ai_next) {
    fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
    if (fd >= 0 && ::connect(fd, a->ai_addr, a->ai_addrlen) != 0) {
      ::close(fd);
      fd = -1;
    }
  }
  ::freeaddrinfo(found);
  return fd;
}

}  // namespace

void TileBook::Note(int64_t x, int64_t y) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (tiles_.size() < 4096) tiles_[{x, y}] = true;
}

std::optional<std::pair<int64_t, int64_t>> TileBook::Pick(uint64_t k) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (tiles_.empty()) return std::nullopt;
  auto it = tiles_.begin();
  std::advance(it, static_cast<std::ptrdiff_t>(k % tiles_.size()));
  return it->first;
}

Viewer::Viewer(const Target& target, const std::atomic<bool>& stop, ViewerStats& stats,
               TileBook& tiles)
    : target_(target),
      stop_(stop),
      stats_(stats),
      tiles_(tiles),
      tile_client_(target.host, target.port) {
  tile_client_.set_keep_alive(true);
  tile_client_.set_tcp_nodelay(true);
  tile_client_.set_connection_timeout(2);
  tile_client_.set_read_timeout(10);
}

void Viewer::Run() {
  while (!stop_) {
    if (!Connect()) {
      // Refused or unreachable: try again a little later (a browser would wait Retry-After).
      for (int i = 0; i < 10 && !stop_; ++i)
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
      continue;
    }
    ++stats_.connected;
    ++stats_.connects;
    ReadUntilEnd();
    --stats_.connected;
    ::close(fd_);
    fd_ = -1;
    if (!stop_) ++stats_.disconnects;
  }
}

bool Viewer::Connect() {
  fd_ = ConnectTo(target_);
  if (fd_ < 0) return false;
  std::string request = "GET /api/v1/events HTTP/1.1\r\nHost: " + target_.host + ":" +
                        std::to_string(target_.port) +
                        "\r\nAccept: text/event-stream\r\nCache-Control: no-cache\r\n";
  if (!last_event_id_.empty()) request += "Last-Event-ID: " + last_event_id_ + "\r\n";
  request += "\r\n";
  if (::send(fd_, request.data(), request.size(), MSG_NOSIGNAL) !=
      static_cast<ssize_t>(request.size())) {
    return Fail();
  }
  wire_.clear();
  text_.clear();
  // Response head.
  const auto deadline = Clock::now() + std::chrono::seconds(5);
  size_t head_end = std::string::npos;
  while ((head_end = wire_.find("\r\n\r\n")) == std::string::npos) {
    if (Clock::now() > deadline || !ReadSome(200)) return Fail();
  }
  const std::string head = wire_.substr(0, head_end);
  wire_.erase(0, head_end + 4);
  const int status = head.size() > 12 ? std::atoi(head.c_str() + 9) : -1;
  if (status != 200) {
    ++stats_.rejected;
    return Fail();
  }
  std::string lower_head = head;
  std::transform(lower_head.begin(), lower_head.end(), lower_head.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  chunked_ = lower_head.find("transfer-encoding: chunked") != std::string::npos;
  return true;
}

bool Viewer::Fail() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  return false;
}

/// Reads what arrives within `timeout_ms`; false on end of stream or error.
bool Viewer::ReadSome(int timeout_ms) {
  pollfd waiter{fd_, POLLIN, 0};
  const int ready = ::poll(&waiter, 1, timeout_ms);
  if (ready == 0) return true;
  if (ready < 0) return errno == EINTR;
  char buffer[16384];
  const ssize_t n = ::recv(fd_, buffer, sizeof buffer, 0);
  if (n <= 0) return false;
  wire_.append(buffer, static_cast<size_t>(n));
  return true;
}

void Viewer::ReadUntilEnd() {
  while (!stop_) {
    if (!ReadSome(200)) return;
    if (!Decode()) return;
    HandleEvents();
  }
}

/// Moves stream bytes to `text_`, undoing chunked framing; false at the final chunk.
bool Viewer::Decode() {
  if (!chunked_) {
    text_ += wire_;
    wire_.clear();
    return true;
  }
  while (true) {
    const size_t line_end = wire_.find("\r\n");
    if (line_end == std::string::npos) return true;
    const size_t size = std::strtoul(wire_.substr(0, line_end).c_str(), nullptr, 16);
    if (size == 0) return false;
    if (wire_.size() < line_end + 2 + size + 2) return true;
    text_ += wire_.substr(line_end + 2, size);
    wire_.erase(0, line_end + 2 + size + 2);
  }
}

void Viewer::HandleEvents() {
  size_t end;
  while ((end = text_.find("\n\n")) != std::string::npos) {
    const std::string block = text_.substr(0, end);
    text_.erase(0, end + 2);
    std::string name = "message", id, data;
    bool has_field = false;
    std::istringstream lines(block);
    std::string line;
    while (std::getline(lines, line)) {
      if (!line.empty() && line.back() == '\r') line.pop_back();
      if (line.empty() || line.front() == ':') continue;  // comments are pings
      const size_t colon = line.find(':');
      const std::string field = line.substr(0, colon);
      std::string value = colon == std::string::npos ? "" : line.substr(colon + 1);
      if (!value.empty() && value.front() == ' ') value.erase(0, 1);
      has_field = true;
      if (field == "event") name = value;
      if (field == "id") id = value;
      if (field == "data") data += value;
    }
    if (!has_field) continue;
    ++stats_.events;
    if (!id.empty()) last_event_id_ = id;
    if (name == "tiles") FetchTiles(data);
  }
}

void Viewer::FetchTiles(const std::string& data) {
  const json parsed = json::parse(data, nullptr, false);
  if (!parsed.is_object() || !parsed.contains("tiles") || !parsed["tiles"].is_array()) return;
  for (const auto& tile : parsed["tiles"]) {
    if (stop_) return;
    if (!tile.contains("x") || !tile.contains("y") || !tile["x"].is_number_integer() ||
        !tile["y"].is_number_integer()) {
      continue;
    }
    const int64_t x = tile["x"].get<int64_t>();
    const int64_t y = tile["y"].get<int64_t>();
    tiles_.Note(x, y);
    ++stats_.tiles_announced;
    std::string path = "/api/v1/map/tiles/" + std::to_string(x) + "/" + std::to_string(y) + ".png";
    if (tile.contains("version")) path += "?v=" + tile["version"].dump();
    const auto start = Clock::now();
    const auto result = tile_client_.Get(path);
    const double ms = SecondsBetween(start, Clock::now()) * 1e3;
    // A tile can vanish between the announcement and the fetch only through a reset: 404 is
    // then what the page sees too, not a server error.
    const int status = result ? result->status : 0;
    tile_record_.Add(ms, status == 404 ? 200 : status);
  }
}

}  // namespace slam::loadgen
