// net::Connection::StartOn (common/connection.h) on real sockets: the owner's
// handlers run on its own strand, not on the I/O thread, in the order the
// frames came; a slow owner stops the reading (bounded inbox) without the
// read timeout firing; the frame after a Hello is read under the limit the
// owner's MarkHandshakeDone sets.

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "penumbra/common/connection.h"
#include "penumbra/common/messages.h"
#include "support/wire_client.h"

namespace penumbra {
namespace {

using namespace std::chrono_literals;
using testing::WireClient;

// A server-side Connection on an accepted loopback socket, its io_context on
// one thread and an owner pool of one thread.
struct OwnedConnection {
  explicit OwnedConnection(net::ConnectionOptions options) : acceptor(io, tcp::endpoint(asio::ip::make_address("127.0.0.1"), 0)) {
    auto connected = WireClient::Connect("127.0.0.1", acceptor.local_endpoint().port());
    EXPECT_TRUE(connected.ok());
    if (connected) client.emplace(std::move(*connected));
    tcp::socket socket(io);
    acceptor.accept(socket);
    connection = net::Connection::Create(std::move(socket), options, "test#1");
  }
  ~OwnedConnection() {
    if (connection) connection->Close("test over");
    guard.reset();
    io.stop();
    if (ioThread.joinable()) ioThread.join();
    owner.join();  // runs what is queued: nothing it holds outlives io
  }
  void Start(size_t maxInbox, std::function<void(wire::Envelope&&)> onMessage) {
    connection->StartOn(asio::make_strand(owner.get_executor()), maxInbox, std::move(onMessage),
                        [this](const std::string& reason) {
                          std::lock_guard lock(mutex);
                          closeReason = reason;
                          closedOnOwner = std::this_thread::get_id() != ioThreadId;
                          closedAfter = received.size();
                          closed.notify_all();
                        });
    ioThread = std::thread([this] {
      ioThreadId = std::this_thread::get_id();
      ready = true;
      io.run();
    });
    while (!ready) std::this_thread::sleep_for(1ms);
  }
  // Owner side: records a view's id (or -1) and whether it ran off the I/O thread.
  void Record(const wire::Envelope& envelope) {
    std::lock_guard lock(mutex);
    received.push_back(envelope.has_view() ? int64_t(envelope.view().view_id()) : -1);
    offIoThread = offIoThread && std::this_thread::get_id() != ioThreadId;
    arrived.notify_all();
  }
  bool WaitReceived(size_t n, std::chrono::milliseconds timeout = 10s) {
    std::unique_lock lock(mutex);
    return arrived.wait_for(lock, timeout, [&] { return received.size() >= n; });
  }

  // Declared before io: the connection (held by io's abandoned handlers)
  // holds a strand of it. The SMA orders its own the same way.
  asio::thread_pool owner{1};
  asio::io_context io;
  std::optional<asio::executor_work_guard<asio::io_context::executor_type>> guard{asio::make_work_guard(io)};
  tcp::acceptor acceptor;
  std::optional<WireClient> client;
  std::shared_ptr<net::Connection> connection;
  std::thread ioThread;
  std::atomic<bool> ready{false};
  std::thread::id ioThreadId;

