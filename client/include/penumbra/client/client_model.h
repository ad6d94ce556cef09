#pragma once
// Everything the client knows about the scene, built from SessionEvents on
// the render thread between frames: the scene (ClientScene), the held mesh
// (MeshStore), the textures received, and the convergence state of the
// latest view. A delta or texture that breaks the protocol empties the mesh
// and makes the session drop that connection; the next connection starts
// from an empty mesh. No GL here.
//
// Threads: render thread only; not thread-safe.

#include <cstdint>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "penumbra/client/mesh_store.h"
#include "penumbra/client/session.h"

namespace spdlog {
class logger;
}

namespace penumbra::client {

/// A texture received and not yet uploaded: sRGB 8-bit RGB, row 0 at the top.
struct ReceivedTexture {
  uint32_t index = 0;
  int width = 0;
  int height = 0;
  std::string rgb8;
};

/// What the SMA last reported this client holds, and whether the client
/// held the same at that point of the stream (after the same deltas).
struct SmaReport {
  uint64_t trianglesHeld = 0;
  uint64_t verticesHeld = 0;
  bool agrees = false;
  uint64_t atSequence = 0;  // the client's last applied delta when it arrived
};

class ClientModel {
 public:
  ClientModel();

  /// Applies events in arrival order. Protocol violations are reported with
  /// requests.AbandonConnection(); the connection's later events are then
  /// ignored.
  void Apply(std::vector<SessionEvent> events, SessionRequests& requests);

  /// True between a Connected event and the end (or abandonment) of that connection.
  bool Online() const { return online_; }
  /// The latest connection's number (0 before the first); the mesh was emptied when it changed.
  uint64_t ConnectionNumber() const { return connection_; }
  /// The latest connection's scene; null before the first connection.
  const ClientScene* Scene() const { return scene_ ? &*scene_ : nullptr; }
  /// Changes whenever a connection serves another scene identity (or the
  /// first time): materials may differ and received textures are dropped.
  uint64_t SceneGeneration() const { return sceneGeneration_; }
  MeshStore& Mesh() { return mesh_; }
  const MeshStore& Mesh() const { return mesh_; }

  /// The SMA's non-fatal error replies (refused moves) since the last call,
  /// for the HUD; each is logged by the session already.
  std::vector<SmaErrorReceived> TakeSmaErrors() { return std::exchange(smaErrors_, {}); }

  /// Textures received since the last call, for upload. The model keeps no copy.
  std::vector<ReceivedTexture> TakeTextures();

  /// True when the last delta applied answers the view with this SetView()
  /// serial and reports it converged, and every texture the held triangles
  /// use has arrived: the image is final until the camera moves.
  bool Converged(uint64_t viewSerial) const;

  const std::optional<SmaReport>& LastSmaReport() const { return smaReport_; }
  /// Deltas or textures refused since start.
  uint64_t ProtocolErrors() const { return protocolErrors_; }

 private:
  void OnConnected(Connected&& event);
  void OnDelta(const DeltaReceived& event, SessionRequests& requests);
  void OnTexture(TextureReceived&& event, SessionRequests& requests);
  void OnCounters(const SmaCountersReceived& event);
  void Abandon(const std::string& reason, SessionRequests& requests);
  void ResetMesh();
  void RequestNeededTextures(SessionRequests& requests);
  bool NeededTexturesArrived() const;

  std::shared_ptr<spdlog::logger> log_;
  MeshStore mesh_;
  std::optional<ClientScene> scene_;
  uint64_t sceneGeneration_ = 0;
  uint64_t connection_ = 0;
  bool online_ = false;
  uint64_t deltaViewSerial_ = 0;  // of the last delta applied
  std::set<uint32_t> texturesRequested_;  // on this connection, or received earlier for this scene
  std::set<uint32_t> texturesReceived_;   // for this scene
  std::vector<ReceivedTexture> texturesToUpload_;
  std::optional<SmaReport> smaReport_;
  uint64_t protocolErrors_ = 0;
  std::vector<SmaErrorReceived> smaErrors_;
};

}  // namespace penumbra::client
