// SmaSession against a scripted SMA in the same process (support/fake_sma.h):
// handshake, views, deltas, texture requests, and reconnection with
// back-off after the SMA goes away or the client abandons a connection.

#include "penumbra/client/session.h"

#include <cmath>
#include <thread>

#include <gtest/gtest.h>

#include "penumbra/common/messages.h"
#include "support/delta_builder.h"
#include "penumbra/common/messages.h"
#include "support/fake_sma.h"

namespace penumbra::client {
namespace {

using namespace std::chrono_literals;
using testing::DeltaBuilder;
using testing::WireClient;
using testing::WireListener;
using Clock = std::chrono::steady_clock;

CameraView FrontView() {
  CameraView view;
  view.pose = CameraPose{Vec3(0.5f, 0.5f, 2.0f), Vec3(0.5f, 0.5f, 0.0f), Vec3(0, 1, 0)};
  view.width = 64;
  view.height = 48;
  return view;
}

class SessionTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto listener = WireListener::Listen();
    ASSERT_TRUE(listener.ok()) << listener.error().message;
    listener_ = std::make_unique<WireListener>(std::move(*listener));
    SmaSessionOptions options;
    options.sma = HostPort{"127.0.0.1", listener_->Port()};
    options.reconnectMin = 50ms;
    options.reconnectMax = 200ms;
    session_ = std::make_unique<SmaSession>(options);
    session_->Start();
  }

  // Accepts the session's next connection and serves the handshake.
  WireClient AcceptClient() {
    auto client = listener_->Accept(5s);
    EXPECT_TRUE(client.ok()) << client.error().message;
    auto served = testing::ServeClientHandshake(*client, testing::UnitSquareSceneInfo());
    EXPECT_TRUE(served.ok()) << served.error().message;
    return std::move(*client);
  }

  // Collects events until one of type T arrives (or a timeout).
  template <class T>
  std::optional<T> WaitForEvent(std::chrono::milliseconds timeout = 5s) {
    const auto deadline = Clock::now() + timeout;
    while (Clock::now() < deadline) {
      for (SessionEvent& e : session_->TakeEvents()) {
        seen_.push_back(e);
        if (auto* t = std::get_if<T>(&e)) return std::move(*t);
      }
      std::this_thread::sleep_for(5ms);
    }
    return std::nullopt;
  }

  std::unique_ptr<WireListener> listener_;
  std::unique_ptr<SmaSession> session_;
  std::vector<SessionEvent> seen_;
};

TEST_F(SessionTest, HandshakesSendsTheViewAndHandsDeltasOver) {
  const uint64_t serial = session_->SetView(FrontView());
  EXPECT_EQ(serial, 1u);
  WireClient sma = AcceptClient();
  auto connected = WaitForEvent<Connected>();
  ASSERT_TRUE(connected.has_value());
  EXPECT_EQ(connected->connection, 1u);
  EXPECT_EQ(connected->scene.name, "unit-square");
  EXPECT_EQ(connected->scene.identity, 1u);  // the Welcome's scene hash
  EXPECT_EQ(session_->Status().state, ConnectionState::kConnected);

  auto view = testing::ReceiveView(sma);
  ASSERT_TRUE(view.ok()) << view.error().message;
  EXPECT_EQ(view->view_id(), 1u);
  EXPECT_EQ(view->width(), 64u);
  EXPECT_FLOAT_EQ(view->eye().z(), 2.0f);

  ASSERT_TRUE(sma.Send(DeltaBuilder(1, 1).Converged().Envelope()));
  auto delta = WaitForEvent<DeltaReceived>();
  ASSERT_TRUE(delta.has_value());
  EXPECT_EQ(delta->viewSerial, serial);
  EXPECT_EQ(delta->delta->sequence(), 1u);
  const SessionStatus status = session_->Status();
  EXPECT_TRUE(status.viewToFirstDeltaMs.has_value());
  EXPECT_GT(status.bytesReceived, 0u);

  // A converged delta is followed by a counters request, and a new view gets
  // the connection's next id.
  const uint64_t second = session_->SetView(FrontView());
  EXPECT_EQ(second, 2u);
  bool sawStatsRequest = false;
  for (int i = 0; i < 5; ++i) {
    auto e = sma.Receive(2s);
    ASSERT_TRUE(e.ok()) << e.error().message;
    sawStatsRequest |= e->has_stats_request();
    if (e->has_view()) {
      EXPECT_EQ(e->view().view_id(), 2u);
      break;
    }
  }
  EXPECT_TRUE(sawStatsRequest);
}

