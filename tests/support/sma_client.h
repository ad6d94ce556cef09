#pragma once
// A scripted Penumbra client for protocol-level tests: handshakes with an
// SMA, sends views, and applies every delta it receives to a HeldMesh, so
// every protocol rule is checked along the way.

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include "penumbra/common/camera.h"
#include "penumbra/common/expected.h"
#include "support/held_mesh.h"
#include "support/process.h"
#include "support/wire_client.h"

namespace penumbra::testing {

class SmaTestClient {
 public:
  /// Connects and handshakes (Hello -> Welcome, SceneInfo).
  static Expected<SmaTestClient> Connect(uint16_t port, const std::string& name = "test-client");
  /// The same with an SMA on another host.
  static Expected<SmaTestClient> Connect(const std::string& host, uint16_t port, const std::string& name);

  const wire::Welcome& Welcome() const { return welcome_; }
  const wire::SceneInfo& Info() const { return info_; }
  HeldMesh& Mesh() { return mesh_; }
  WireClient& Wire() { return wire_; }

  /// Sends a view; ids must increase per connection.
  bool SendView(const CameraView& view, uint64_t viewId);

  /// Receives and applies deltas until one for `viewId` reports convergence,
  /// within `timeout` (times SanitizerTimeScale() in a sanitizer build).
  /// Sends a Heartbeat whenever it has sent nothing for 5 s, as the protocol
  /// asks of a waiting client, so that waits longer than the SMA's read
  /// timeout keep the connection.
  Status WaitConverged(uint64_t viewId, std::chrono::milliseconds timeout = std::chrono::seconds(60));

  /// Asks the SMA for a counter, applying deltas that arrive meanwhile
  /// (the reply comes after whatever the SMA queued for this client before
  /// it) within `timeout`.
  Expected<double> Counter(const std::string& name, std::chrono::milliseconds timeout = std::chrono::seconds(10));

  /// Applies one received envelope: deltas go to the mesh, an error reply
  /// fails, anything else is ignored.
  Status Apply(const wire::Envelope& envelope);

  /// Deltas applied so far, in order: (kind, view id, triangles added, removed).
  struct DeltaRecord {
    int kind;
    uint64_t viewId;
    int added;
    int removed;
  };
  const std::vector<DeltaRecord>& Log() const { return log_; }

 private:
  explicit SmaTestClient(WireClient wire) : wire_(std::move(wire)) {}
  
  WireClient wire_;
  wire::Welcome welcome_;
  wire::SceneInfo info_;
  HeldMesh mesh_;
  std::vector<DeltaRecord> log_;
  uint64_t nextStatsId_ = 1;
  std::chrono::steady_clock::time_point lastSent_ = std::chrono::steady_clock::now();
};

/// The prefix ("renderer.N") of the SMA counters of the renderer endpoint at
/// `address` ("127.0.0.1:7100"): clients see renderers by index only, and
/// the SMA's log pairs each index with its address (an operator's view).
/// Waits up to `timeout` for that log line.
Expected<std::string> RendererCounterPrefix(const ChildProcess& sma, const std::string& address,
                                            std::chrono::milliseconds timeout = std::chrono::seconds(30));

/// A CameraView from a SceneInfo preset, at the given resolution.
CameraView ViewFromPreset(const wire::CameraPreset& preset, int width, int height);
/// The SceneInfo's preset called `name` as a CameraView; an error naming it
/// when the scene has none of that name.
Expected<CameraView> ViewFromPreset(const wire::SceneInfo& info, const std::string& name, int width, int height);

}  // namespace penumbra::testing
