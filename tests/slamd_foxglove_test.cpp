// slamd's Foxglove WebSocket server as a black box, with a small client of Boost.Beast (the
// official npm client checks the schemas: tests/foxglove/). This suite also runs under the
// sanitizers (scripts/sanitize), where the slamd child is instrumented too: the serving thread,
// the snapshot watcher and the SLAM thread meet here.

#include <unistd.h>

#include <algorithm>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/websocket.hpp>
#include <chrono>
#include <optional>

#include "tests/slamd_harness.hpp"

namespace slamd_test {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace websocket = beast::websocket;
using tcp = asio::ip::tcp;

/// A blocking Foxglove client: every read has a deadline.
class Client {
 public:
  explicit Client(int port) : ws_(io_) {
    beast::get_lowest_layer(ws_).connect(
        tcp::endpoint(asio::ip::make_address("127.0.0.1"), static_cast<uint16_t>(port)));
    ws_.set_option(websocket::stream_base::decorator([](websocket::request_type& req) {
      req.set(beast::http::field::sec_websocket_protocol, "foxglove.websocket.v1");
    }));
    ws_.handshake(response_, "127.0.0.1:" + std::to_string(port), "/");
  }

  const websocket::response_type& response() const { return response_; }

  void Send(const json& message) { SendText(message.dump()); }
  void SendText(const std::string& text) {
    ws_.text(true);
    ws_.write(asio::buffer(text));
  }
  /// One text message in frames of `frame_bytes`.
  void SendFragmented(const std::string& text, size_t frame_bytes) {
    ws_.text(true);
    for (size_t at = 0; at < text.size(); at += frame_bytes) {
      const size_t n = std::min(frame_bytes, text.size() - at);
      ws_.write_some(at + n == text.size(), asio::buffer(text.data() + at, n));
    }
  }

  /// The next message: text as JSON, or a message-data frame (its subscription and payload).
  struct Message {
    bool binary = false;
    json text;
    uint32_t subscription = 0;
    json payload;
  };
  std::optional<Message> Next(double timeout_s = 10.0) {
    beast::get_lowest_layer(ws_).expires_after(
        std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000)));
    beast::flat_buffer buffer;
    beast::error_code ec;
    ws_.read(buffer, ec);
    if (ec) return std::nullopt;
    const std::string data = beast::buffers_to_string(buffer.data());
    Message m;
    m.binary = ws_.got_binary();
    if (!m.binary) {
      m.text = json::parse(data, nullptr, false);
    } else if (data.size() >= 13 && data[0] == 1) {
      for (size_t i = 0; i < 4; ++i) {
        m.subscription |= static_cast<uint32_t>(static_cast<uint8_t>(data[1 + i])) << (8 * i);
      }
      m.payload = json::parse(data.substr(13), nullptr, false);
    }
    return m;
  }

  /// Reads until a text message with this op (skipping message data), within `timeout_s`.
  std::optional<json> NextOp(const std::string& op, double timeout_s = 10.0) {
    const auto deadline = After(timeout_s);
    while (Clock::now() < deadline) {
      const auto m = Next(std::chrono::duration<double>(deadline - Clock::now()).count());
      if (!m) return std::nullopt;
      if (!m->binary && m->text.value("op", "") == op) return m->text;
    }
    return std::nullopt;
  }

  /// Subscribes to every advertised channel (subscription id = channel id); topic by id.
  std::map<uint32_t, std::string> SubscribeAll() {
    const auto advertise = NextOp("advertise");
    std::map<uint32_t, std::string> topics;
    if (!advertise) return topics;
    json subscriptions = json::array();
    for (const json& c : (*advertise)["channels"]) {
      topics[c["id"].get<uint32_t>()] = c["topic"].get<std::string>();
      subscriptions.push_back({{"id", c["id"]}, {"channelId", c["id"]}});
    }
    Send({{"op", "subscribe"}, {"subscriptions", subscriptions}});
    return topics;
  }

 private:
  asio::io_context io_;
  websocket::stream<beast::tcp_stream> ws_;
  websocket::response_type response_;
};

