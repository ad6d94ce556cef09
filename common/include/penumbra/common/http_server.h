#pragma once
// HttpServer: a small HTTP/1.1 server (Boost.Beast) for operators' GET
// endpoints (/metrics, /healthz, /readyz; operator_http.h), apart from the
// tiers' own protocol.
//
// Threads and ownership: the server owns an io_context and ONE thread of its
// own that runs the listener and every session (each on its own strand), and
// calls the route handlers. So a handler that waits briefly (a shared lock,
// a snapshot) never stalls the tier's I/O threads, and a slow or hostile
// HTTP peer never touches them.
// Limits: each read has a timeout and a size limit (request line and headers;
// a request with a body is refused), only GET is served, at most
// `maxConnections` connections at once (more are closed on accept).

#include <chrono>
#include <cstddef>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <thread>

#include "penumbra/common/asio.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/expected.h"

namespace penumbra::net {

struct HttpResponse {
  unsigned status = 200;
  std::string contentType = "text/plain; charset=utf-8";
  std::string body;
};

struct HttpServerOptions {
  std::chrono::milliseconds readTimeout{5000};   // a request (or the idle gap before the next) within this
  std::chrono::milliseconds writeTimeout{5000};
  size_t maxRequestBytes = 8192;                 // request line + headers
  size_t maxConnections = 32;
};

class HttpServer {
 public:
  /// Called on the server's thread; should return quickly.
  using Handler = std::function<HttpResponse()>;
  /// Exact paths ("/metrics"); the query string is ignored.
  using Routes = std::map<std::string, Handler, std::less<>>;

  /// Binds `where` and starts serving `routes` on the server's own thread.
  static Expected<std::unique_ptr<HttpServer>> Start(const HostPort& where, Routes routes,
                                                     HttpServerOptions options = {});
  /// Stops (as Stop()).
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  /// The bound address (port 0 in `where` picks a free one).
  tcp::endpoint Endpoint() const { return endpoint_; }

  /// Graceful stop: closes the listener and every connection, then joins the
  /// server's thread. Idempotent; call from any thread but the server's.
  void Stop();

  struct State;

 private:
  HttpServer() = default;
  std::shared_ptr<State> state_;
  tcp::endpoint endpoint_;
  std::thread thread_;
};

}  // namespace penumbra::net