TEST_F(SessionTest, ReconnectsWhenTheSmaGoesAwayAndSendsTheViewAgain) {
  session_->SetView(FrontView());
  {
    WireClient sma = AcceptClient();
    ASSERT_TRUE(WaitForEvent<Connected>().has_value());
    ASSERT_TRUE(testing::ReceiveView(sma).ok());
  }  // the SMA closes
  auto lost = WaitForEvent<Disconnected>();
  ASSERT_TRUE(lost.has_value());
  EXPECT_EQ(lost->connection, 1u);
  EXPECT_FALSE(session_->Status().lastError.empty());

  WireClient sma = AcceptClient();
  auto connected = WaitForEvent<Connected>();
  ASSERT_TRUE(connected.has_value());
  EXPECT_EQ(connected->connection, 2u);
  auto view = testing::ReceiveView(sma);
  ASSERT_TRUE(view.ok());
  EXPECT_EQ(view->view_id(), 1u) << "view ids count per connection";
  EXPECT_EQ(session_->Status().connections, 2u);
}

// An SMA stopping says SHUTTING_DOWN before it closes: the client reports
// that, not a bare "peer closed the connection", and reconnects.
TEST_F(SessionTest, AnSmaShuttingDownIsReportedAsSuchAndReconnectedTo) {
  session_->SetView(FrontView());
  {
    WireClient sma = AcceptClient();
    ASSERT_TRUE(WaitForEvent<Connected>().has_value());
    ASSERT_TRUE(sma.Send(MakeError(0, wire::ERROR_CODE_SHUTTING_DOWN, "SMA is shutting down", true)));
  }  // and closes
  auto lost = WaitForEvent<Disconnected>();
  ASSERT_TRUE(lost.has_value());
  EXPECT_NE(lost->reason.find("is shutting down"), std::string::npos) << lost->reason;
  EXPECT_NE(session_->Status().lastError.find("is shutting down"), std::string::npos) << session_->Status().lastError;
  WireClient sma = AcceptClient();
  ASSERT_TRUE(WaitForEvent<Connected>().has_value());
  EXPECT_EQ(session_->Status().connections, 2u);
}

TEST_F(SessionTest, AbandoningAConnectionTellsTheSmaWhyAndReconnects) {
  session_->SetView(FrontView());
  WireClient first = AcceptClient();
  ASSERT_TRUE(WaitForEvent<Connected>().has_value());
  session_->AbandonConnection(1, "delta 2: removal of triangle 9, which is not held");
  bool sawError = false;
  for (int i = 0; i < 5 && !sawError; ++i) {
    auto e = first.Receive(2s);
    if (!e) break;
    sawError = e->has_error() && e->error().fatal() &&
               e->error().message().find("removal of triangle 9") != std::string::npos;
  }
  EXPECT_TRUE(sawError);
  EXPECT_TRUE(first.WaitClosed());
  WireClient second = AcceptClient();
  auto connected = WaitForEvent<Connected>();
  ASSERT_TRUE(connected.has_value());
  EXPECT_EQ(connected->connection, 2u);
  // A request naming the abandoned connection is ignored.
  session_->AbandonConnection(1, "stale");
  session_->RequestTexture(2, 0);
  auto request = second.Receive(2s);
  ASSERT_TRUE(request.ok());
  while (request.ok() && !request->has_texture_request()) request = second.Receive(2s);
  ASSERT_TRUE(request.ok());
  EXPECT_EQ(request->texture_request().texture(), 0u);
}

TEST_F(SessionTest, RefusesADeltaForAViewNeverSent) {
  WireClient sma = AcceptClient();
  ASSERT_TRUE(WaitForEvent<Connected>().has_value());
  ASSERT_TRUE(sma.Send(DeltaBuilder(1, 5).Envelope()));
  bool sawError = false;
  for (int i = 0; i < 5 && !sawError; ++i) {
    auto e = sma.Receive(2s);
    if (!e) break;
    sawError = e->has_error() && e->error().fatal() && e->error().message().find("view 5") != std::string::npos;
  }
  EXPECT_TRUE(sawError);
  EXPECT_TRUE(sma.WaitClosed());
  EXPECT_FALSE(WaitForEvent<DeltaReceived>(300ms).has_value());
}