  std::mutex mutex;
  std::condition_variable arrived, closed;
  std::vector<int64_t> received;
  bool offIoThread = true;
  std::string closeReason;
  bool closedOnOwner = false;
  size_t closedAfter = 0;
};

wire::Envelope View(uint64_t id) {
  wire::Envelope envelope;
  envelope.mutable_view()->set_view_id(id);
  return envelope;
}

TEST(ConnectionStartOn, HandlersRunOnTheOwnersStrandInOrderAndTheCloseLast) {
  OwnedConnection c({});
  c.Start(8, [&](wire::Envelope&& e) { c.Record(e); });
  constexpr int kViews = 500;
  std::string burst;
  for (int i = 1; i <= kViews; ++i) burst += EncodeEnvelopeFrame(View(i));
  ASSERT_TRUE(c.client->SendRaw(burst));
  ASSERT_TRUE(c.WaitReceived(kViews));
  c.client.reset();  // the peer closes
  std::unique_lock lock(c.mutex);
  ASSERT_TRUE(c.closed.wait_for(lock, 10s, [&] { return !c.closeReason.empty(); }));
  EXPECT_TRUE(c.offIoThread) << "a message handler ran on the I/O thread";
  EXPECT_TRUE(c.closedOnOwner) << "the close handler ran on the I/O thread";
  EXPECT_EQ(c.closedAfter, size_t(kViews)) << "the close overtook messages";
  ASSERT_EQ(c.received.size(), size_t(kViews));
  for (int i = 0; i < kViews; ++i) ASSERT_EQ(c.received[i], i + 1) << "out of order at " << i;
}

TEST(ConnectionStartOn, ASlowOwnerStopsTheReadingWithoutATimeout) {
  net::ConnectionOptions options;
  options.readTimeout = 300ms;        // the owner is slower than this
  options.heartbeatInterval = 100ms;
  OwnedConnection c(options);
  std::mutex gateMutex;
  std::condition_variable gateOpened;
  bool open = false;
  c.Start(4, [&](wire::Envelope&& e) {
    {
      std::unique_lock lock(gateMutex);
      gateOpened.wait(lock, [&] { return open; });
    }
    c.Record(e);
  });
  // Megabytes of views: a connection that kept reading would have read all
  // of them (loopback takes what is sent at once), one that stopped at most
  // its read chunk and what the inbox holds.
  constexpr int kViews = 500'000;
  std::thread sender([&] {
    std::string burst;
    for (int i = 1; i <= kViews; ++i) {
      burst += EncodeEnvelopeFrame(View(i));
      if (burst.size() > (1 << 20) || i == kViews) {
        if (!c.client->SendRaw(burst)) return;
        burst.clear();
      }
    }
  });
  std::this_thread::sleep_for(1s);  // three read timeouts
  const uint64_t readWhileBlocked = c.connection->BytesReceived();
  EXPECT_TRUE(c.connection->IsOpen()) << "closed while its owner was busy: " << c.closeReason;
  EXPECT_LT(readWhileBlocked, uint64_t(1) << 20) << "kept reading for an owner that handled nothing";
  {
    std::lock_guard lock(gateMutex);
    open = true;
  }
  gateOpened.notify_all();
  sender.join();
  ASSERT_TRUE(c.WaitReceived(kViews, 60s)) << c.received.size() << " of " << kViews << "; " << c.closeReason;
  std::lock_guard lock(c.mutex);
  for (int i = 0; i < kViews; ++i) ASSERT_EQ(c.received[i], i + 1) << "out of order at " << i;
}

// A Hello and, in the same write, a frame larger than the limit before the
// handshake: read after the owner's MarkHandshakeDone it passes; without it
// the connection closes (what the test would see if the connection read
// ahead of the owner).
void HelloThenLargeFrame(bool markHandshake) {
  net::ConnectionOptions options;
  options.handshakeTimeout = 5s;
  options.maxFrameBytesBeforeHandshake = 1024;
  options.maxFrameBytes = 1 << 20;
  OwnedConnection c(options);
  c.Start(8, [&](wire::Envelope&& e) {
    if (e.has_hello() && markHandshake) {
      std::this_thread::sleep_for(50ms);  // an owner that takes its time
      c.connection->MarkHandshakeDone();
    }
    c.Record(e);
  });
  wire::Envelope hello;
  hello.mutable_hello()->set_peer_name("test");
  wire::Envelope error;  // 8 kB: over the limit before the handshake
  error.mutable_error()->set_message(std::string(8000, 'x'));
  ASSERT_TRUE(c.client->SendRaw(EncodeEnvelopeFrame(hello) + EncodeEnvelopeFrame(error) +
                                EncodeEnvelopeFrame(View(9))));
  if (markHandshake) {
    ASSERT_TRUE(c.WaitReceived(3));
    EXPECT_TRUE(c.connection->IsOpen());
  } else {
    EXPECT_TRUE(c.client->WaitClosed());
    std::lock_guard lock(c.mutex);
    EXPECT_EQ(c.received.size(), 1u) << "only the Hello is under the limit";
  }
}

TEST(ConnectionStartOn, TheFrameAfterAHelloIsReadUnderTheLimitTheOwnerSets) { HelloThenLargeFrame(true); }
TEST(ConnectionStartOn, WithoutTheHandshakeALargeFrameCloses) { HelloThenLargeFrame(false); }

}  // namespace
}  // namespace penumbra
