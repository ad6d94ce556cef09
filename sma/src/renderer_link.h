#pragma once
// One connection to one renderer address: connect (TCP or TLS), Hello and
// the renderer's Welcome, back-off and reconnection, frames in and out. It
// moves bytes and reports events; which samples it carries is the
// SampleScheduler's business, reached through the RendererPool.
//
// Threads: its public functions are thread-safe (a small mutex of its own,
// taken after the pool's, never held while it calls an event handler). The
// handlers run on the connection's strand or the link's timer, without the
// link's lock.

#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <string>

#include "penumbra/common/connection.h"
#include "penumbra/sma/renderer_pool.h"

namespace penumbra::sma {

class RendererLink : public std::enable_shared_from_this<RendererLink> {
 public:
  struct Events {
    /// The renderer's Welcome was accepted: the link is ready for batches.
    std::function<void(RendererLink&, const wire::Welcome&)> onReady;
    /// Any other message from the renderer (ShadeReply, Error, ...).
    std::function<void(RendererLink&, wire::Envelope&&)> onMessage;
    /// The connection closed (or never opened); the link reconnects after
    /// its back-off unless removed. `wasReady`: it had been ready.
    std::function<void(RendererLink&, const std::string& reason, bool wasReady)> onClosed;
  };

  /// `options` must outlive the link (the pool's).
  static std::shared_ptr<RendererLink> Create(asio::io_context& io, const RendererPoolOptions& options,
                                              tcp::endpoint endpoint, std::string host, uint32_t index, Events events);

  /// Connects now (posted to the I/O context).
  void Start();
  /// Sends one encoded frame; false when not connected or its queue is full.
  bool Send(std::shared_ptr<const std::string> frame);
  /// Drops the current connection (it reconnects after its back-off).
  void Drop(const std::string& reason);
  /// Closes for good: no reconnection.
  void Remove(const std::string& reason);
  /// The next reconnection waits at least this long (quarantine, refusals).
  void BackOffAtLeast(std::chrono::milliseconds wait);
  /// A whole batch answered well: the next reconnection may be quick.
  void ResetBackOff();
  std::chrono::milliseconds BackOff() const;

  bool Ready() const;
  std::string PeerName() const;
  const tcp::endpoint& Endpoint() const { return endpoint_; }
  const std::string& Label() const { return label_; }
  uint32_t Index() const { return index_; }

 private:
  enum class State { kWaiting, kConnecting, kHandshaking, kReady, kRemoved };
  RendererLink(asio::io_context& io, const RendererPoolOptions& options, tcp::endpoint endpoint, std::string host,
               uint32_t index, Events events);
  void Connect();
  void OnConnected(net::Stream stream);
  void OnMessage(wire::Envelope&& envelope);
  void OnClosed(const std::string& reason);
  void ScheduleReconnectLocked();

  asio::io_context& io_;
  const RendererPoolOptions& options_;
  const tcp::endpoint endpoint_;
  const std::string host_;  // the configured name it came from: TLS checks the certificate against it
  const std::string label_;
  const uint32_t index_;
  const Events events_;

  mutable std::mutex mutex_;
  State state_ = State::kWaiting;
  std::shared_ptr<net::Connection> connection_;
  std::chrono::milliseconds backoff_;
  asio::steady_timer timer_;
  std::string peerName_;
  uint32_t connectFailures_ = 0;  // in a row; 0 once ready
};

}  // namespace penumbra::sma