TEST(SessionRetryTest, KeepsTryingUntilAnSmaListens) {
  uint16_t port = 0;
  {
    auto probe = WireListener::Listen();
    ASSERT_TRUE(probe.ok());
    port = probe->Port();
  }  // nobody listens there now
  SmaSessionOptions options;
  options.sma = HostPort{"127.0.0.1", port};
  options.reconnectMin = 20ms;
  options.reconnectMax = 100ms;
  SmaSession session(options);
  session.Start();
  std::this_thread::sleep_for(300ms);
  SessionStatus status = session.Status();
  EXPECT_NE(status.state, ConnectionState::kConnected);
  EXPECT_NE(status.lastError.find("refused"), std::string::npos) << status.lastError;

  auto listener = WireListener::Listen(port);
  ASSERT_TRUE(listener.ok()) << listener.error().message;
  auto sma = listener->Accept(5s);
  ASSERT_TRUE(sma.ok()) << sma.error().message;
  ASSERT_TRUE(testing::ServeClientHandshake(*sma, testing::UnitSquareSceneInfo()).ok());
  const auto deadline = Clock::now() + 5s;
  while (session.Status().state != ConnectionState::kConnected && Clock::now() < deadline)
    std::this_thread::sleep_for(5ms);
  EXPECT_EQ(session.Status().state, ConnectionState::kConnected);
  EXPECT_TRUE(session.Status().lastError.empty());
  session.Stop();
  EXPECT_EQ(session.Status().state, ConnectionState::kStopped);
}

// Issue 16: what retrying cannot fix stops the session with the reason;
// what it can fix (the SMA shutting down) is retried as before.
TEST_F(SessionTest, PermanentRefusalsStopTheSessionAndTransientOnesAreRetried) {
  auto refuse = [&](wire::ErrorCode code, const std::string& message) {
    auto client = listener_->Accept(5s);
    ASSERT_TRUE(client.ok()) << client.error().message;
    auto hello = client->Receive(5s);
    ASSERT_TRUE(hello.ok() && hello->has_hello());
    ASSERT_TRUE(client->Send(MakeError(0, code, message, /*fatal=*/true)));
  };
  // Transient: the session comes back.
  refuse(wire::ERROR_CODE_SHUTTING_DOWN, "draining");
  {
    auto again = listener_->Accept(5s);
    ASSERT_TRUE(again.ok()) << "a transient refusal is retried: " << again.error().message;
    auto hello = again->Receive(5s);
    ASSERT_TRUE(hello.ok() && hello->has_hello());
    ASSERT_TRUE(again->Send(MakeError(0, wire::ERROR_CODE_VERSION_MISMATCH,
                                      "protocol version 1 is not supported (this peer speaks 2)", true)));
  }
  const auto deadline = Clock::now() + 5s;
  while (session_->Status().permanentError.empty() && Clock::now() < deadline) std::this_thread::sleep_for(10ms);
  const SessionStatus status = session_->Status();
  EXPECT_EQ(status.state, ConnectionState::kStopped);
  EXPECT_NE(status.permanentError.find("protocol version 1 is not supported"), std::string::npos)
      << status.permanentError;
  EXPECT_FALSE(listener_->Accept(1s).ok()) << "no retry after a permanent refusal";
}

TEST(SessionPermanentTest, AWelcomeFromAnotherRoleStopsTheSession) {
  for (const wire::Role role : {wire::ROLE_RENDERER, wire::ROLE_CLIENT}) {
    auto listener = WireListener::Listen();
    ASSERT_TRUE(listener.ok());
    SmaSessionOptions options;
    options.sma = HostPort{"127.0.0.1", listener->Port()};
    options.reconnectMin = 50ms;
    SmaSession session(options);
    session.Start();
    auto peer = listener->Accept(5s);
    ASSERT_TRUE(peer.ok());
    ASSERT_TRUE(peer->Receive(5s).ok());
    wire::Envelope welcome;
    welcome.mutable_welcome()->set_protocol_version(kProtocolVersion);
    welcome.mutable_welcome()->set_role(role);
    ASSERT_TRUE(peer->Send(welcome));
    const auto deadline = Clock::now() + 5s;
    while (session.Status().permanentError.empty() && Clock::now() < deadline) std::this_thread::sleep_for(10ms);
    EXPECT_NE(session.Status().permanentError.find("expected sma"), std::string::npos)
        << session.Status().permanentError;
    EXPECT_FALSE(listener->Accept(500ms).ok()) << "no retry";
  }
}

