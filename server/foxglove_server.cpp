#include "server/foxglove_server.hpp"

// Boost.Beast (Debian's libboost-dev 1.74, header-only with Boost.Asio) rather than
// websocketpp 0.8.2: Beast builds as C++20 with GCC 12 (websocketpp's headers do not), and its
// explicit asynchronous writes are what a bounded per-client queue needs.
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <array>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <chrono>
#include <deque>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <utility>

#include "server/access_policy.hpp"
#include "server/api_json.hpp"
#include "server/connection_admission.hpp"
#include "server/foxglove_messages.hpp"
#include "server/foxglove_protocol.hpp"
#include "server/request_guard.hpp"

#ifndef SLAMD_VERSION
#define SLAMD_VERSION "0"
#endif

namespace slam::server {

namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = asio::ip::tcp;
using json = nlohmann::json;
using Clock = std::chrono::steady_clock;
using foxglove::Channel;
using foxglove::kInfo;
using foxglove::kWarning;
using foxglove::Status;

constexpr auto kTick = std::chrono::milliseconds(50);
constexpr auto kHandshakeTimeout = std::chrono::seconds(10);
constexpr double kDropWarningEverySeconds = 5.0;
constexpr size_t kMaxTrajectoryPoses = 5000;
/// Connections that have not finished their upgrade hold a socket each for up to the handshake
/// timeout: at most this many of one address, and in all (connection_admission.hpp).
constexpr size_t kMaxHandshakes = 64;
constexpr size_t kMaxHandshakesPerAddress = 16;
/// What a client's control messages (status, parameterValues, serverInfo, advertise) may hold
/// unsent, at their cost in memory: a client that asks for more replies than it reads is
/// disconnected. slamd's own control messages are few (parameter updates replace one another,
/// drop warnings come every 5 s): only a client's own requests fill this.
constexpr size_t kMaxControlQueueBytes = 256 * 1024;
/// A message longer than foxglove::kMaxMessageBytes is read on in chunks of this size, discarded.
constexpr size_t kDiscardChunkBytes = 16 * 1024;
/// The queue key of spontaneous parameterValues (beyond every subscription id): a newer one
/// replaces one still waiting (it holds every followed parameter's value).
constexpr int64_t kParameterUpdatesKey = int64_t{1} << 32;
/// After a client leaves, its queue's memory goes back to the system (malloc_trim), at most this
/// often: glibc keeps freed small blocks in its arenas, so without it slamd keeps hundreds of
/// megabytes after clients that had filled their queues are gone (RELIABILITY.md, round three).
constexpr auto kTrimEvery = std::chrono::seconds(1);
constexpr int kSocketSendBuffer = 256 * 1024;
/// The web app of Foxglove: a page of that origin may change the budget (without a token).
constexpr std::string_view kFoxgloveAppOrigin = "https://app.foxglove.dev";

double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

uint64_t Nanoseconds(double t_s) {
  return t_s > 0.0 ? static_cast<uint64_t>(std::llround(t_s * 1e9)) : 0;
}

/// The subprotocol to answer with: the newer name if the client offers it, else the first one.
std::string ChooseSubprotocol(std::string_view offered) {
  bool sdk = false, v1 = false;
  std::string item;
  std::istringstream list{std::string(offered)};
  while (std::getline(list, item, ',')) {
    item.erase(0, item.find_first_not_of(" \t"));
    item.erase(item.find_last_not_of(" \t") + 1);
    sdk = sdk || item == foxglove::kSubprotocolSdk;
    v1 = v1 || item == foxglove::kSubprotocolV1;
  }
  if (sdk) return std::string(foxglove::kSubprotocolSdk);
  if (v1) return std::string(foxglove::kSubprotocolV1);
  return {};
}

}  // namespace

struct FoxgloveServer::Impl {
  struct Session;

  SlamService& service;
  FoxgloveOptions options;
  asio::io_context io{1};
  tcp::acceptor acceptor{io};
  asio::steady_timer ticker{io};
  asio::steady_timer accept_retry{io};
  std::thread thread;
  std::thread watcher;  // hands every published snapshot to the serving thread
  std::atomic<bool> stopping{false};
  bool started = false;