class FoxgloveSlamd : public SlamdSuite {
 protected:
  static void SetUpTestSuite() {
    foxglove_port_ = FreeTcpPort();
    // A small budget keeps scans coming under the sanitizers too.
    StartShared({"--budget", "2000", "--foxglove-port", std::to_string(foxglove_port_),
                 "--foxglove-buffer-kb", "64"});
  }
  static void TearDownTestSuite() { StopShared(); }
  static inline int foxglove_port_ = 0;
};

TEST_F(FoxgloveSlamd, ServerInfoThenEveryChannelOnSubscription) {
  Client client(foxglove_port_);
  EXPECT_EQ(client.response()[beast::http::field::sec_websocket_protocol], "foxglove.websocket.v1");
  const auto info = client.NextOp("serverInfo");
  ASSERT_TRUE(info);
  EXPECT_EQ((*info)["capabilities"], json({"parameters", "parametersSubscribe", "clientPublish"}));
  EXPECT_EQ((*info)["supportedEncodings"], json({"json"}));
  const auto topics = client.SubscribeAll();
  ASSERT_EQ(topics.size(), 6u);  // simulated: /ground_truth too
  std::set<std::string> seen;
  const auto deadline = After(20);
  while (seen.size() < topics.size() && Clock::now() < deadline) {
    const auto m = client.Next();
    ASSERT_TRUE(m) << "no message within 10 s; seen " << seen.size();
    if (!m->binary) continue;
    ASSERT_TRUE(topics.count(m->subscription)) << m->subscription;
    ASSERT_TRUE(m->payload.is_object()) << topics.at(m->subscription);
    seen.insert(topics.at(m->subscription));
  }
  EXPECT_EQ(seen, std::set<std::string>(
                      {"/map", "/pose", "/trajectory", "/tf", "/scan", "/ground_truth"}));
}

TEST_F(FoxgloveSlamd, SetParametersChangesTheBudgetAsRestDoesAndRefusesBadValues) {
  Client client(foxglove_port_);
  client.Send({{"op", "setParameters"},
               {"id", "one"},
               {"parameters", {{{"name", "budget.rays_per_scan"}, {"value", 3000.0}}}}});
  const auto values = client.NextOp("parameterValues");
  ASSERT_TRUE(values);
  EXPECT_EQ((*values)["id"], "one");
  EXPECT_EQ((*values)["parameters"][0]["value"], 3000.0);
  EXPECT_EQ(GetJson(http(), kBudgetPath)["rays_per_scan"], 3000);

  client.Send({{"op", "setParameters"},
               {"parameters", {{{"name", "budget.policy"}, {"value", "greedy"}}}}});
  const auto status = client.NextOp("status");
  ASSERT_TRUE(status);
  EXPECT_EQ((*status)["level"], 2);
  EXPECT_NE((*status)["message"].get<std::string>().find("budget.policy"), std::string::npos);
  EXPECT_EQ(GetJson(http(), kBudgetPath)["policy"], "fixed");
  // Back as the suite started.
  EXPECT_EQ(http().MergePatch(kBudgetPath, R"({"rays_per_scan": 2000})").status, 200);
}

TEST_F(FoxgloveSlamd, AStalledClientLosesMessagesOthersDoNot) {
  Client stalled(foxglove_port_);
  stalled.SubscribeAll();  // and then reads nothing
  Client reader(foxglove_port_);
  const auto topics = reader.SubscribeAll();
  uint32_t pose_channel = 0;
  for (const auto& [id, topic] : topics) {
    if (topic == "/pose") pose_channel = id;
  }
  const auto dropped = [&] {
    const Reply metrics = http().Get("/metrics");
    const std::string name = "\nslamd_foxglove_messages_dropped_total ";
    const size_t at = metrics.body.find(name);
    return at == std::string::npos ? -1.0 : std::stod(metrics.body.substr(at + name.size()));
  };
  int poses = 0;
  const auto deadline = After(90);
  while (dropped() <= 0 && Clock::now() < deadline) {
    const auto m = reader.Next();
    ASSERT_TRUE(m) << "the reading client got nothing for 10 s while another stalled";
    if (m->binary && m->subscription == pose_channel) ++poses;
  }
  EXPECT_GT(dropped(), 0) << "nothing dropped for the stalled client within 90 s";
  EXPECT_GT(poses, 0);
  // The reader still gets every new pose.
  const auto pose = [&]() -> bool {
    for (int i = 0; i < 200; ++i) {
      const auto m = reader.Next();
      if (!m) return false;
      if (m->binary && m->subscription == pose_channel) return true;
    }
    return false;
  };
  EXPECT_TRUE(pose());
}

