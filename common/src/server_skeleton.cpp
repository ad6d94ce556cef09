#include "penumbra/common/server_skeleton.h"

#include <csignal>
#include <thread>

#include <fmt/format.h>

#include "penumbra/common/logging.h"
#include "penumbra/common/messages.h"

namespace penumbra::net {

using Clock = std::chrono::steady_clock;

ServerSkeletonBase::ServerSkeletonBase(asio::io_context& io, ServerSkeletonOptions options, ServerHooks hooks)
    : io_(io),
      control_(asio::make_strand(io)),
      options_(std::move(options)),
      hooks_(std::move(hooks)),
      log_(Logger(options_.role.logger)),
      signals_(control_, SIGINT, SIGTERM),
      statsTimer_(control_),
      drainTimer_(control_) {}

ServerSkeletonBase::~ServerSkeletonBase() = default;

Expected<tcp::endpoint> ServerSkeletonBase::Listen() {
  // Descriptors for every connection allowed, and some for everything else.
  const size_t fit = FitConnectionsToDescriptorLimit(options_.maxConnections, options_.role.reservedDescriptors);
  if (fit < options_.maxConnections) {
    log_->warn("the descriptor limit (ulimit -n) allows only {} {} connections; --max-connections {} lowered to that",
               fit, options_.role.peer, options_.maxConnections);
    options_.maxConnections = fit;
  }
  listener_ = Listener::Create(io_, [this](Stream stream) { Accept(std::move(stream)); });
  if (options_.tls) listener_->SetTls(options_.tls, options_.connection.handshakeTimeout);
  auto bound = listener_->Listen(options_.listen);
  if (bound)
    log_->info("{}: listening for {} on {}:{} ({}{})", options_.name, options_.role.peers,
               bound->address().to_string(), bound->port(), options_.tls ? "TLS" : "plain TCP",
               options_.tokenRequired ? ", token required" : "");
  return bound;
}

void ServerSkeletonBase::RunIo(int ioThreads) {
  signals_.async_wait([this](const boost::system::error_code& ec, int signal) {
    if (ec) return;
    log_->info("{}: signal {} received: shutting down", options_.name, signal);
    Shutdown();
  });
  if (listener_) listener_->Start();
  ArmStats();
  std::vector<std::thread> extra;
  for (int i = 1; i < ioThreads; ++i) extra.emplace_back([this] { io_.run(); });
  io_.run();
  for (auto& t : extra) t.join();
}

void ServerSkeletonBase::Shutdown() {
  asio::post(control_, [this] { BeginShutdown(); });
}

void ServerSkeletonBase::BeginShutdown() {
  if (draining_.exchange(true)) return;
  if (listener_) listener_->Stop();
  signals_.cancel();
  statsTimer_.cancel();
  drainDeadline_ = Clock::now() + options_.drainTimeout;
  if (hooks_.beginShutdown) hooks_.beginShutdown();
  const std::string message = options_.role.service + " is shutting down";
  TellAndClose(MakeError(0, wire::ERROR_CODE_SHUTTING_DOWN, message, /*fatal=*/true),
               options_.role.service + " shutting down");
  PollDrain();
}

void ServerSkeletonBase::PollDrain() {
  const size_t remaining = SessionCount();
  // Every peer was told and is closing; stop when they are gone, or at the
  // deadline whatever a slow peer does.
  if (remaining == 0 || Clock::now() >= drainDeadline_) {
    if (remaining > 0)
      log_->warn("{}: {} connection(s) still closing at the shutdown deadline; dropped", options_.name, remaining);
    io_.stop();
    return;
  }
  drainTimer_.expires_after(std::chrono::milliseconds(20));
  drainTimer_.async_wait([this](const boost::system::error_code& ec) {
    if (!ec) PollDrain();
  });
}

void ServerSkeletonBase::ArmStats() {
  statsTimer_.expires_after(options_.statsInterval);
  statsTimer_.async_wait([this](const boost::system::error_code& ec) {
    if (ec || Draining()) return;
    if (hooks_.logStats) hooks_.logStats();
    ArmStats();
  });
}

void ServerSkeletonBase::RefuseDraining(Stream stream) {
  RefuseConnection(std::move(stream),
                   MakeError(0, wire::ERROR_CODE_SHUTTING_DOWN, options_.role.service + " is shutting down", true));
}

void ServerSkeletonBase::RefuseAtCap(Stream stream, const std::string& peer) {
  if (const uint64_t n = refusals_.Note())
    log_->warn("{} {} connection(s) refused, latest from {}: at the cap of {} connections (--max-connections)", n,
               options_.role.peer, peer, options_.maxConnections);
  RefuseConnection(std::move(stream),
                   MakeError(0, wire::ERROR_CODE_TOO_MANY_CONNECTIONS,
                             fmt::format("this {} serves at most {} connections at once; try again later",
                                         options_.role.service, options_.maxConnections),
                             true));
}

std::shared_ptr<Connection> ServerSkeletonBase::NewConnection(Stream stream, uint64_t id, const std::string& peer) {
  auto connection = Connection::Create(std::move(stream), options_.connection,
                                       fmt::format("{}#{} {}", options_.role.peer, id, peer));
  log_->info("{}: connected", connection->Id());
  return connection;
}

}  // namespace penumbra::net
