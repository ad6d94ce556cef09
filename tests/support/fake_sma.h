#pragma once
// The SMA's side of the client protocol, scripted, for tests of clients: a
// test accepts a client's connection on a WireListener, serves the handshake
// with these helpers, and then sends whatever deltas (good or bad) it wants.

#include <chrono>
#include <cstdint>

#include "penumbra/common/client_scene.h"
#include "penumbra/common/expected.h"
#include "penumbra/wire.pb.h"
#include "support/wire_client.h"

namespace penumbra::testing {

/// A SceneInfo for a unit square in the z = 0 plane: material 0 untextured
/// grey, material 1 textured (texture 0 of 1), one camera preset "front"
/// looking at the square from +z, Drago defaults.
wire::SceneInfo UnitSquareSceneInfo();
/// The same, as the client receives it (ClientSceneFromWire) from an SMA
/// whose scene has this identity.
ClientScene UnitSquareScene(uint64_t identity = 1);

/// Waits for the client's Hello (role CLIENT), answers Welcome (role SMA,
/// `sceneHash`) and `info`.
Status ServeClientHandshake(WireClient& client, const wire::SceneInfo& info, uint64_t sceneHash = 1);

/// The next View the client sends, skipping other messages (stats and
/// texture requests).
Expected<wire::View> ReceiveView(WireClient& client, std::chrono::milliseconds timeout = std::chrono::seconds(10));

}  // namespace penumbra::testing
