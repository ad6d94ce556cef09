#pragma once
// The client's side of the client protocol (docs/protocol.md, "Client
// protocol"), on its own network thread: connects to an SMA, handshakes,
// sends the camera, requests textures and counters, and hands everything it
// receives to the render thread as SessionEvents. When the connection fails
// or is lost it reconnects with exponential back-off and sends the latest
// view again; each successful handshake starts a new numbered connection, so
// the render thread can tell a fresh mesh from a stale one.
//
// Threads: the session owns one network thread running an io_context; all
// connection and session state is touched only there. The public methods
// are thread-safe and never block on the network: they post to that thread
// or read a snapshot under a small lock.

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "penumbra/common/camera.h"
#include "penumbra/common/client_scene.h"
#include "penumbra/common/connection_options.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/refinement_params.h"
#include "penumbra/common/rigid_transform.h"
#include "penumbra/common/tls.h"

namespace penumbra::wire {
class Delta;  // penumbra/wire.pb.h: only the model's mesh store reads a delta's fields
}

namespace penumbra::client {

// --- Events handed to the render thread ------------------------------------

/// A handshake completed: `connection` (1, 2, ...) numbers it; everything
/// held from earlier connections is stale.
struct Connected {
  uint64_t connection = 0;
  /// The SceneInfo, validated (ClientSceneFromWire), with the Welcome's
  /// scene hash as its identity.
  ClientScene scene;
};

/// The numbered connection ended; a reconnection follows unless stopping.
struct Disconnected {
  uint64_t connection = 0;
  std::string reason;
};

struct DeltaReceived {
  uint64_t connection = 0;
  /// The SetView() serial of the view this delta answers, or 0 when it
  /// answers an older view than the last one sent.
  uint64_t viewSerial = 0;
  /// Never null. Shared, so that events stay copyable and the header does
  /// not need the generated protobuf code (the GL code includes it).
  std::shared_ptr<const wire::Delta> delta;
};

/// A TextureData's fields as received; ClientModel validates them.
struct TextureReceived {
  uint64_t connection = 0;
  uint32_t texture = 0;
  uint32_t width = 0;
  uint32_t height = 0;
  std::string rgb8;  // width * height * 3 bytes, sRGB-encoded, rows top first (if valid)
};

/// The SMA's counters about this client, in stream order with the deltas:
/// after applying every earlier delta the client should hold exactly what
/// the SMA believes it holds.
struct SmaCountersReceived {
  uint64_t connection = 0;
  std::map<std::string, double> counters;
};

/// A non-fatal ErrorReply from the SMA: a request of this client was
/// refused and nothing changed (a MoveObject on an animated object, say);
/// the connection goes on.
struct SmaErrorReceived {
  uint64_t connection = 0;
  uint64_t requestId = 0;  // the refused request's; a MoveObject's has kMoveRequestBit
  bool move = false;       // it answers a MoveObject (or a move that could not be sent: connection 0)
  std::string message;     // "SMA host:port reports CODE: text", printable
};

using SessionEvent =
    std::variant<Connected, Disconnected, DeltaReceived, TextureReceived, SmaCountersReceived, SmaErrorReceived>;

/// MoveObject request ids have this bit set, so that an ErrorReply tells
/// which kind of request it answers.
inline constexpr uint64_t kMoveRequestBit = uint64_t(1) << 62;

/// What the render thread's model asks of the network side. Calls name the
/// connection they concern and are ignored once it has ended.
class SessionRequests {
 public:
  virtual ~SessionRequests() = default;
  /// Asks the SMA for a texture (answered by a TextureReceived).
  virtual void RequestTexture(uint64_t connection, uint32_t texture) = 0;
  /// Reports a protocol violation to the SMA (a fatal ErrorReply), closes
  /// the connection and reconnects after the back-off.
  virtual void AbandonConnection(uint64_t connection, const std::string& reason) = 0;
};

enum class ConnectionState {
  kConnecting,   // resolving, connecting or handshaking
  kConnected,    // handshake done, SceneInfo received
  kWaiting,      // back-off before the next attempt
  kStopped,
};
const char* ToString(ConnectionState state);

/// A snapshot for the HUD and the statistics lines.
struct SessionStatus {
  ConnectionState state = ConnectionState::kConnecting;
  uint64_t connections = 0;       // successful handshakes so far
  uint64_t bytesReceived = 0;     // over every connection
  std::optional<double> viewToFirstDeltaMs;  // the latest view's, once its first delta arrived
  std::string lastError;          // why the last connection or attempt failed; empty if none
  /// Set when the SMA's address answered with something retrying cannot fix
  /// (another role -- e.g. a renderer's port --, another protocol version, a
  /// scene mismatch; AUTH_FAILED: a missing or wrong token, or TLS
  /// required): the session has stopped (state kStopped) and this says
  /// why. Empty otherwise.
  std::string permanentError;
  /// When the state is kConnecting or kWaiting: since when the client has
  /// been without a connection (or since Start()).
  std::chrono::steady_clock::time_point disconnectedSince;
};

struct SmaSessionOptions {
  HostPort sma;
  std::string clientName = "penumbra-client";
  net::ConnectionOptions connection{.maxFrameBytes = 256u << 20};  // textures arrive whole
  std::chrono::milliseconds connectTimeout{3000};
  std::chrono::milliseconds reconnectMin{250};
  std::chrono::milliseconds reconnectMax{5000};
  /// Interval between StatsRequests while connected (one is also sent after
  /// every delta that reports convergence).
  std::chrono::milliseconds countersInterval{1000};
  /// Reading from the socket pauses while the render thread has not taken
  /// this many bytes of events, so a slow renderer backs the SMA up (which
  /// then coalesces its deltas) instead of growing memory.
  size_t maxPendingEventBytes = size_t(64) << 20;
  /// Sent in the Hello (the SMA's --auth-token-file); empty: none.
  std::string authToken;
  /// TLS to the SMA, verified against this context's CA and the host name
  /// in `sma`; null: plain TCP.
  std::shared_ptr<net::ssl::context> tls;
};

class SmaSession final : public SessionRequests {
 public:
  explicit SmaSession(SmaSessionOptions options);
  /// Stops the network thread (Stop()).
  ~SmaSession() override;
  SmaSession(const SmaSession&) = delete;
  SmaSession& operator=(const SmaSession&) = delete;

