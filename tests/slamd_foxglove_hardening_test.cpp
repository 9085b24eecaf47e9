// slamd's Foxglove port under hostile clients (issue 46): the admission rule on its own
// (server/connection_admission.hpp), then slamd as a child process: one address's half-open
// upgrades and idle watch-only pages do not lock out a client of another address, and clients that
// flood control messages without reading their replies neither grow slamd's memory beyond a bound
// nor leave it grown once they are gone. Clients bind to several loopback addresses (127.0.0.x)
// before they connect, as clients of different machines would come.

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/websocket.hpp>
#include <chrono>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "server/api_json.hpp"
#include "server/connection_admission.hpp"
#include "server/foxglove_protocol.hpp"
#include "tests/slamd_harness.hpp"

namespace slamd_test {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace websocket = beast::websocket;
using tcp = asio::ip::tcp;
using slam::server::Admission;
using slam::server::Admit;
using slam::server::HeldConnection;

// ---------------------------------------------------------------------------------------------
// The admission rule

Clock::time_point At(int seconds) { return Clock::time_point{} + std::chrono::seconds(seconds); }

TEST(ConnectionAdmission, AdmitsUnderTheCapsWithoutClosingAnything) {
  const std::vector<HeldConnection> held = {{"127.0.0.2", At(1), 0}, {"127.0.0.3", At(2), 0}};
  const Admission a = Admit(held, "127.0.0.2", 0, {2, 3});
  EXPECT_TRUE(a.admit);
  EXPECT_FALSE(a.evict);
}

TEST(ConnectionAdmission, AnAddressAtItsCapLosesItsOwnOldest) {
  const std::vector<HeldConnection> held = {
      {"127.0.0.2", At(5), 0}, {"127.0.0.3", At(1), 0}, {"127.0.0.2", At(3), 0}};
  const Admission a = Admit(held, "127.0.0.2", 0, {2, 10});
  EXPECT_TRUE(a.admit);
  EXPECT_EQ(a.evict, 2u);  // 127.0.0.2's oldest, not the older one of 127.0.0.3
}

TEST(ConnectionAdmission, AtTheTotalTheFullestAddressGivesWaySoAnotherAlwaysGetsIn) {
  std::vector<HeldConnection> held;
  for (int i = 0; i < 6; ++i) held.push_back({"127.0.0.2", At(10 + i), 0});
  held.push_back({"127.0.0.4", At(1), 0});
  held.push_back({"127.0.0.4", At(2), 0});
  const Admission a = Admit(held, "127.0.0.3", 0, {8, 8});
  EXPECT_TRUE(a.admit);
  EXPECT_EQ(a.evict, 0u);  // the oldest of 127.0.0.2, which holds the most
  // On a tie, the newcomer's own address gives way.
  const std::vector<HeldConnection> tie = {{"127.0.0.2", At(1), 0}, {"127.0.0.3", At(2), 0}};
  EXPECT_EQ(Admit(tie, "127.0.0.3", 0, {4, 2}).evict, 1u);
}

TEST(ConnectionAdmission, LowerRanksGiveWayFirstAndNeverDisplaceHigherOnes) {
  // Watch-only pages (rank 0) and clients that may change the budget (rank 1).
  const std::vector<HeldConnection> held = {
      {"127.0.0.1", At(1), 1}, {"127.0.0.1", At(2), 0}, {"127.0.0.1", At(3), 0}};
  const Admission writer = Admit(held, "127.0.0.1", 1, {3, 16});
  EXPECT_TRUE(writer.admit);
  EXPECT_EQ(writer.evict, 1u);  // the oldest page, not the older writer
  const Admission page = Admit(held, "127.0.0.1", 0, {3, 16});
  EXPECT_EQ(page.evict, 1u);
  const std::vector<HeldConnection> writers = {{"127.0.0.1", At(1), 1}, {"127.0.0.1", At(2), 1}};
  const Admission refused = Admit(writers, "127.0.0.1", 0, {2, 16});
  EXPECT_FALSE(refused.admit);
  EXPECT_FALSE(refused.evict);
}

// ---------------------------------------------------------------------------------------------
// Replies a client's message can cost

/// A subscribe message of 1800 subscriptions to channels that do not exist (54 KB): before,
/// each was answered with a status of its own.
std::string InvalidSubscribe() {
  json subscriptions = json::array();
  for (int i = 0; i < 1800; ++i) subscriptions.push_back({{"id", i}, {"channelId", 1000 + i}});
  return json{{"op", "subscribe"}, {"subscriptions", subscriptions}}.dump();
}

TEST(FoxgloveReplies, ASubscribeOfManyBadSubscriptionsCostsAFewStatusesNotOneEach) {
  namespace fox = slam::server::foxglove;
  slam::BudgetSettings budget;
  fox::ClientProtocol client(
      fox::Channels(true), true,
      {[&] { return budget; },
       [&](const json& patch) { return slam::server::MergeBudget(budget, patch); }});
  const fox::Effects e = client.OnText(InvalidSubscribe());
  EXPECT_TRUE(e.refused);
  EXPECT_TRUE(e.subscribed.empty());
  ASSERT_EQ(e.replies.size(), fox::kMaxRefusalsNamed + 1);
  EXPECT_EQ(e.replies.front()["message"], "no channel 1000");
  EXPECT_EQ(e.replies.back()["message"], "1792 more subscriptions of this message refused");
  const fox::Effects long_one = client.OnTooLong(70000);
  ASSERT_EQ(long_one.replies.size(), 1u);
  EXPECT_EQ(long_one.replies[0]["level"], fox::kError);
  EXPECT_EQ(long_one.replies[0]["message"],
            "a message of 70000 bytes was discarded: at most 64 KiB a message");
}

// ---------------------------------------------------------------------------------------------
// Sockets from a chosen loopback address

/// A TCP connection to 127.0.0.1:`port` from `source` (another 127.0.0.x); -1 on failure.
int ConnectFrom(const std::string& source, int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return -1;
  sockaddr_in local{};
  local.sin_family = AF_INET;
  ::inet_pton(AF_INET, source.c_str(), &local.sin_addr);
  sockaddr_in remote{};
  remote.sin_family = AF_INET;
  remote.sin_port = htons(static_cast<uint16_t>(port));
  remote.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::bind(fd, reinterpret_cast<sockaddr*>(&local), sizeof local) != 0 ||
      ::connect(fd, reinterpret_cast<sockaddr*>(&remote), sizeof remote) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

/// A blocking Foxglove client from a chosen loopback address; Open throws what the upgrade met.
class Client {
 public:
  Client() : ws_(io_) {}

  /// Connects from `source` and upgrades (with `origin` as the Origin header, when not empty).
  void Open(const std::string& source, int port, const std::string& origin = "",
            int receive_buffer = 0) {
    auto& socket = beast::get_lowest_layer(ws_).socket();
    socket.open(tcp::v4());
    if (receive_buffer > 0)
      socket.set_option(asio::socket_base::receive_buffer_size(receive_buffer));
    socket.bind(tcp::endpoint(asio::ip::make_address(source), 0));
    beast::get_lowest_layer(ws_).expires_after(std::chrono::seconds(5));
    beast::get_lowest_layer(ws_).connect(
        tcp::endpoint(asio::ip::make_address("127.0.0.1"), static_cast<uint16_t>(port)));
    ws_.set_option(websocket::stream_base::decorator([origin](websocket::request_type& req) {
      req.set(beast::http::field::sec_websocket_protocol, "foxglove.websocket.v1");
      if (!origin.empty()) req.set(beast::http::field::origin, origin);
    }));
    ws_.handshake("127.0.0.1:" + std::to_string(port), "/");
    beast::get_lowest_layer(ws_).expires_never();
  }

  /// Writes a text message; false once the connection failed.
  bool Send(const std::string& text) {
    beast::error_code ec;
    ws_.text(true);
    ws_.write(asio::buffer(text), ec);
    return !ec;
  }

  /// The next text message with this op within `timeout_s` (message data skipped), or nullopt
  /// when none came or the connection closed.
  std::optional<json> NextOp(const std::string& op, double timeout_s = 5.0) {
    const auto deadline = After(timeout_s);
    while (Clock::now() < deadline) {
      beast::get_lowest_layer(ws_).expires_at(deadline);
      beast::flat_buffer buffer;
      beast::error_code ec;
      ws_.read(buffer, ec);
      if (ec) return std::nullopt;
      if (ws_.got_binary()) continue;
      json m = json::parse(beast::buffers_to_string(buffer.data()), nullptr, false);
      if (m.is_object() && m.value("op", "") == op) return m;
    }
    return std::nullopt;
  }

  /// Shuts the socket down (wakes a thread blocked writing on it).
  void Shutdown() {
    beast::error_code ignored;
    beast::get_lowest_layer(ws_).socket().shutdown(tcp::socket::shutdown_both, ignored);
  }

 private:
  asio::io_context io_;
  websocket::stream<beast::tcp_stream> ws_;
};

std::string MetricsBody(int http_port) {
  Http http("127.0.0.1", http_port);
  return http.Get("/metrics").body;
}

// ---------------------------------------------------------------------------------------------
// One address does not lock others out

class FoxgloveAdmission : public SlamdSuite {
 protected:
  static void SetUpTestSuite() {
    foxglove_port_ = FreeTcpPort();
    StartShared({"--budget", "2000", "--foxglove-port", std::to_string(foxglove_port_)});
  }
  static void TearDownTestSuite() { StopShared(); }
  static inline int foxglove_port_ = 0;
};

TEST_F(FoxgloveAdmission, HalfOpenUpgradesAndIdlePagesOfOneAddressDoNotLockAnotherOut) {
  // 16 idle watch-only connections of a page of another site, then 64 upgrades that never
  // finish their request, all from 127.0.0.2 (before: every other client was refused, 503 or
  // closed at once, until they timed out).
  std::vector<std::unique_ptr<Client>> pages;
  for (int i = 0; i < 16; ++i) {
    pages.push_back(std::make_unique<Client>());
    ASSERT_NO_THROW(pages.back()->Open("127.0.0.2", foxglove_port_, "http://evil.example"))
        << "watch-only connection " << i;
  }
  std::vector<int> half_open;
  for (int i = 0; i < 64; ++i) {
    const int fd = ConnectFrom("127.0.0.2", foxglove_port_);
    ASSERT_GE(fd, 0);
    ASSERT_TRUE(SendAll(fd, "GET / HTTP/1.1\r\n"));
    half_open.push_back(fd);
  }
  Nap();  // let the server accept them all
  const auto start = Clock::now();
  Client other;
  std::string failure;
  try {
    other.Open("127.0.0.3", foxglove_port_);
  } catch (const std::exception& e) {
    failure = e.what();
  }
  const double seconds = SecondsSince(start);
  EXPECT_EQ(failure, "") << "a client of 127.0.0.3 could not connect";
  EXPECT_LT(seconds, 1.0) << "a client of 127.0.0.3 waited " << seconds << " s";
  if (failure.empty()) {
    EXPECT_TRUE(other.NextOp("serverInfo"));
  }
  std::printf(
      "[ measured ] 127.0.0.3 connected in %.1f ms beside 16 pages and 64 half-open "
      "upgrades of 127.0.0.2\n",
      seconds * 1000.0);
  const std::string metrics = MetricsBody(port());
  EXPECT_NE(metrics.find("\nslamd_foxglove_evicted_total "), std::string::npos);
  for (const int fd : half_open) ::close(fd);
}

TEST_F(FoxgloveAdmission, AClientThatMayChangeTheBudgetDisplacesPagesOfItsOwnAddress) {
  // A page of another site fills its address's share; a client that may change the budget
  // (no Origin: Foxglove's desktop app, a script) from the same address still gets in.
  std::vector<std::unique_ptr<Client>> pages;
  for (int i = 0; i < 16; ++i) {
    pages.push_back(std::make_unique<Client>());
    ASSERT_NO_THROW(pages.back()->Open("127.0.0.4", foxglove_port_, "http://evil.example"));
  }
  Client writer;
  ASSERT_NO_THROW(writer.Open("127.0.0.4", foxglove_port_));
  EXPECT_TRUE(writer.NextOp("serverInfo"));
  // The pages never displace it: 8 more of them come and go, and it still gets its replies.
  for (int i = 0; i < 8; ++i) {
    Client page;
    ASSERT_NO_THROW(page.Open("127.0.0.4", foxglove_port_, "http://evil.example"));
  }
  ASSERT_TRUE(writer.Send(R"({"op": "getParameters", "parameterNames": [], "id": "w"})"));
  const auto values = writer.NextOp("parameterValues");
  ASSERT_TRUE(values) << "the writer was displaced by pages of another site";
  EXPECT_EQ((*values)["id"], "w");
}

// ---------------------------------------------------------------------------------------------
// Memory of clients that flood control messages and never read

TEST(FoxgloveMemory, ClientsThatNeverReadTheirRepliesStayBoundedAndTheirMemoryReturns) {
  const int foxglove_port = FreeTcpPort();
  SlamdProcess slamd;
  std::string error;
  ASSERT_TRUE(
      slamd.Start({"--budget", "2000", "--foxglove-port", std::to_string(foxglove_port)}, &error))
      << error;
  // The map of the first seconds settles first.
  std::this_thread::sleep_for(std::chrono::seconds(2));
  const double start_mib = RssMib(slamd.pid());
  ASSERT_GT(start_mib, 0.0);

  // 16 clients over 4 addresses (the per-address cap is 8), each with a small receive buffer
  // that it never reads, flooding subscribe messages for 6 s.
  const std::string flood = InvalidSubscribe();
  std::vector<std::unique_ptr<Client>> clients;
  for (int i = 0; i < 16; ++i) {
    clients.push_back(std::make_unique<Client>());
    ASSERT_NO_THROW(
        clients.back()->Open("127.0.0." + std::to_string(10 + i % 4), foxglove_port, "", 4096));
  }
  std::atomic<bool> stop{false};
  std::atomic<int> sent{0};
  std::vector<std::thread> writers;
  for (auto& client : clients) {
    writers.emplace_back([&, c = client.get()] {
      while (!stop && c->Send(flood)) ++sent;
    });
  }
  double peak_mib = start_mib;
  const auto flood_end = After(6.0);
  while (Clock::now() < flood_end) {
    peak_mib = std::max(peak_mib, RssMib(slamd.pid()));
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  stop = true;
  for (auto& client : clients) client->Shutdown();
  for (auto& w : writers) w.join();
  clients.clear();

  // Gone: slamd gives the memory back within a few seconds.
  double after_mib = RssMib(slamd.pid());
  const auto settle = After(5.0);
  while (after_mib > start_mib + 8.0 && Clock::now() < settle) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    after_mib = RssMib(slamd.pid());
  }
  std::printf(
      "[ measured ] RSS start %.1f MiB, peak %.1f MiB, after the clients left %.1f MiB "
      "(%d messages of 1800 bad subscriptions sent)\n",
      start_mib, peak_mib, after_mib, sent.load());
  EXPECT_GT(sent.load(), 100) << "the clients barely flooded";
#if !defined(SLAMD_RSS_UNMEASURABLE)
  EXPECT_LT(peak_mib - start_mib, 64.0);
  EXPECT_LT(after_mib - start_mib, 16.0);
#endif

  // One that asks for replies with small messages and never reads them is disconnected.
  Client asker;
  ASSERT_NO_THROW(asker.Open("127.0.0.14", foxglove_port, "", 4096));
  const auto deadline = After(20.0);
  bool dropped = false;
  while (!dropped && Clock::now() < deadline) dropped = !asker.Send("{}");
  EXPECT_TRUE(dropped) << "a client that never reads its replies was not disconnected in 20 s";
  const auto closed =
      Metric(ParseMetrics(MetricsBody(slamd.port())), "slamd_foxglove_closed_unread_total");
  ASSERT_TRUE(closed);
  EXPECT_GE(*closed, 1.0);
  slamd.Stop();
}

}  // namespace
}  // namespace slamd_test