  // The serving thread's own state.
  std::vector<std::shared_ptr<Session>> sessions;  // every connection, from its accept
  bool trim_pending = false;  // a client left: return freed memory (kTrimEvery)
  Clock::time_point last_trim{};
  std::string server_info;  // the serverInfo and advertise messages, as sent
  std::string advertise;
  std::vector<foxglove::ChannelSpec> channels;
  BudgetSettings last_budget;
  // Payloads made once per snapshot (or map version) and shared by every subscriber.
  struct Cached {
    uint64_t key = 0;
    bool valid = false;
    std::shared_ptr<const std::string> payload;
    double t_s = 0.0;
  };
  Cached map, trajectory;

  // Counters (read by /metrics from other threads).
  std::atomic<int64_t> clients{0};
  std::atomic<uint64_t> connections{0}, refused{0}, evicted{0}, closed_unread{0}, messages_sent{0},
      messages_dropped{0}, messages_replaced{0}, bytes_sent{0}, parameter_changes{0},
      pose_estimates{0}, bad_requests{0};

  Impl(SlamService& s, const FoxgloveOptions& o) : service(s), options(o) {
    channels = foxglove::Channels(service.simulated());
    server_info =
        json{{"op", "serverInfo"},
             {"name", std::string("slamd ") + SLAMD_VERSION},
             {"capabilities", {"parameters", "parametersSubscribe", "clientPublish"}},
             {"supportedEncodings", {"json"}},
             {"metadata",
              {{"map_frame", foxglove::kMapFrame}, {"robot_frame", foxglove::kRobotFrame}}},
             {"sessionId",
              std::to_string(std::chrono::system_clock::now().time_since_epoch().count())}}
            .dump();
    advertise = foxglove::Advertise(channels).dump();
    last_budget = service.Budget();
  }

  /// A client's merge patch of the budget, as PATCH /api/v1/budget applies it.
  Result<BudgetSettings> PatchBudget(const json& patch) {
    const SlamService::BudgetChange change = service.ChangeBudget(
        [](uint64_t) { return true; },
        [&](const BudgetSettings& current) { return MergeBudget(current, patch); });
    if (!change.errors.empty()) return change.errors;
    return change.budget;
  }

  void Accept();
  void Tick();
  void Publish(const std::shared_ptr<const SlamSnapshot>& snapshot, bool new_scan);
  std::shared_ptr<const std::string> MapPayload(const SlamSnapshot& s);
  std::shared_ptr<const std::string> TrajectoryPayload(const SlamSnapshot& s);
  void CloseAll();
  void Forget(const Session* session);
  void TrimMemory();
};

/// One client: the upgrade, then its subscriptions and its bounded send queue. Lives on the
/// serving thread only.
struct FoxgloveServer::Impl::Session : std::enable_shared_from_this<Session> {
  Impl& server;
  websocket::stream<beast::tcp_stream> ws;
  const std::string peer;  // the client's address
  const Clock::time_point since = Clock::now();
  beast::flat_buffer buffer;
  uint64_t message_bytes = 0;  // read of the client's message being read
  http::request_parser<http::empty_body> parser;
  bool writer = false;    // may change the budget
  bool admitted = false;  // a client: its upgrade passed every check (counts against max_clients)
  bool open = false;      // the WebSocket is up
  bool closed = false;
  std::optional<foxglove::ClientProtocol> protocol;  // once the WebSocket is up

  struct Outgoing {
    std::shared_ptr<const std::string> payload;  // message data's is shared by every subscriber
    std::array<char, foxglove::kMessageDataHeaderBytes> header{};  // message data's own
    bool binary = false;       // message data (header, then payload)
    bool control = false;      // not droppable: counted against kMaxControlQueueBytes
    int64_t latest_only = -1;  // the key whose older queued message this one replaces
    size_t cost = 0;           // what the entry holds in memory
  };
  /// An entry's memory beyond its payload's capacity: the entry in the deque, the shared string's
  /// control block and std::string (one allocation), and the allocator's headers and rounding.
  /// Counting only payload bytes let 60-byte statuses cost three times what was counted.
  static constexpr size_t kEntryOverheadBytes = sizeof(Outgoing) + 96;
  std::deque<Outgoing> queue;
  size_t queued_cost = 0;   // every entry's cost
  size_t control_cost = 0;  // the control entries' cost
  bool writing = false;
  uint64_t dropped_untold = 0;
  Clock::time_point last_drop_warning{};
  // Per subscription: what was last sent of the map and the trajectory, and when.
  struct Sent {
    uint64_t key = 0;
    bool any = false;
    Clock::time_point at{};
  };
  std::map<uint32_t, Sent> sent;

