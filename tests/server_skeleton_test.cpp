// net::ServerSkeleton (common/server_skeleton.h) on real sockets: the
// connection cap, the session registry, the stats hook, and the graceful
// shutdown that tells every peer SHUTTING_DOWN. The renderer's and the SMA's
// protocol tests cover the same behaviour through the real servers.

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "penumbra/common/messages.h"
#include "penumbra/common/server_skeleton.h"
#include "support/wire_client.h"

namespace penumbra {
namespace {

using namespace std::chrono_literals;
using testing::WireClient;

// The least a session is: it reads (dropping what it gets) and leaves the
// registry when its connection closes.
class QuietSession : public std::enable_shared_from_this<QuietSession> {
 public:
  QuietSession(net::ServerSkeleton<QuietSession>* const* skeleton, std::shared_ptr<net::Connection> connection,
               uint64_t id)
      : skeleton_(skeleton), connection_(std::move(connection)), id_(id) {}
  void Start() {
    auto self = shared_from_this();
    connection_->Start([](wire::Envelope&&) {}, [self](const std::string&) { (*self->skeleton_)->Remove(self->id_); });
  }
  net::Connection& Connection() { return *connection_; }

 private:
  net::ServerSkeleton<QuietSession>* const* skeleton_;
  std::shared_ptr<net::Connection> connection_;
  uint64_t id_;
};

struct TestServer {
  explicit TestServer(size_t maxConnections) {
    net::ServerSkeletonOptions options;
    options.name = "skeleton-test";
    options.role.service = "test server";
    options.role.peer = "peer";
    options.role.peers = "peers";
    options.role.logger = "test";
    options.maxConnections = maxConnections;
    options.statsInterval = 20ms;
    skeleton = std::make_unique<net::ServerSkeleton<QuietSession>>(
        io, options,
        net::ServerHooks{.logStats = [this] { ++statsLines; },
                         .beginShutdown = [this] { sessionsAtShutdown = skeleton->SessionCount(); }},
        [this](std::shared_ptr<net::Connection> connection, uint64_t id) {
          return std::make_shared<QuietSession>(&raw, std::move(connection), id);
        });
    raw = skeleton.get();
    auto bound = skeleton->Listen();
    EXPECT_TRUE(bound.ok()) << bound.error().message;
    if (bound) port = bound->port();
    thread = std::thread([this] {
      skeleton->RunIo(2);
      returned = true;
    });
  }
  ~TestServer() {
    skeleton->Shutdown();
    if (thread.joinable()) thread.join();
  }
  bool WaitForSessions(size_t n) {
    for (int i = 0; i < 500 && skeleton->SessionCount() != n; ++i) std::this_thread::sleep_for(10ms);
    return skeleton->SessionCount() == n;
  }

  asio::io_context io;
  std::unique_ptr<net::ServerSkeleton<QuietSession>> skeleton;
  net::ServerSkeleton<QuietSession>* raw = nullptr;
  uint16_t port = 0;
  std::thread thread;
  std::atomic<int> statsLines{0};
  std::atomic<size_t> sessionsAtShutdown{size_t(-1)};
  std::atomic<bool> returned{false};
};

TEST(ServerSkeletonTest, RefusesPeersBeyondTheCapAndServesThoseWithin) {
  TestServer server(2);
  auto a = WireClient::Connect("127.0.0.1", server.port);
  auto b = WireClient::Connect("127.0.0.1", server.port);
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_TRUE(server.WaitForSessions(2));

  auto extra = WireClient::Connect("127.0.0.1", server.port);
  ASSERT_TRUE(extra.ok());
  auto refusal = extra->Receive(5s);
  ASSERT_TRUE(refusal.ok()) << refusal.error().message;
  ASSERT_TRUE(refusal->has_error()) << BodyName(*refusal);
  EXPECT_EQ(refusal->error().code(), wire::ERROR_CODE_TOO_MANY_CONNECTIONS);
  EXPECT_TRUE(refusal->error().fatal());
  EXPECT_NE(refusal->error().message().find("test server serves at most 2 connections"), std::string::npos)
      << refusal->error().message();
  EXPECT_TRUE(extra->WaitClosed(5s));
  EXPECT_EQ(server.skeleton->SessionCount(), 2u);

  // A peer that leaves frees its place.
  a = Fail("closed by the test");
  ASSERT_TRUE(server.WaitForSessions(1));
  auto again = WireClient::Connect("127.0.0.1", server.port);
  ASSERT_TRUE(again.ok());
  EXPECT_TRUE(server.WaitForSessions(2));
}

TEST(ServerSkeletonTest, ShutdownTellsEveryPeerAndReturnsOnceTheyAreClosed) {
  TestServer server(8);
  auto a = WireClient::Connect("127.0.0.1", server.port);
  auto b = WireClient::Connect("127.0.0.1", server.port);
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_TRUE(server.WaitForSessions(2));
  for (int i = 0; i < 500 && server.statsLines == 0; ++i) std::this_thread::sleep_for(10ms);
  EXPECT_GT(server.statsLines.load(), 0) << "the stats hook never ran";

  server.skeleton->Shutdown();
  for (auto* peer : {&*a, &*b}) {
    auto told = peer->Receive(5s);
    ASSERT_TRUE(told.ok()) << told.error().message;
    ASSERT_TRUE(told->has_error()) << BodyName(*told);
    EXPECT_EQ(told->error().code(), wire::ERROR_CODE_SHUTTING_DOWN);
    EXPECT_EQ(told->error().message(), "test server is shutting down");
    EXPECT_TRUE(peer->WaitClosed(5s));
  }
  server.thread.join();
  EXPECT_TRUE(server.returned);
  EXPECT_EQ(server.sessionsAtShutdown.load(), 2u) << "the tier's hook runs before the peers are closed";
  EXPECT_EQ(server.skeleton->SessionCount(), 0u);
  EXPECT_FALSE(WireClient::Connect("127.0.0.1", server.port, 1s).ok()) << "the listener is closed";
}

}  // namespace
}  // namespace penumbra
