#pragma once
// slamd's connections on top of cpp-httplib 0.11 (docs/design.md appendix C).
//
// Bounded requests: cpp-httplib 0.11 bounds each header line (8 KiB) but not their number, nor
// the time a request may take to arrive: a client streaming header lines grew slamd by over a
// gigabyte in seconds, and one sending a byte every few seconds held a pool thread for ever.
// BoundedServer replaces the library's connection loop with the same loop over a stream that
// gives each request a byte budget (head plus the largest body allowed) and a deadline; past
// either, reads fail and the library answers 400 and closes the connection.
//
// The gate: httplib gives each connection a pool thread from accept to close. 24 connections
// trickling their headers delayed a normal GET by 8 s, 240 idle ones by 19.5 s, and 64
// keep-alive clients at full speed saw p99 1.4 s. Here one thread polls every waiting
// connection and hands it to a worker only once its buffer holds a whole request; after the
// response it comes back to the gate, so workers serve requests in arrival order, each to the
// end (details in bounded_server.cpp).

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "server/http_library.hpp"

namespace slam::server {

struct Connection;
class Gate;

class BoundedServer final : public httplib::Server {
 public:
  BoundedServer();
  ~BoundedServer() override;

  /// One request through the parser, the pre-routing guard, routing, the handlers and the
  /// logger, as on a connection that closes after it; the response bytes.
  std::string ProcessInMemory(std::string_view request, size_t max_response_bytes);

  /// httplib listens with a backlog of 5: when the 8 viewers of the load test opened their tile
  /// connections at once while the SLAM kept both cores busy, the kernel dropped SYNs
  /// (TcpExtListenOverflows) and those requests waited for the 1 s SYN retransmission. Linux
  /// takes a second listen() on a listening socket as a new backlog.
  void WidenListenBacklog();

  /// Starts the gate and `workers` threads that serve whole requests (event streams hold one
  /// each for their lifetime). Before listen_after_bind.
  void StartServing(size_t workers);
  /// After listen_after_bind returned (stop()): closes the waiting connections and waits for
  /// the workers (event streams end within their wake-up interval once the server stops).
  void Shutdown();

  uint64_t connections_timed_out() const;
  uint64_t connections_evicted() const;

  size_t max_head_bytes = 64 * 1024;
  size_t max_body_bytes = 64 * 1024;
  std::chrono::seconds request_deadline{10};

 private:
  // httplib hands each accepted connection to this on one of its pool threads: it goes to the
  // gate at once (without a gate, as in HandleInMemory's users, it is closed).
  bool process_and_close_socket(socket_t sock) override;
  void Dispatch(Connection c);
  // One request of a connection whose buffer holds it (httplib's loop of 0.11 for one turn,
  // over a bounded stream); then the connection goes back to the gate, or closes.
  void Serve(Connection c);

  std::unique_ptr<Gate> gate_;
  std::unique_ptr<httplib::ThreadPool> workers_;
};

/// For a handler that answers without reading the request's body: the connection cannot carry
/// another request (the unread body would be parsed as the next one), so it closes after this
/// response. httplib 0.11 closes a connection only when the request asks for it, whatever the
/// response's Connection header says.
void CloseConnectionAfterResponse();

/// The head of the request this thread is processing, as received (request line and header
/// lines up to the blank line, or what has arrived of them), for the request guard; nullptr
/// outside a request.
const std::string* RequestHeadAsReceived();

}  // namespace slam::server