  Session(Impl& s, tcp::socket socket, std::string address)
      : server(s), ws(std::move(socket)), peer(std::move(address)) {}

  void ReadRequest() {
    // A fixed kernel send buffer (no autotuning up to megabytes): what a client has not read
    // waits in its bounded queue, where it is counted and dropped, and the kernel holds little
    // per client. At 256 KiB a link of 10 ms still carries 25 MB/s.
    beast::error_code ignored;
    beast::get_lowest_layer(ws).socket().set_option(
        asio::socket_base::send_buffer_size(kSocketSendBuffer), ignored);
    parser.header_limit(16 * 1024);
    beast::get_lowest_layer(ws).expires_after(kHandshakeTimeout);
    http::async_read(ws.next_layer(), buffer, parser,
                     [self = shared_from_this()](beast::error_code ec, size_t) {
                       if (ec) return self->Close();
                       self->OnRequest();
                     });
  }

  void Refuse(http::status status, const std::string& why,
              const std::vector<std::pair<std::string, std::string>>& headers = {}) {
    server.refused.fetch_add(1);
    auto res = std::make_shared<http::response<http::string_body>>(status, 11);
    res->set(http::field::server, std::string("slamd/") + SLAMD_VERSION);
    res->set(http::field::content_type, "text/plain; charset=utf-8");
    for (const auto& [name, value] : headers) res->set(name, value);
    res->body() = "slamd: " + why + "\n";
    res->keep_alive(false);
    res->prepare_payload();
    http::async_write(
        ws.next_layer(), *res, [self = shared_from_this(), res](beast::error_code, size_t) {
          beast::error_code ignored;
          self->ws.next_layer().socket().shutdown(tcp::socket::shutdown_both, ignored);
          self->Close();
        });
  }

  void OnRequest() {
    const auto& req = parser.get();
    if (!websocket::is_upgrade(req)) {
      return Refuse(http::status::upgrade_required,
                    "this port speaks the Foxglove WebSocket protocol (foxglove.websocket.v1); "
                    "the web page and the REST API are on slamd's HTTP port",
                    {{"Upgrade", "websocket"}});
    }
    // The same rules as the HTTP server's: Host names, then the token; without one, a page of
    // another site may watch but not change the budget, and Foxglove's web app may.
    const AccessPolicy policy(server.options.token, server.options.allowed_hosts);
    const std::string host(req[http::field::host]);
    if (const auto refusal = policy.CheckHost(host)) {
      return Refuse(static_cast<http::status>(refusal->status), refusal->detail);
    }
    if (const auto refusal = policy.CheckToken(std::string(req[http::field::authorization]))) {
      return Refuse(static_cast<http::status>(refusal->status), refusal->detail,
                    {{"WWW-Authenticate", refusal->challenge}});
    }
    if (policy.has_token()) {
      writer = true;
    } else {
      const std::string origin(req[http::field::origin]);
      writer =
          origin.empty() || origin == kFoxgloveAppOrigin || AccessPolicy::SameOrigin(origin, host);
    }
    const std::string subprotocol =
        ChooseSubprotocol(std::string(req[http::field::sec_websocket_protocol]));
    if (subprotocol.empty()) {
      return Refuse(http::status::bad_request,
                    "no Foxglove subprotocol offered (Sec-WebSocket-Protocol: "
                    "foxglove.websocket.v1 or foxglove.sdk.v1)");
    }
    // The caps: a newcomer displaces the oldest client of its own address at that address's
    // cap, else the oldest of the address holding the most; a page of another site (rank 0)
    // never displaces a client that may change the budget (rank 1).
    std::vector<HeldConnection> held;
    std::vector<std::shared_ptr<Session>> holders;
    for (const std::shared_ptr<Session>& s : server.sessions) {
      if (!s->admitted || s->closed) continue;
      held.push_back({s->peer, s->since, s->writer ? 1 : 0});
      holders.push_back(s);
    }
    const Admission admission =
        Admit(held, peer, writer ? 1 : 0,
              {static_cast<size_t>(std::max(1, server.options.max_clients_per_address)),
               static_cast<size_t>(std::max(1, server.options.max_clients))});
    if (!admission.admit) {
      return Refuse(http::status::service_unavailable,
                    "too many Foxglove clients (" + std::to_string(server.options.max_clients) +
                        " in all, " + std::to_string(server.options.max_clients_per_address) +
                        " per address), and none that a page of another site may displace",
                    {{"Retry-After", "5"}});
    }
    if (admission.evict) {
      server.evicted.fetch_add(1);
      holders[*admission.evict]->Close();
    }
    admitted = true;
    beast::get_lowest_layer(ws).expires_never();
    websocket::stream_base::timeout timeouts{};
    timeouts.handshake_timeout = kHandshakeTimeout;
    timeouts.idle_timeout = std::chrono::seconds(30);  // pinged at half of it; closed unanswered
    timeouts.keep_alive_pings = true;
    ws.set_option(timeouts);
    ws.set_option(websocket::stream_base::decorator([subprotocol](websocket::response_type& res) {
      res.set(http::field::sec_websocket_protocol, subprotocol);
      res.set(http::field::server, std::string("slamd/") + SLAMD_VERSION);
    }));
    // No limit on Beast's side (it would close with 1009): Read discards what is beyond
    // foxglove::kMaxMessageBytes and answers with a status error, the connection stays.
    ws.read_message_max(0);
    ws.async_accept(req, [self = shared_from_this()](beast::error_code ec) {
      if (ec) return self->Close();
      self->OnOpen();
    });
  }