TEST_F(FoxgloveSlamd, UpgradesThatBreakTheRulesAreRefused) {
  const auto status_of = [&](const std::string& request) {
    return RawExchange(foxglove_port_, request, 2.0).status;  // a 101 keeps the connection
  };
  const std::string upgrade =
      "GET / HTTP/1.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
      "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n";
  EXPECT_EQ(status_of("GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"), 426);
  EXPECT_EQ(status_of(upgrade + "Host: evil.example\r\nSec-WebSocket-Protocol: "
                                "foxglove.websocket.v1\r\n\r\n"),
            403);
  EXPECT_EQ(status_of(upgrade + "Host: 127.0.0.1\r\nSec-WebSocket-Protocol: chat\r\n\r\n"), 400);
  EXPECT_EQ(status_of(upgrade + "Host: 127.0.0.1\r\nSec-WebSocket-Protocol: foxglove.sdk.v1, "
                                "foxglove.websocket.v1\r\n\r\n"),
            101);
}

TEST_F(FoxgloveSlamd, ConnectionsThatNeverUpgradeAreBoundedAndDoNotLockOthersOut) {
  // Connections that send nothing hold their sockets until the handshake timeout (10 s); beyond
  // 16 of one address, the oldest of them is closed, and the newest stays.
  std::vector<int> idle;
  for (int i = 0; i < 17; ++i) {
    const int fd = ConnectTo(foxglove_port_);
    ASSERT_GE(fd, 0);
    idle.push_back(fd);
    Nap();  // accepted in this order
  }
  std::string got;
  EXPECT_EQ(ReadSome(idle.front(), got, 5.0), 0) << "the oldest idle connection was not closed";
  EXPECT_EQ(ReadSome(idle.back(), got, 0.5), -1) << "the newest idle connection was closed";
  // Beside them, a client connects at once.
  const auto start = Clock::now();
  Client client(foxglove_port_);
  EXPECT_TRUE(client.NextOp("serverInfo", 5.0));
  EXPECT_LT(SecondsSince(start), 1.0);
  for (const int fd : idle) ::close(fd);
}

TEST_F(FoxgloveSlamd, AMessageTooLongIsAnsweredWithAStatusAndTheConnectionStays) {
  // docs/http-api.md: more than 64 KiB is answered with a status error; the connection stays
  // (before: Beast closed it with 1009).
  Client client(foxglove_port_);
  ASSERT_TRUE(client.NextOp("advertise"));
  client.SendText(std::string(65 * 1024, ' ') + "{}");
  auto status = client.NextOp("status");
  ASSERT_TRUE(status) << "no status for a 65 KiB message (closed?)";
  EXPECT_EQ((*status)["level"], 2);
  EXPECT_NE((*status)["message"].get<std::string>().find("64 KiB"), std::string::npos)
      << (*status)["message"];
  // Far longer, in several frames: discarded as it comes, the same answer.
  client.SendFragmented(std::string(3 << 20, 'x'), 256 * 1024);
  status = client.NextOp("status");
  ASSERT_TRUE(status) << "no status for a 3 MiB message (closed?)";
  EXPECT_NE((*status)["message"].get<std::string>().find("3145728 bytes"), std::string::npos)
      << (*status)["message"];
  // The connection still serves: a message of exactly 64 KiB is parsed as usual.
  std::string request = R"({"op": "getParameters", "parameterNames": [], "id": "after"})";
  request += std::string(64 * 1024 - request.size(), ' ');
  client.SendText(request);
  const auto values = client.NextOp("parameterValues");
  ASSERT_TRUE(values) << "the connection did not stay after the long messages";
  EXPECT_EQ((*values)["id"], "after");
}

}  // namespace
}  // namespace slamd_test
