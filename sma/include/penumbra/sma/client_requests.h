#pragma once
// The checks the SMA makes on what a client sends, as plain functions of the
// message (no session, no socket), so that they are fuzzed with bytes
// (tests/fuzz) and the server's session only applies their result.

#include <cstddef>
#include <cstdint>

#include "penumbra/common/camera.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/scene.h"
#include "penumbra/wire.pb.h"

namespace penumbra::sma {

/// The camera view a View message asks for, or why it is refused: not a
/// usable view (ValidateCameraView) or more than `maxViewPixels` pixels.
/// Messages start with "view <id>: ". Any thread.
Expected<CameraView> ViewFromWire(const wire::View& view, uint64_t maxViewPixels);

// SessionOptions are converted and checked by ApplySessionOptions
// (common/wire_convert.h), shared with the client; the limits this SMA sets
// on top are CheckClientRefinement (client_limits.h).

/// OK when the TextureRequest names one of the scene's `textureCount` textures.
Status CheckTextureRequest(const wire::TextureRequest& request, size_t textureCount);

}  // namespace penumbra::sma