  void OnOpen() {
    open = true;
    protocol.emplace(server.channels, writer,
                     foxglove::BudgetAccess{
                         [this] { return server.service.Budget(); },
                         [this](const nlohmann::json& patch) { return server.PatchBudget(patch); }},
                     foxglove::PoseAccess{server.service.config().resolution_m,
                                          [this](const PoseRequest& request) {
                                            server.service.RequestPose(request);
                                          }});
    server.clients.fetch_add(1);
    server.connections.fetch_add(1);
    buffer.clear();
    SendText(server.server_info);
    SendText(server.advertise);
    if (!writer) {
      SendJson(Status(kInfo,
                      "this connection comes from a web page of another origin: it may watch "
                      "but not change slamd's parameters"));
    }
    Read();
  }

  /// Reads the client's next message piece by piece: up to foxglove::kMaxMessageBytes kept, the
  /// rest of a longer one read and discarded; then what it asked is done.
  void Read() {
    const size_t room = message_bytes > foxglove::kMaxMessageBytes
                            ? kDiscardChunkBytes
                            : foxglove::kMaxMessageBytes + 1 - buffer.size();
    ws.async_read_some(buffer, room, [self = shared_from_this()](beast::error_code ec, size_t n) {
      if (ec) return self->Close();
      self->message_bytes += n;
      if (self->message_bytes > foxglove::kMaxMessageBytes) {
        self->buffer.consume(self->buffer.size());
      }
      if (!self->ws.is_message_done()) return self->Read();
      const uint64_t bytes = std::exchange(self->message_bytes, 0);
      self->Apply(bytes > foxglove::kMaxMessageBytes ? self->protocol->OnTooLong(bytes)
                  : self->ws.got_text()
                      ? self->protocol->OnText(beast::buffers_to_string(self->buffer.data()))
                      : self->protocol->OnBinary(beast::buffers_to_string(self->buffer.data())));
      self->buffer.consume(self->buffer.size());
      if (!self->closed) self->Read();
    });
  }

  /// Closes the socket (the pending operations end with an error) and forgets the session; its
  /// memory goes with the last of them.
  void Close() {
    if (closed) return;
    closed = true;
    beast::error_code ignored;
    beast::get_lowest_layer(ws).socket().close(ignored);
    if (open) {
      server.clients.fetch_sub(1);
      server.trim_pending = true;
    }
    server.Forget(this);
  }

  void SendText(const std::string& text, int64_t latest_only = -1) {
    Outgoing entry;
    entry.payload = std::make_shared<const std::string>(text);
    entry.latest_only = latest_only;
    Enqueue(std::move(entry), false);
  }
  void SendJson(const json& message, int64_t latest_only = -1) {
    SendText(Dump(message), latest_only);
  }

