#include "penumbra/common/http_server.h"

#include <atomic>
#include <mutex>
#include <optional>
#include <vector>

#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <fmt/format.h>

#include "penumbra/common/connection.h"
#include "penumbra/common/logging.h"

namespace penumbra::net {

namespace beast = boost::beast;
namespace http = boost::beast::http;
using boost::system::error_code;

class HttpSession;

struct HttpServer::State {
  State(HttpServer::Routes r, HttpServerOptions o) : routes(std::move(r)), options(o), log(Logger("http")) {}

  asio::io_context io;
  HttpServer::Routes routes;
  HttpServerOptions options;
  std::shared_ptr<spdlog::logger> log;
  std::shared_ptr<Listener> listener;
  std::atomic<size_t> connections{0};
  std::atomic<bool> stopping{false};
  std::weak_ptr<State> self;  // for the sessions to share ownership
  // Connections refused at the limit, and when that was last logged (the
  // server's thread only): one line per 10 s at most, however many.
  uint64_t refused = 0;
  std::chrono::steady_clock::time_point refusedLogged{};
  std::mutex sessionsMutex;
  std::vector<std::weak_ptr<HttpSession>> sessions;  // for Stop(); pruned on accept

  void Accept(tcp::socket socket);
};

// One HTTP connection; everything runs on its socket's strand.
class HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(std::shared_ptr<HttpServer::State> server, tcp::socket socket)
      : server_(std::move(server)), stream_(std::move(socket)), buffer_(server_->options.maxRequestBytes) {
    ++server_->connections;
  }
  ~HttpSession() { --server_->connections; }

  void Start() {
    asio::dispatch(stream_.get_executor(), [self = shared_from_this()] { self->DoRead(); });
  }

  /// Any thread: close the connection (cancels its reads and writes).
  void Close() {
    asio::post(stream_.get_executor(), [self = shared_from_this()] {
      error_code ec;
      self->stream_.socket().shutdown(tcp::socket::shutdown_both, ec);
      self->stream_.close();
    });
  }

 private:
  void DoRead() {
    if (server_->stopping) return;
    parser_.emplace();
    parser_->header_limit(uint32_t(server_->options.maxRequestBytes));
    parser_->body_limit(0);
    stream_.expires_after(server_->options.readTimeout);
    http::async_read(stream_, buffer_, *parser_,
                     [self = shared_from_this()](const error_code& ec, size_t) { self->OnRead(ec); });
  }

  void OnRead(const error_code& ec) {
    if (ec == http::error::end_of_stream || ec == asio::error::operation_aborted || ec == beast::error::timeout ||
        ec == asio::error::connection_reset || ec == asio::error::eof) {
      Shutdown();
      return;
    }
    if (ec) {
      // The request is malformed or too large: answer 4xx and close; the
      // rest of what the peer sends is never read.
      unsigned status = 400;
      if (ec == http::error::header_limit || ec == http::error::buffer_overflow) status = 431;
      else if (ec == http::error::body_limit || ec == http::error::unexpected_body) status = 413;
      server_->log->debug("{}: bad request ({}): {}", Peer(), ec.message(), status);
      Respond(MakeResponse(status, fmt::format("{}\n", ec.message())), /*keepAlive=*/false);
      return;
    }
    const auto& request = parser_->get();
    if (request.method() != http::verb::get) {
      auto response = MakeResponse(405, "only GET is served\n");
      response.set(http::field::allow, "GET");
      Respond(std::move(response), /*keepAlive=*/false);
      return;
    }
    std::string_view target(request.target().data(), request.target().size());
    target = target.substr(0, target.find('?'));
    auto route = server_->routes.find(target);
    if (route == server_->routes.end()) {
      Respond(MakeResponse(404, "not found; try /metrics, /healthz or /readyz\n"), request.keep_alive());
      return;
    }
    HttpResponse result = route->second();
    auto response = MakeResponse(result.status, std::move(result.body));
    response.set(http::field::content_type, result.contentType);
    Respond(std::move(response), request.keep_alive());
  }

