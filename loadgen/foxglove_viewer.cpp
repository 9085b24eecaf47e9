#include "loadgen/foxglove_viewer.hpp"

#include <boost/asio/connect.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/websocket.hpp>
#include <chrono>
#include <nlohmann/json.hpp>
#include <thread>

namespace slam::loadgen {

namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace websocket = beast::websocket;
using tcp = asio::ip::tcp;
using json = nlohmann::json;
using Clock = std::chrono::steady_clock;

void RecordFirst(std::atomic<int64_t>& slot, int64_t ms) {
  int64_t seen = slot.load();
  while (ms > seen && !slot.compare_exchange_weak(seen, ms)) {
  }
}

/// One connection: true if it was up (then ended), false if it could not be made.
bool Session(const Target& target, const std::string& token, const std::atomic<bool>& stop,
             FoxgloveStats& stats, bool first_connection) {
  asio::io_context io;
  websocket::stream<beast::tcp_stream> ws(io);
  beast::error_code ec;
  tcp::resolver resolver(io);
  const auto endpoints = resolver.resolve(target.host, std::to_string(target.port), ec);
  if (ec) return false;
  beast::get_lowest_layer(ws).expires_after(std::chrono::seconds(5));
  beast::get_lowest_layer(ws).connect(endpoints, ec);
  if (ec) return false;
  ws.set_option(websocket::stream_base::decorator([&token](websocket::request_type& req) {
    req.set(beast::http::field::sec_websocket_protocol, "foxglove.websocket.v1");
    if (!token.empty()) req.set(beast::http::field::authorization, "Bearer " + token);
  }));
  ws.handshake(target.host + ":" + std::to_string(target.port), "/", ec);
  if (ec) return false;
  beast::get_lowest_layer(ws).expires_never();
  stats.connected.fetch_add(1);
  stats.connects.fetch_add(1);
  const auto connected_at = Clock::now();
  const auto since = [&] {
    return std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - connected_at)
        .count();
  };

  // Channel ids of /map and /pose, and the subscriptions (subscription id = channel id).
  uint32_t map_channel = 0, pose_channel = 0;
  bool got_map = false, got_pose = false, failed = false;
  beast::flat_buffer buffer;
  std::function<void()> read = [&] {
    ws.async_read(buffer, [&](beast::error_code error, size_t) {
      if (error) {
        failed = true;
        return;
      }
      const std::string data = beast::buffers_to_string(buffer.data());
      buffer.consume(buffer.size());
      if (ws.got_binary()) {
        stats.messages.fetch_add(1);
        stats.bytes.fetch_add(static_cast<int64_t>(data.size()));
        if (data.size() >= 5 && data[0] == 1) {
          const uint32_t sub = static_cast<uint8_t>(data[1]) |
                               (static_cast<uint32_t>(static_cast<uint8_t>(data[2])) << 8) |
                               (static_cast<uint32_t>(static_cast<uint8_t>(data[3])) << 16) |
                               (static_cast<uint32_t>(static_cast<uint8_t>(data[4])) << 24);
          if (sub == map_channel) {
            stats.maps.fetch_add(1);
            if (!got_map && first_connection) RecordFirst(stats.first_map_ms, since());
            got_map = true;
          } else if (sub == pose_channel) {
            stats.poses.fetch_add(1);
            if (!got_pose && first_connection) RecordFirst(stats.first_pose_ms, since());
            got_pose = true;
          }
        }
      } else {
        const json message = json::parse(data, nullptr, false);
        const std::string op = message.is_object() ? message.value("op", "") : "";
        if (op == "status") stats.statuses.fetch_add(1);
        if (op == "advertise" && message.contains("channels")) {
          json subscriptions = json::array();
          for (const json& channel : message["channels"]) {
            const auto id = channel.value("id", 0u);
            if (channel.value("topic", "") == "/map") map_channel = id;
            if (channel.value("topic", "") == "/pose") pose_channel = id;
            subscriptions.push_back({{"id", id}, {"channelId", id}});
          }
          ws.text(true);
          beast::error_code write_error;
          ws.write(asio::buffer(json{{"op", "subscribe"}, {"subscriptions", subscriptions}}.dump()),
                   write_error);
          if (write_error) {
            failed = true;
            return;
          }
        }
      }
      read();
    });
  };
  read();
  while (!stop && !failed) io.run_for(std::chrono::milliseconds(100));
  stats.connected.fetch_sub(1);
  if (!stop) stats.disconnects.fetch_add(1);
  beast::get_lowest_layer(ws).socket().close(ec);
  io.run_for(std::chrono::milliseconds(100));  // the read's cancellation
  return true;
}

}  // namespace

void RunFoxgloveViewer(const Target& target, const std::string& token,
                       const std::atomic<bool>& stop, FoxgloveStats& stats) {
  bool first = true;
  while (!stop) {
    if (!Session(target, token, stop, stats, first)) {
      stats.refused.fetch_add(1);
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    first = false;
  }
}

}  // namespace slam::loadgen