  void Account(const Outgoing& entry, bool add) {
    const auto apply = [add](size_t& total, size_t cost) {
      total = add ? total + cost : total - cost;
    };
    apply(queued_cost, entry.cost);
    if (entry.control) apply(control_cost, entry.cost);
  }

  /// Queues a message; a droppable one (message data) is dropped when the queue is full; a
  /// control message beyond kMaxControlQueueBytes disconnects the client instead. One with
  /// `latest_only` (a subscription's id: the map, the trajectory, of which Foxglove keeps only the
  /// last; or kParameterUpdatesKey) replaces the one of that key still waiting in the queue.
  void Enqueue(Outgoing entry, bool droppable) {
    if (closed) return;
    entry.control = !droppable;
    entry.cost = entry.payload->capacity() + kEntryOverheadBytes;
    if (entry.latest_only >= 0) {
      // The front is being written when `writing`: only later entries may be replaced.
      for (size_t i = writing ? 1 : 0; i < queue.size(); ++i) {
        if (queue[i].latest_only != entry.latest_only) continue;
        Account(queue[i], false);
        if (entry.binary) server.messages_replaced.fetch_add(1);
        queue[i] = std::move(entry);
        Account(queue[i], true);
        return;
      }
    }
    // The message being written is the socket's already: the limits are on what waits behind
    // it (a map larger than the buffer does not make the poses after it drop).
    const Outgoing* front = writing ? &queue.front() : nullptr;
    const size_t waiting = queued_cost - (front ? front->cost : 0);
    if (droppable && waiting + entry.cost > server.options.max_queued_bytes && waiting > 0) {
      server.messages_dropped.fetch_add(1);
      ++dropped_untold;
      const auto now = Clock::now();
      if (Seconds(now - last_drop_warning) >= kDropWarningEverySeconds) {
        last_drop_warning = now;
        SendJson(Status(kWarning, "slamd dropped " + std::to_string(dropped_untold) +
                                      " message(s) for this client: it reads more slowly than "
                                      "slamd publishes"));
        dropped_untold = 0;
      }
      return;
    }
    const size_t control_waiting = control_cost - (front && front->control ? front->cost : 0);
    if (!droppable && control_waiting + entry.cost > kMaxControlQueueBytes) {
      // A client that asks for more than it reads: let it go rather than hold its replies.
      server.closed_unread.fetch_add(1);
      return Close();
    }
    if (entry.binary) server.messages_sent.fetch_add(1);
    queue.push_back(std::move(entry));
    Account(queue.back(), true);
    Pump();
  }

  void Pump() {
    if (writing || queue.empty() || closed) return;
    writing = true;
    const Outgoing& front = queue.front();
    ws.binary(front.binary);
    auto done = [self = shared_from_this()](beast::error_code ec, size_t n) {
      self->writing = false;
      if (ec) return self->Close();
      self->server.bytes_sent.fetch_add(n);
      self->Account(self->queue.front(), false);
      self->queue.pop_front();
      self->Pump();
    };
    // The deque keeps the front where it is while later entries come and go.
    if (front.binary) {
      ws.async_write(std::array<asio::const_buffer, 2>{asio::buffer(front.header),
                                                       asio::buffer(*front.payload)},
                     std::move(done));
    } else {
      ws.async_write(asio::buffer(*front.payload), std::move(done));
    }
  }

  /// A message-data frame of a payload shared with the other subscribers.
  void SendData(uint32_t subscription, double t_s, std::shared_ptr<const std::string> payload,
                bool latest_only = false) {
    Outgoing entry;
    entry.payload = std::move(payload);
    entry.header = foxglove::MessageDataHeader(subscription, Nanoseconds(t_s));
    entry.binary = true;
    entry.latest_only = latest_only ? int64_t{subscription} : -1;
    Enqueue(std::move(entry), true);
  }