  http::response<http::string_body> MakeResponse(unsigned status, std::string body) {
    http::response<http::string_body> response{http::int_to_status(status), 11};
    response.set(http::field::server, "penumbra");
    response.set(http::field::content_type, "text/plain; charset=utf-8");
    response.body() = std::move(body);
    return response;
  }

  void Respond(http::response<http::string_body> response, bool keepAlive) {
    response_ = std::move(response);
    response_.keep_alive(keepAlive && !server_->stopping);
    response_.prepare_payload();
    stream_.expires_after(server_->options.writeTimeout);
    http::async_write(stream_, response_, [self = shared_from_this()](const error_code& ec, size_t) {
      if (ec || !self->response_.keep_alive()) {
        self->Shutdown();
        return;
      }
      self->DoRead();
    });
  }

  void Shutdown() {
    error_code ec;
    stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
    stream_.close();
  }

  std::string Peer() {
    error_code ec;
    auto remote = stream_.socket().remote_endpoint(ec);
    return ec ? std::string("?") : fmt::format("{}:{}", remote.address().to_string(), remote.port());
  }

  std::shared_ptr<HttpServer::State> server_;
  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::empty_body>> parser_;
  http::response<http::string_body> response_;
};

void HttpServer::State::Accept(tcp::socket socket) {
  if (stopping) return;
  if (connections.load() >= options.maxConnections) {
    // Bounded: a flood of connections costs a closed socket each, no memory,
    // and no more than a log line per 10 s.
    ++refused;
    const auto now = std::chrono::steady_clock::now();
    if (now - refusedLogged >= std::chrono::seconds(10)) {
      log->warn("{} connections open already: closed {} new one(s), the last from {}", options.maxConnections,
                refused, PeerAddress(socket));
      refused = 0;
      refusedLogged = now;
    }
    return;  // the socket closes as it goes out of scope
  }
  auto session = std::make_shared<HttpSession>(self.lock(), std::move(socket));
  {
    std::lock_guard lock(sessionsMutex);
    std::erase_if(sessions, [](const std::weak_ptr<HttpSession>& s) { return s.expired(); });
    sessions.push_back(session);
  }
  session->Start();
}

Expected<std::unique_ptr<HttpServer>> HttpServer::Start(const HostPort& where, Routes routes,
                                                        HttpServerOptions options) {
  std::unique_ptr<HttpServer> server(new HttpServer());
  auto state = std::make_shared<State>(std::move(routes), options);
  state->self = state;
  std::weak_ptr<State> weak = state;
  state->listener = Listener::Create(state->io, [weak](Stream stream) {
    if (auto s = weak.lock()) s->Accept(std::move(stream).TakePlainSocket());
  });
  auto bound = state->listener->Listen(where);
  if (!bound) return Fail(fmt::format("--http: {}", bound.error().message));
  server->endpoint_ = *bound;
  server->state_ = state;
  state->listener->Start();
  server->thread_ = std::thread([state] { state->io.run(); });
  state->log->info("HTTP endpoint on {}:{} (/metrics, /healthz, /readyz)", bound->address().to_string(),
                   bound->port());
  return server;
}

void HttpServer::Stop() {
  if (!state_ || state_->stopping.exchange(true)) {
    if (thread_.joinable()) thread_.join();
    return;
  }
  state_->listener->Stop();
  std::vector<std::shared_ptr<HttpSession>> open;
  {
    std::lock_guard lock(state_->sessionsMutex);
    for (auto& weak : state_->sessions)
      if (auto s = weak.lock()) open.push_back(std::move(s));
    state_->sessions.clear();
  }
  for (auto& s : open) s->Close();
  open.clear();
  // With the acceptor and every socket closed, run() runs out of work.
  if (thread_.joinable()) thread_.join();
}

HttpServer::~HttpServer() { Stop(); }

}  // namespace penumbra::net