  /// Starts the network thread and the first connection attempt. Once.
  void Start();
  /// Closes the connection and joins the network thread. Idempotent.
  void Stop();

  /// The camera to show. Sent at once when connected (with the next view id
  /// of the connection), and again after every reconnection. Returns the
  /// view's serial (1, 2, ...), which DeltaReceived::viewSerial refers to.
  uint64_t SetView(const CameraView& view);

  /// Refinement settings for this client's session on the SMA (founding
  /// paper §4). Sent at once when connected, and again after every
  /// reconnection, before the view.
  void SetSessionOptions(const RefinementRequest& request);

  /// Asks the SMA to move object `object` (ClientObject id, 1..N) to
  /// `objectToWorld` (issue 14); every client of the scene, this one
  /// included, then receives a MOVED delta. Sent at once when connected;
  /// without a connection it is dropped (a move is not replayed on a later
  /// connection, where the scene may have moved on) and an
  /// SmaErrorReceived says so. A refusal arrives as an SmaErrorReceived.
  /// Returns the request id (kMoveRequestBit set). Any thread.
  uint64_t MoveObject(uint32_t object, const RigidTransform& objectToWorld);

  /// Every event since the last call, in arrival order. Never blocks.
  std::vector<SessionEvent> TakeEvents();

  SessionStatus Status() const;

  void RequestTexture(uint64_t connection, uint32_t texture) override;
  void AbandonConnection(uint64_t connection, const std::string& reason) override;

 private:
  class Impl;
  std::shared_ptr<Impl> impl_;
};

}  // namespace penumbra::client