  /// Does what a client message asked: the replies, and the latest of each new subscription's
  /// channel at once.
  void Apply(const foxglove::Effects& effects) {
    if (effects.refused) server.bad_requests.fetch_add(1);
    if (effects.budget_changed) server.parameter_changes.fetch_add(1);
    if (effects.pose_requested) server.pose_estimates.fetch_add(1);
    for (const json& reply : effects.replies) SendJson(reply);
    for (const uint32_t id : effects.unsubscribed) sent.erase(id);
    for (const uint32_t id : effects.subscribed) sent.erase(id);
    if (!effects.subscribed.empty()) server.Publish(server.service.Snapshot(), false);
    if (effects.budget_changed) server.Tick();  // followers of the parameters hear of it now
  }
};

void FoxgloveServer::Impl::Forget(const Session* session) {
  std::erase_if(sessions, [&](const auto& s) { return s.get() == session; });
}

void FoxgloveServer::Impl::Accept() {
  acceptor.async_accept([this](beast::error_code ec, tcp::socket socket) {
    if (stopping || ec == asio::error::operation_aborted) return;  // closed: stopping
    if (ec) {
      // Out of file descriptors, say: try again shortly rather than stop accepting.
      refused.fetch_add(1);
      accept_retry.expires_after(std::chrono::milliseconds(100));
      accept_retry.async_wait([this](beast::error_code error) {
        if (!error && !stopping) Accept();
      });
      return;
    }
    // The handshake caps (kMaxHandshakes): the oldest upgrade of the newcomer's address, or of
    // the address holding the most, is closed to make room; the newcomer always gets its turn.
    beast::error_code no_peer;
    const tcp::endpoint remote = socket.remote_endpoint(no_peer);
    std::string peer = no_peer ? std::string() : remote.address().to_string();
    std::vector<HeldConnection> held;
    std::vector<std::shared_ptr<Session>> holders;
    for (const std::shared_ptr<Session>& s : sessions) {
      if (s->admitted || s->closed) continue;
      held.push_back({s->peer, s->since, 0});
      holders.push_back(s);
    }
    const Admission admission = Admit(held, peer, 0, {kMaxHandshakesPerAddress, kMaxHandshakes});
    if (admission.evict) {
      evicted.fetch_add(1);
      holders[*admission.evict]->Close();
    }
    auto session = std::make_shared<Session>(*this, std::move(socket), std::move(peer));
    sessions.push_back(session);
    session->ReadRequest();
    Accept();
  });
}

std::shared_ptr<const std::string> FoxgloveServer::Impl::MapPayload(const SlamSnapshot& s) {
  if (!map.valid || map.key != s.map_version) {
    map.payload = std::make_shared<const std::string>(
        Dump(foxglove::Grid(s, options.max_grid_cells, s.has_pose ? s.pose.t : 0.0)));
    map.key = s.map_version;
    map.valid = true;
    map.t_s = s.has_pose ? s.pose.t : 0.0;
  }
  return map.payload;
}

std::shared_ptr<const std::string> FoxgloveServer::Impl::TrajectoryPayload(const SlamSnapshot& s) {
  if (!trajectory.valid || trajectory.key != s.sequence) {
    trajectory.payload = std::make_shared<const std::string>(
        Dump(foxglove::PosesInFrame(ScanEndTrajectory(s), kMaxTrajectoryPoses)));
    trajectory.key = s.sequence;
    trajectory.valid = true;
    trajectory.t_s = s.has_pose ? s.pose.t : 0.0;
  }
  return trajectory.payload;
}

