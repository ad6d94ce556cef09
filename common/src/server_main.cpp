#include "penumbra/common/server_main.h"

#include <cstdio>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "penumbra/common/auth.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/version.h"

namespace penumbra {

ServerMain::ServerMain(CLI::App& app, ServerMainSpec spec, const net::ConnectionOptions& connection,
                       size_t maxConnections)
    : spec_(std::move(spec)),
      connection_(connection),
      listenFlag_(spec_.listen),
      name_(spec_.name),
      maxFrameBytes_(connection.maxFrameBytes),
      heartbeatMs_(int(connection.heartbeatInterval.count())),
      readTimeoutMs_(int(connection.readTimeout.count())),
      handshakeTimeoutMs_(int(connection.handshakeTimeout.count())),
      maxConnections_(maxConnections) {
  app.set_version_flag("--version", spec_.program + " " + std::string(kVersion));
  app.add_option("--listen", listenFlag_,
                 fmt::format("Address for {}, HOST:PORT (port 0: any free port)", spec_.peers))
      ->capture_default_str();
  app.add_option("--max-frame-bytes", maxFrameBytes_,
                 "Largest frame accepted; larger frames close the connection")
      ->check(CLI::Range(1024u, 1u << 30))->capture_default_str();
  app.add_option("--heartbeat-ms", heartbeatMs_, "Idle interval after which a heartbeat is sent")
      ->check(CLI::Range(10, 3600000))->capture_default_str();
  app.add_option("--handshake-timeout-ms", handshakeTimeoutMs_,
                 "A peer that has not completed its Hello by then is dropped")
      ->check(CLI::Range(10, 3600000))->capture_default_str();
  app.add_option("--read-timeout-ms", readTimeoutMs_, "Silence after which a peer is dropped")
      ->check(CLI::Range(10, 3600000))->capture_default_str();
  app.add_option("--stats-interval", statsSeconds_, "Seconds between counter lines in the log")
      ->check(CLI::Range(1, 86400))->capture_default_str();
  app.add_option("--name", name_, "Name reported in handshakes and logs")->capture_default_str();
  app.add_option("--port-file", portFile_, "Write the bound port to this file once listening (for scripts/tests)");
  app.add_option("--log-level", logLevel_, "trace, debug, info, warn, error, critical or off")->capture_default_str();
  app.add_option("--log-format", logFormat_, "text, or json: one JSON object per log line")->capture_default_str();
  // Connection limits and shutdown (issue 12)
  app.add_option("--max-connections", maxConnections_,
                 fmt::format("Connections ({}, and peers yet to say Hello) served at once; more are refused with "
                             "TOO_MANY_CONNECTIONS and closed at once",
                             spec_.peers))
      ->check(CLI::Range(size_t(1), size_t(1) << 20))->capture_default_str();
  // Operator HTTP endpoint (issue 16)
  app.add_option("--http", httpListen_,
                 fmt::format("Serve /metrics (Prometheus), /healthz and /readyz on HOST:PORT (port 0: any free "
                             "port); ready {}",
                             spec_.readyWhen));
  app.add_option("--http-port-file", httpPortFile_, "Write the bound --http port to this file once listening");
  // Tokens and TLS (docs/deploy.md)
  app.add_option("--auth-token-file", authTokenFile_,
                 fmt::format("Require {} to present the token in this file (their {}); keep it mode 600", spec_.peers,
                             spec_.peerTokenFlag));
  auto* certOption = app.add_option(
      "--tls-cert", tlsCert_, fmt::format("Serve {} TLS with this PEM certificate chain (leaf first)", spec_.peers));
  auto* keyOption = app.add_option("--tls-key", tlsKey_, "... and this unencrypted PEM private key");
  certOption->needs(keyOption);
  keyOption->needs(certOption);
}

int ServerMain::Fail(int code, std::string_view message) const {
  std::fprintf(stderr, "%s: %.*s\n", spec_.program.c_str(), int(message.size()), message.data());
  return code;
}

bool ServerMain::ReadToken(std::string_view flag, const std::string& path, std::string* out) const {
  auto token = ReadAuthTokenFile(path);
  if (!token) {
    Fail(2, fmt::format("{}: {}", flag, token.error().message));
    return false;
  }
  if (!token->warning.empty()) Logger(spec_.logger)->warn("{}", token->warning);
  *out = std::move(token->token);
  return true;
}

std::optional<int> ServerMain::Setup() {
  if (!SetupLogging(logLevel_)) return Fail(2, fmt::format("unknown --log-level '{}'", logLevel_));
  if (!SetupLogFormat(logFormat_)) return Fail(2, fmt::format("unknown --log-format '{}' (text or json)", logFormat_));
  auto where = ParseHostPort(listenFlag_, /*allowPortZero=*/true);
  if (!where) return Fail(2, "--listen: " + where.error().message);
  listen_ = *where;
  // Before the scene loads (minutes for a big one): a bad host is reported now.
  if (auto ok = net::CheckListenAddress(listen_); !ok) return Fail(2, "--listen: " + ok.error().message);
  // Secrets and certificates before the scene: a wrong file fails in a moment.
  if (!authTokenFile_.empty() && !ReadToken("--auth-token-file", authTokenFile_, &authToken_)) return 2;
  if (!tlsCert_.empty()) {
    auto context = net::MakeTlsServerContext(tlsCert_, tlsKey_);
    if (!context) return Fail(2, context.error().message);
    tls_ = std::move(*context);
  }
  return std::nullopt;
}

std::optional<int> ServerMain::StartHttp() {
  auto http = OperatorEndpoint::FromFlags(httpListen_, httpPortFile_, spec_.metricsPrefix);
  if (!http) return Fail(1, http.error().message);
  http_ = std::move(*http);
  return std::nullopt;
}

net::ConnectionOptions ServerMain::Connection() const {
  net::ConnectionOptions out = connection_;
  out.maxFrameBytes = maxFrameBytes_;
  out.heartbeatInterval = std::chrono::milliseconds(heartbeatMs_);
  out.readTimeout = std::chrono::milliseconds(readTimeoutMs_);
  out.handshakeTimeout = std::chrono::milliseconds(handshakeTimeoutMs_);
  return out;
}

int ServerMain::Serve(uint16_t port, OperatorProbe probe, const std::function<void()>& run) {
  if (!portFile_.empty()) {
    if (auto written = WritePortFile(portFile_, port); !written) return Fail(1, written.error().message);
  }
  if (http_) http_->Attach(std::move(probe));
  run();
  if (http_) http_->Detach();
  return 0;
}

}  // namespace penumbra