// Issue 14: MoveObject goes out with its object, its 12 row-major floats and
// a request id marked as a move; the SMA's non-fatal refusal comes back as
// an event (the connection stays); a move without a connection is reported,
// not queued.
TEST_F(SessionTest, MovesAreSentAndTheirRefusalsSurfaceWithoutEndingTheConnection) {
  const RigidTransform t = RigidTransform::FromAxisAngle(Vec3(0, 0, 1), 0.5f, Vec3(1, 2, 3));
  const uint64_t early = session_->MoveObject(1, t);
  EXPECT_NE(early & kMoveRequestBit, 0u);
  auto notSent = WaitForEvent<SmaErrorReceived>();
  ASSERT_TRUE(notSent.has_value());
  EXPECT_EQ(notSent->requestId, early);
  EXPECT_TRUE(notSent->move);
  EXPECT_NE(notSent->message.find("not sent: no connection"), std::string::npos) << notSent->message;

  WireClient sma = AcceptClient();
  ASSERT_TRUE(WaitForEvent<Connected>().has_value());
  const uint64_t requestId = session_->MoveObject(2, t);
  EXPECT_NE(requestId, early);
  std::optional<wire::MoveObject> move;
  for (int i = 0; i < 10 && !move; ++i) {
    auto e = sma.Receive(2s);
    ASSERT_TRUE(e.ok()) << e.error().message;
    if (e->has_move_object()) move = e->move_object();
  }
  ASSERT_TRUE(move.has_value());
  EXPECT_EQ(move->request_id(), requestId);
  EXPECT_EQ(move->object(), 2u);
  ASSERT_EQ(move->object_to_world_size(), 12);
  const auto m = t.ToRowMajor();
  for (int i = 0; i < 12; ++i) EXPECT_EQ(move->object_to_world(i), m[size_t(i)]);

  ASSERT_TRUE(sma.Send(MakeError(requestId, wire::ERROR_CODE_INVALID_REQUEST, "object 2 is animated", false)));
  auto refused = WaitForEvent<SmaErrorReceived>();
  ASSERT_TRUE(refused.has_value());
  EXPECT_EQ(refused->connection, 1u);
  EXPECT_EQ(refused->requestId, requestId);
  EXPECT_TRUE(refused->move);
  EXPECT_NE(refused->message.find("object 2 is animated"), std::string::npos) << refused->message;
  // Still connected: a delta still arrives.
  session_->SetView(FrontView());
  ASSERT_TRUE(testing::ReceiveView(sma).ok());
  ASSERT_TRUE(sma.Send(DeltaBuilder(1, 1).Converged().Envelope()));
  EXPECT_TRUE(WaitForEvent<DeltaReceived>().has_value());
  EXPECT_EQ(session_->Status().connections, 1u);
}

// A MOVED may come before the SMA has this connection's first view (another
// client's move, an animation step): view id 0 is then not a violation.
TEST_F(SessionTest, AMovedBeforeTheFirstViewIsHandedOver) {
  WireClient sma = AcceptClient();
  ASSERT_TRUE(WaitForEvent<Connected>().has_value());
  DeltaBuilder moved(1, 0, wire::DELTA_KIND_MOVED);
  moved.Mutable().set_scene_epoch(3);
  ASSERT_TRUE(sma.Send(moved.Envelope()));
  auto delta = WaitForEvent<DeltaReceived>();
  ASSERT_TRUE(delta.has_value());
  EXPECT_EQ(delta->viewSerial, 0u);
  EXPECT_EQ(delta->delta->kind(), wire::DELTA_KIND_MOVED);
  // Any other delta for view 0 still is one.
  ASSERT_TRUE(sma.Send(DeltaBuilder(2, 0, wire::DELTA_KIND_STATUS).Envelope()));
  bool refused = false;
  for (int i = 0; i < 10 && !refused; ++i) {
    auto e = sma.Receive(2s);
    if (!e) break;
    refused = e->has_error() && e->error().fatal();
  }
  EXPECT_TRUE(refused);
}

}  // namespace
}  // namespace penumbra::client