void FoxgloveServer::Impl::Publish(const std::shared_ptr<const SlamSnapshot>& snapshot,
                                   bool new_scan) {
  const SlamSnapshot& s = *snapshot;
  const auto now = Clock::now();
  // Payloads of this snapshot, made when a subscriber first needs them.
  std::shared_ptr<const std::string> pose, tf, scan, truth;
  for (const std::shared_ptr<Session>& session : std::vector(sessions)) {
    if (!session->protocol) continue;
    for (const auto& [id, channel] : session->protocol->subscriptions()) {
      Session::Sent& sent = session->sent[id];
      const bool first = !sent.any;
      switch (channel) {
        case Channel::kMap:
        case Channel::kTrajectory: {
          const bool is_map = channel == Channel::kMap;
          const uint64_t key = is_map ? s.map_version : s.sequence;
          const double period = is_map ? options.map_period_s : options.trajectory_period_s;
          if (!first && (sent.key == key || Seconds(now - sent.at) < period)) break;
          if (!is_map && !s.has_pose) break;
          const auto payload = is_map ? MapPayload(s) : TrajectoryPayload(s);
          session->SendData(id, is_map ? map.t_s : trajectory.t_s, payload, true);
          sent = {key, true, now};
          break;
        }
        case Channel::kPose:
        case Channel::kTransform:
        case Channel::kScan:
        case Channel::kGroundTruth: {
          if (!s.has_pose || !(new_scan || first)) break;
          std::shared_ptr<const std::string>* payload = nullptr;
          json message;
          if (channel == Channel::kPose) {
            payload = &pose;
            if (!*payload) message = foxglove::PoseInFrame(s.pose);
          } else if (channel == Channel::kTransform) {
            payload = &tf;
            if (!*payload) message = foxglove::FrameTransform(s.pose);
          } else if (channel == Channel::kScan) {
            if (!s.scan_points) break;
            payload = &scan;
            if (!*payload) message = foxglove::PointCloud(*s.scan_points, s.pose.t);
          } else {
            if (!s.truth) break;
            payload = &truth;
            if (!*payload) message = foxglove::PoseInFrame({s.pose.t, *s.truth});
          }
          if (!*payload) *payload = std::make_shared<const std::string>(Dump(message));
          session->SendData(id, s.pose.t, *payload);
          sent = {s.sequence, true, now};
          break;
        }
      }
    }
  }
}

void FoxgloveServer::Impl::Tick() {
  if (stopping) return;
  // What the period of /map and /trajectory held back.
  Publish(service.Snapshot(), false);
  const BudgetSettings budget = service.Budget();
  if (!(budget == last_budget)) {
    last_budget = budget;
    const json all = foxglove::BudgetParameters(budget);
    for (const std::shared_ptr<Session>& session : std::vector(sessions)) {
      json values = json::array();
      for (const json& p : all) {
        if (session->protocol &&
            session->protocol->parameter_updates().count(p["name"].get<std::string>()) != 0)
          values.push_back(p);
      }
      if (!values.empty()) {
        session->SendJson({{"op", "parameterValues"}, {"parameters", values}},
                          kParameterUpdatesKey);
      }
    }
  }
  if (trim_pending && Clock::now() - last_trim >= kTrimEvery) TrimMemory();
}

void FoxgloveServer::Impl::TrimMemory() {
  trim_pending = false;
  last_trim = Clock::now();
#if defined(__GLIBC__)
  // Gives the free pages of every arena back (madvise); takes each arena's lock for the walk, a
  // few milliseconds at most, and runs only after a client left, at most once a second.
  malloc_trim(0);
#endif
}

void FoxgloveServer::Impl::CloseAll() {
  beast::error_code ignored;
  acceptor.close(ignored);
  ticker.cancel();
  accept_retry.cancel();
  for (const std::shared_ptr<Session>& session : std::vector(sessions)) session->Close();
}

FoxgloveServer::FoxgloveServer(SlamService& service, const FoxgloveOptions& options)
    : impl_(std::make_unique<Impl>(service, options)) {}

FoxgloveServer::~FoxgloveServer() { Stop(); }

Result<int> FoxgloveServer::Bind() {
  Impl& s = *impl_;
  const std::string where = s.options.bind + ":" + std::to_string(s.options.port);
  beast::error_code ec;
  tcp::resolver resolver(s.io);
  const auto endpoints = resolver.resolve(s.options.bind, std::to_string(s.options.port),
                                          tcp::resolver::numeric_service, ec);
  if (ec || endpoints.empty()) {
    return Error("Foxglove server: cannot resolve " + s.options.bind + ": " + ec.message());
  }
  const tcp::endpoint endpoint = endpoints.begin()->endpoint();
  s.acceptor.open(endpoint.protocol(), ec);
  if (!ec) s.acceptor.set_option(asio::socket_base::reuse_address(true), ec);
  if (!ec) s.acceptor.bind(endpoint, ec);
  if (!ec) s.acceptor.listen(asio::socket_base::max_listen_connections, ec);
  if (ec) {
    return Error("Foxglove server: cannot listen on " + where + " (" + ec.message() +
                 "; --foxglove-port 0 turns it off)");
  }
  return static_cast<int>(s.acceptor.local_endpoint().port());
}

