#pragma once
// The held mesh on the GPU, and the draw calls that shade it.
//
// Layout: vertex slots live in one buffer read as a texture buffer (three
// RGBA32F texels per vertex: position, radiance, irradiance); each triangle
// group (one per texture, MeshStore) has a vertex buffer of corner records
// (vertex slot, material, uv) drawn with glDrawArrays, so a triangle's
// corners fetch their vertex by slot. Sync() uploads only the slot ranges a
// delta dirtied; a buffer is reallocated (and refilled) only when its slots
// outgrow it, doubling, so that cost is amortised over many deltas.
//
// Movable objects: a vertex slot's position.w names its object; the vertex
// shader applies that object's transform from a texture buffer of
// transforms (MeshStore::ObjectTransforms, entry 0 the identity), so a move
// uploads 48 bytes per object of the scene and no vertex.
//
// Shading: untextured triangles interpolate the vertices' radiance
// (Gouraud); textured ones compute emission + Kd * texture / pi * E per
// pixel from the interpolated irradiance E, so texture detail finer than the
// mesh shows. Textures are uploaded as sRGB, so sampling returns linear
// albedo. Until a texture arrives its triangles show the vertex radiance.
//
// Threads: render thread, with the context current.

#include <cstdint>
#include <optional>
#include <vector>

#include <glm/mat4x4.hpp>
#include <glm/vec4.hpp>

#include "gl/gl_objects.h"
#include "penumbra/client/client_model.h"

namespace penumbra::client::gl {

class MeshRenderer {
 public:
  /// `requestedAnisotropy`: --anisotropy, or nullopt for the default
  /// (penumbra/client/texture_filtering.h: 16 on a GPU, 1 on llvmpipe).
  static Expected<MeshRenderer> Create(std::optional<float> requestedAnisotropy = std::nullopt);
  /// The GL_TEXTURE_MAX_ANISOTROPY textures are filtered with (1: isotropic).
  float Anisotropy() const { return anisotropy_; }

  /// Brings the GPU copy up to date with `model`: materials and textures
  /// when the scene changes, textures received, and the dirty slot ranges
  /// of vertices and triangles (which it takes from the model's store).
  /// Fails on a GL error (out of memory).
  Status Sync(ClientModel& model);

  /// Draws the radiance of every held triangle into the bound RGBA32F
  /// framebuffer (alpha 1 where a surface is), with depth testing.
  void DrawRadiance(const glm::mat4& worldToClip) const;
  /// Draws every held triangle's edges in `colour` (alpha-blended) over the
  /// bound framebuffer, tested against the depth the radiance pass left.
  void DrawWireframe(const glm::mat4& worldToClip, const glm::vec4& colour) const;

  /// Bytes sent to the GPU by the last Sync().
  size_t LastUploadBytes() const { return lastUploadBytes_; }

  /// Diagnostics for a slow frame: how long each group's radiance draw takes
  /// alone (into the bound framebuffer, waited for with glFinish), as drawn,
  /// without its texture, and with its texture filtered isotropically.
  struct GroupDrawTime {
    int32_t texture = -1;
    int textureWidth = 0, textureHeight = 0;
    uint32_t slots = 0;
    double seconds = 0.0, secondsUntextured = 0.0, secondsIsotropic = 0.0;
  };
  std::vector<GroupDrawTime> TimeGroupDraws(const glm::mat4& worldToClip);

 private:
  struct GroupBuffers {
    Buffer corners;
    VertexArray vao;
    uint32_t capacity = 0;      // triangle slots the buffer holds
    uint32_t drawnSlots = 0;    // the store's high-water mark at the last Sync
    Texture albedo;             // empty until the texture arrives
    int albedoWidth = 0, albedoHeight = 0;
    float anisotropy = 1.0f;    // the albedo's GL_TEXTURE_MAX_ANISOTROPY
  };

  MeshRenderer(Program radiance, Program wire) : radiance_(std::move(radiance)), wire_(std::move(wire)) {}
  void UploadMaterials(const ClientScene& scene);
  void UploadTexture(const ReceivedTexture& texture);
  void UploadObjectTransforms(const MeshStore& store);
  void SyncVertices(MeshStore& store);
  void SyncGroup(TriangleGroup& group, GroupBuffers& gpu);
  void DrawGroups(const Program& program, const glm::mat4& worldToClip, bool textures, int onlyGroup = -1) const;

  Program radiance_;
  Program wire_;
  Buffer vertexBuffer_;
  Texture vertexTexture_;  // texture-buffer view of vertexBuffer_
  uint32_t vertexCapacity_ = 0;
  Buffer materialBuffer_;
  Texture materialTexture_;
  Buffer objectBuffer_;
  Texture objectTexture_;  // texture-buffer view of objectBuffer_: 3 texels per object
  std::vector<GroupBuffers> groups_;
  float anisotropy_ = 1.0f;
  uint64_t sceneGeneration_ = 0;
  size_t lastUploadBytes_ = 0;
};

}  // namespace penumbra::client::gl
