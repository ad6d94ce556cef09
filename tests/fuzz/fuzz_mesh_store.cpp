// The client's delta application (client/src/mesh_store.cpp) on its own:
// deltas applied in order to a mesh store set up for the Cornell box's eight
// materials, two of them textured, so that the fuzzer spends its time on
// the store rather than on reaching it through a handshake. The scene has
// two movable objects (issue 14), so vertex_objects and MOVED deltas are
// exercised too. A refused delta
// resets the store, as the client does when it drops the connection.
// After every delta the store's own view must be consistent: the vertex
// slots cover every held vertex, and every triangle slot in use names a
// vertex slot in range. Input: a stream of frames whose envelopes carry
// deltas (other bodies are skipped). Every held vertex lies within the
// bounds the store was given (MeshStore::SetVertexBounds).

#include <cmath>

#include "fuzz_support.h"
#include "penumbra/client/mesh_store.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace penumbra;
  static const bool quiet = (fuzz::QuietLogs(), true);
  (void)quiet;
  // Materials 0..7; 6 and 7 use textures 0 and 1.
  const std::vector<int32_t> materialTextures{-1, -1, -1, -1, -1, -1, 0, 1};
  const std::vector<RigidTransform> objects{RigidTransform::Identity(),
                                            RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.5f, Vec3(1, 0, 0))};
  // Vertices must lie within 10 m of the origin in every space (the seeds'
  // do); the fuzzer's far-flung ones are refused.
  const Bounds3 room{Vec3(-10.0f), Vec3(10.0f)};
  const std::vector<Bounds3> spaceBounds{room, room, room};
  client::MeshStore store;
  auto reset = [&] {
    store.Reset(materialTextures, 2, objects);
    PENUMBRA_CHECK(store.SetVertexBounds(spaceBounds).ok(), "three finite boxes for three spaces");
  };
  reset();
  for (const wire::Envelope& envelope : fuzz::DecodeFrameStream(data, size)) {
    if (!envelope.has_delta()) continue;
    if (!store.Apply(envelope.delta())) {
      reset();
      continue;
    }
    const auto vertexSlots = store.VertexSlots();
    PENUMBRA_CHECK(vertexSlots.size() >= store.VertexCount(), "fewer vertex slots than vertices");
    for (const client::GpuVertex& v : vertexSlots)  // released slots are zeroed: inside too
      for (int c = 0; c < 3; ++c)
        PENUMBRA_CHECK(std::abs(v.position[c]) <= 10.1f, "a held vertex outside the bounds set");
    size_t triangles = 0;
    for (client::TriangleGroup& group : store.Groups()) {
      PENUMBRA_CHECK(group.slots.size() >= group.allocator.HighWater(), "triangle slots behind the allocator");
      for (size_t s = 0; s < group.allocator.HighWater(); ++s) {
        const client::GpuTriangle& t = group.slots[s];
        if (t.corners[0].material == client::kEmptyTriangleSlot) continue;
        ++triangles;
        for (const client::GpuCorner& c : t.corners)
          PENUMBRA_CHECK(c.vertexSlot < vertexSlots.size(), "a triangle names a vertex slot out of range");
      }
      for (const client::SlotRange& r : group.dirty.Take())
        PENUMBRA_CHECK(uint64_t(r.first) + r.count <= group.allocator.HighWater(), "a dirty range beyond the slots in use");
    }
    PENUMBRA_CHECK(triangles == store.TriangleCount(), "triangle slots disagree with the triangle count");
    for (const client::SlotRange& r : store.DirtyVertices().Take())
      PENUMBRA_CHECK(uint64_t(r.first) + r.count <= vertexSlots.size(), "a dirty vertex range beyond the slots in use");
    (void)store.HeldLuminance();
    PENUMBRA_CHECK(store.ObjectTransforms().size() == objects.size() + 1, "the transform table lost its size");
  }
  return 0;
}
