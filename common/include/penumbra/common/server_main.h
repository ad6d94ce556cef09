#pragma once
// ServerMain: what the renderer's and the SMA's main() share -- the common
// flags (--listen, --port-file, --name, --log-level, --log-format,
// --max-frame-bytes, --heartbeat-ms, --handshake-timeout-ms,
// --read-timeout-ms, --stats-interval, --max-connections, --http,
// --http-port-file, --auth-token-file, --tls-cert/--tls-key, --version), their
// checks and set-up (logging, the listen address, the token, the TLS
// context, the operator endpoint), and the run: port file, endpoint attached,
// serve, endpoint detached. The descriptor limit, the connection cap and the
// signals are the server's (server_skeleton.h).
//
// Errors are one line on stderr, "<program>: <message>", and an exit code:
// 2 for a flag, 1 for anything else. Threads: main's only.

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "penumbra/common/connection.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/operator_http.h"
#include "penumbra/common/tls.h"

namespace CLI {
class App;
}

namespace penumbra {

/// What differs between the tiers in the common flags.
struct ServerMainSpec {
  std::string program;        // "penumbra-renderer": --version and error lines
  std::string listen;         // --listen's default, "127.0.0.1:7100"
  std::string name;           // --name's default
  std::string peers;          // who connects, for help texts: "SMAs", "clients"
  std::string peerTokenFlag;  // the peers' flag with the same token: "--renderer-auth-token-file"
  std::string readyWhen;      // --http's readiness, "once the scene is loaded"
  std::string metricsPrefix;  // "penumbra_renderer"
  std::string logger;         // the named logger of set-up warnings: "renderer"
};

class ServerMain {
 public:
  /// Adds the common flags to `app`; their defaults are `connection`'s and
  /// `maxConnections`.
  ServerMain(CLI::App& app, ServerMainSpec spec, const net::ConnectionOptions& connection, size_t maxConnections);

  /// After parsing: logging, then --listen (parsed, and its host checked now
  /// rather than after minutes of scene loading), the token file and the TLS
  /// context. nullopt: all set; else the exit code (the error is printed).
  std::optional<int> Setup();
  /// Starts --http, if given (before the scene loads: liveness holds while
  /// it loads, readiness not). nullopt: done; else the exit code.
  std::optional<int> StartHttp();
  /// After the server is listening on `port`: writes --port-file, attaches
  /// `probe` to --http, calls `run` (the server's Run()), detaches. Returns
  /// the exit code.
  int Serve(uint16_t port, OperatorProbe probe, const std::function<void()>& run);

  /// Prints "<program>: <message>" on stderr; returns `code`.
  int Fail(int code, std::string_view message) const;
  /// Reads the token file `path` given by `flag` into `*out` (a warning is
  /// logged when others may read it). false: printed, exit with 2.
  bool ReadToken(std::string_view flag, const std::string& path, std::string* out) const;

  /// After Setup().
  const HostPort& Listen() const { return listen_; }
  const std::string& Name() const { return name_; }
  const std::string& AuthToken() const { return authToken_; }
  const std::shared_ptr<net::ssl::context>& Tls() const { return tls_; }
  /// The connection flags applied to the defaults given.
  net::ConnectionOptions Connection() const;
  std::chrono::milliseconds Heartbeat() const { return std::chrono::milliseconds(heartbeatMs_); }
  std::chrono::milliseconds StatsInterval() const { return std::chrono::seconds(statsSeconds_); }
  size_t MaxConnections() const { return maxConnections_; }
  /// Sets the fields every tier's server options share (listen, name,
  /// authToken, tls, maxConnections, statsInterval); the connection options
  /// (Connection()) are the tier's to place.
  template <class ServerOptions>
  void Fill(ServerOptions& options) const {
    options.listen = listen_;
    options.name = name_;
    options.authToken = authToken_;
    options.tls = tls_;
    options.maxConnections = maxConnections_;
    options.statsInterval = StatsInterval();
  }

 private:
  ServerMainSpec spec_;
  net::ConnectionOptions connection_;
  std::string listenFlag_, portFile_, name_, logLevel_ = "info", logFormat_ = "text";
  std::string httpListen_, httpPortFile_, authTokenFile_, tlsCert_, tlsKey_;
  uint32_t maxFrameBytes_ = 0;
  int heartbeatMs_ = 0, readTimeoutMs_ = 0, handshakeTimeoutMs_ = 0, statsSeconds_ = 10;
  size_t maxConnections_ = 0;

  HostPort listen_;
  std::string authToken_;
  std::shared_ptr<net::ssl::context> tls_;
  std::unique_ptr<OperatorEndpoint> http_;
};

}  // namespace penumbra
