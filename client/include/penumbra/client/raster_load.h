#pragma once
// What one frame's mesh draw asks of the rasteriser, estimated on the CPU
// from the mesh store: how many triangle slots the draw calls cover and how
// many pixels the held triangles cover on screen (overdraw included). Used
// to explain a slow frame in the log (is the mesh unusual, or is the GL
// implementation slow on an ordinary one?). Pure math, no GL; O(triangle
// slots), so it is meant for the occasional frame, not every one.

#include <cstdint>
#include <string>

#include <glm/mat4x4.hpp>

#include "penumbra/client/mesh_store.h"
#include "penumbra/common/math.h"

namespace penumbra::client {

struct RasterLoad {
  uint64_t slotsDrawn = 0;     // triangle slots the draw calls cover (each group's high-water mark)
  uint64_t trianglesLive = 0;  // of them, slots that hold a triangle
  /// Sum over live triangles of their pixel area inside the viewport (at
  /// most the triangle's bounding box clipped to the viewport; a triangle
  /// with a corner at or behind the eye plane counts its clipped box, as
  /// far as it can be told, else the whole viewport).
  double coveredPixels = 0.0;
  uint64_t trianglesCrossingEyePlane = 0;
  /// The live triangle covering the most pixels, and its corners (world).
  double largestPixels = 0.0;
  Vec3 largestCorners[3] = {};
};

/// `width` x `height`: the viewport the draw renders into.
RasterLoad MeasureRasterLoad(const MeshStore& store, const glm::mat4& worldToClip, int width, int height);

/// One line for the log: counts, covered pixels as a multiple of the
/// viewport (the overdraw), the largest triangle.
std::string Describe(const RasterLoad& load, int width, int height);

}  // namespace penumbra::client