void FoxgloveServer::Start() {
  Impl& s = *impl_;
  if (s.started) return;
  s.started = true;
  s.Accept();
  // The publishing tick: new snapshots, map and trajectory periods, parameter changes.
  struct Ticker {
    Impl& s;
    void operator()(beast::error_code ec) const {
      if (ec || s.stopping) return;
      s.Tick();
      s.ticker.expires_after(kTick);
      s.ticker.async_wait(*this);
    }
  };
  s.ticker.expires_after(kTick);
  s.ticker.async_wait(Ticker{s});
  s.thread = std::thread([&s] { s.io.run(); });
  // Every snapshot (one per scan) to the serving thread, which sends each scan's pose,
  // transform and readings; the SLAM thread only notifies.
  s.watcher = std::thread([&s] {
    uint64_t sequence = s.service.Snapshot()->sequence;
    while (!s.stopping) {
      auto snapshot = s.service.WaitNewer(sequence, std::chrono::milliseconds(250));
      if (snapshot->sequence == sequence) continue;
      sequence = snapshot->sequence;
      asio::post(s.io, [&s, snapshot = std::move(snapshot)] {
        if (!s.stopping) s.Publish(snapshot, true);
      });
    }
  });
}

void FoxgloveServer::Stop() {
  Impl& s = *impl_;
  if (s.stopping.exchange(true)) return;
  if (!s.started) return;
  if (s.watcher.joinable()) s.watcher.join();
  asio::post(s.io, [&s] {
    s.CloseAll();
    s.io.stop();
  });
  if (s.thread.joinable()) s.thread.join();
}

FoxgloveCounters FoxgloveServer::Counters() const {
  const Impl& s = *impl_;
  FoxgloveCounters c;
  c.clients = s.clients.load();
  c.connections = s.connections.load();
  c.refused = s.refused.load();
  c.evicted = s.evicted.load();
  c.closed_unread = s.closed_unread.load();
  c.messages_sent = s.messages_sent.load();
  c.messages_dropped = s.messages_dropped.load();
  c.messages_replaced = s.messages_replaced.load();
  c.bytes_sent = s.bytes_sent.load();
  c.parameter_changes = s.parameter_changes.load();
  c.pose_estimates = s.pose_estimates.load();
  c.bad_requests = s.bad_requests.load();
  return c;
}

std::string FoxgloveServer::MetricsText() const {
  const FoxgloveCounters c = Counters();
  std::ostringstream o;
  const auto metric = [&](const char* name, const char* type, const char* help, auto value) {
    o << "# HELP slamd_foxglove_" << name << ' ' << help << "\n# TYPE slamd_foxglove_" << name
      << ' ' << type << "\nslamd_foxglove_" << name << ' ' << value << '\n';
  };
  metric("clients", "gauge", "Foxglove WebSocket clients connected.", c.clients);
  metric("connections_total", "counter", "Foxglove WebSocket connections accepted.", c.connections);
  metric("refused_total", "counter",
         "Foxglove WebSocket upgrades refused (not an upgrade, host, token, subprotocol, cap).",
         c.refused);
  metric("evicted_total", "counter",
         "Foxglove connections closed to make room for a newer one (the oldest of the same "
         "address, or of the address holding the most).",
         c.evicted);
  metric("closed_unread_total", "counter",
         "Foxglove clients disconnected because their replies waited unread beyond the bound.",
         c.closed_unread);
  metric("messages_sent_total", "counter", "Foxglove message-data frames queued for clients.",
         c.messages_sent);
  metric("messages_dropped_total", "counter",
         "Foxglove message-data frames dropped because a client's send queue was full.",
         c.messages_dropped);
  metric("messages_replaced_total", "counter",
         "Foxglove /map and /trajectory messages replaced by a newer one before they were sent.",
         c.messages_replaced);
  metric("sent_bytes_total", "counter", "Bytes written to Foxglove clients.", c.bytes_sent);
  metric("parameter_changes_total", "counter", "Budget changes made through Foxglove parameters.",
         c.parameter_changes);
  metric("pose_estimates_total", "counter",
         "Pose estimates published by Foxglove clients and passed on (as POST /api/v1/pose).",
         c.pose_estimates);
  metric("bad_requests_total", "counter",
         "Foxglove client messages refused (not JSON, unknown op, invalid parameters).",
         c.bad_requests);
  return o.str();
}

}  // namespace slam::server
