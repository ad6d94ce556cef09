#include "gl/mesh_renderer.h"

#include <algorithm>
#include <chrono>

#include <glm/gtc/type_ptr.hpp>

#include "penumbra/client/texture_filtering.h"

// The GL code sees the client core's domain types (ClientScene, the mesh
// store, the session's events), never the wire's protobuf messages: this
// fails the build if an include brings them back.
#ifdef GOOGLE_PROTOBUF_INCLUDED_penumbra_2fwire_2eproto
#error "penumbra/wire.pb.h reached the GL code; keep protobuf types inside the client core's .cpp files"
#endif

namespace penumbra::client::gl {

namespace {

// Dirty ranges closer than this many clean slots are uploaded as one: a few
// unchanged slots cost less than another glBufferSubData call.
constexpr uint32_t kMergeGapSlots = 64;
constexpr uint32_t kMinCapacitySlots = 1024;

// Capacity for `needed` slots when `current` is too small: at least 1.5x what
// is needed and twice what was there, so that a large first view is not
// followed by a full re-upload on the next small delta, and growth stays
// amortised O(1) per slot.
uint32_t GrownCapacity(uint32_t needed, uint32_t current) {
  return std::max({needed + needed / 2, 2 * current, kMinCapacitySlots});
}

// Texture units.
constexpr GLint kVertexUnit = 0;
constexpr GLint kMaterialUnit = 1;
constexpr GLint kAlbedoUnit = 2;
constexpr GLint kObjectUnit = 3;

constexpr const char* kMeshVertexShader = R"(#version 330 core
layout(location = 0) in uint aVertexSlot;
layout(location = 1) in uint aMaterial;
layout(location = 2) in vec2 aUv;
uniform samplerBuffer uVertices;  // per vertex slot: position (w: object id), radiance, irradiance
uniform samplerBuffer uObjects;   // per object id: object-to-world rows (0: identity, the static part)
uniform mat4 uWorldToClip;
out vec3 vRadiance;
out vec3 vIrradiance;
out vec2 vUv;
flat out uint vMaterial;
const uint kEmptyTriangleSlot = 0xffffffffu;
void main() {
  vMaterial = aMaterial;
  vUv = aUv;
  if (aMaterial == kEmptyTriangleSlot) {
    // All three corners of an empty slot land outside the clip volume.
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
    vRadiance = vec3(0.0);
    vIrradiance = vec3(0.0);
    return;
  }
  int texel = int(aVertexSlot) * 3;
  vec4 stored = texelFetch(uVertices, texel);
  // A movable object's vertices are in its space; a move changes only its
  // row of uObjects (MeshStore, "Movable objects").
  int object = int(stored.w + 0.5) * 3;
  vec4 p = vec4(stored.xyz, 1.0);
  vec3 world = vec3(dot(texelFetch(uObjects, object), p), dot(texelFetch(uObjects, object + 1), p),
                    dot(texelFetch(uObjects, object + 2), p));
  gl_Position = uWorldToClip * vec4(world, 1.0);
  vRadiance = texelFetch(uVertices, texel + 1).rgb;
  vIrradiance = texelFetch(uVertices, texel + 2).rgb;
}
)";

constexpr const char* kRadianceFragmentShader = R"(#version 330 core
in vec3 vRadiance;
in vec3 vIrradiance;
in vec2 vUv;
flat in uint vMaterial;
uniform samplerBuffer uMaterials;  // per material: albedo Kd, emission
uniform sampler2D uAlbedo;         // sRGB texture: sampling returns linear values
uniform bool uTextured;
layout(location = 0) out vec4 outRadiance;
const float kPi = 3.14159265358979323846;
void main() {
  vec3 radiance = vRadiance;
  if (uTextured) {
    vec3 kd = texelFetch(uMaterials, int(vMaterial) * 2).rgb;
    vec3 emission = texelFetch(uMaterials, int(vMaterial) * 2 + 1).rgb;
    // Image row 0 is uploaded first (t = 0) but v = 0 is the image's bottom
    // row (common/scene.h, Texture::Sample): flip v.
    vec3 albedo = kd * texture(uAlbedo, vec2(vUv.x, 1.0 - vUv.y)).rgb;
    radiance = albedo / kPi * vIrradiance + (gl_FrontFacing ? emission : vec3(0.0));
  }
  outRadiance = vec4(radiance, 1.0);
}
)";

constexpr const char* kWireFragmentShader = R"(#version 330 core
uniform vec4 uColour;
layout(location = 0) out vec4 outColour;
void main() { outColour = uColour; }
)";

}  // namespace

Expected<MeshRenderer> MeshRenderer::Create(std::optional<float> requestedAnisotropy) {
  auto radiance = BuildProgram("mesh radiance", kMeshVertexShader, kRadianceFragmentShader);
  if (!radiance) return radiance.error();
  auto wire = BuildProgram("mesh wireframe", kMeshVertexShader, kWireFragmentShader);
  if (!wire) return wire.error();
  MeshRenderer renderer(std::move(*radiance), std::move(*wire));
  GLfloat maxAnisotropy = 1.0f;  // without the extension: isotropic only
  if (epoxy_has_gl_extension("GL_EXT_texture_filter_anisotropic") ||
      epoxy_has_gl_extension("GL_ARB_texture_filter_anisotropic"))
    glGetFloatv(GL_MAX_TEXTURE_MAX_ANISOTROPY_EXT, &maxAnisotropy);
  const auto* glRenderer = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  renderer.anisotropy_ = ChooseAnisotropy(requestedAnisotropy, glRenderer ? glRenderer : "", maxAnisotropy);
  renderer.vertexBuffer_ = MakeBuffer();
  renderer.vertexTexture_ = MakeTexture();
  renderer.materialBuffer_ = MakeBuffer();
  renderer.materialTexture_ = MakeTexture();
  renderer.objectBuffer_ = MakeBuffer();
  renderer.objectTexture_ = MakeTexture();
  for (const Program* p : {&renderer.radiance_, &renderer.wire_}) {
    glUseProgram(p->id());
    glUniform1i(glGetUniformLocation(p->id(), "uVertices"), kVertexUnit);
    glUniform1i(glGetUniformLocation(p->id(), "uMaterials"), kMaterialUnit);
    glUniform1i(glGetUniformLocation(p->id(), "uAlbedo"), kAlbedoUnit);
    glUniform1i(glGetUniformLocation(p->id(), "uObjects"), kObjectUnit);
  }
  glUseProgram(0);
  if (auto error = TakeGlError("creating the mesh renderer"); !error.empty()) return Fail(error);
  return renderer;
}

Status MeshRenderer::Sync(ClientModel& model) {
  lastUploadBytes_ = 0;
  MeshStore& store = model.Mesh();
  if (model.Scene() && model.SceneGeneration() != sceneGeneration_) {
    sceneGeneration_ = model.SceneGeneration();
    UploadMaterials(*model.Scene());
    groups_.clear();  // drops the old scene's textures too
  }
  if (groups_.size() != store.Groups().size()) groups_.resize(store.Groups().size());
  for (const ReceivedTexture& texture : model.TakeTextures()) UploadTexture(texture);
  SyncVertices(store);
  if (store.TakeObjectTransformsChanged()) UploadObjectTransforms(store);
  for (size_t g = 0; g < groups_.size(); ++g) SyncGroup(store.Groups()[g], groups_[g]);
  if (auto error = TakeGlError("uploading mesh changes"); !error.empty()) return Fail(error);
  return Status::Ok();
}

void MeshRenderer::UploadMaterials(const ClientScene& scene) {
  std::vector<float> texels;
  texels.reserve(scene.materials.size() * 8);
  for (const ClientMaterial& m : scene.materials) {
    texels.insert(texels.end(), {m.albedo.x, m.albedo.y, m.albedo.z, 0.0f});
    texels.insert(texels.end(), {m.emission.x, m.emission.y, m.emission.z, 0.0f});
  }
  if (texels.empty()) texels.resize(8, 0.0f);  // a texture buffer needs storage
  glBindBuffer(GL_TEXTURE_BUFFER, materialBuffer_.id());
  glBufferData(GL_TEXTURE_BUFFER, GLsizeiptr(texels.size() * sizeof(float)), texels.data(), GL_STATIC_DRAW);
  glBindTexture(GL_TEXTURE_BUFFER, materialTexture_.id());
  glTexBuffer(GL_TEXTURE_BUFFER, GL_RGBA32F, materialBuffer_.id());
  lastUploadBytes_ += texels.size() * sizeof(float);
}

void MeshRenderer::UploadObjectTransforms(const MeshStore& store) {
  // The whole table (48 bytes per object, entry 0 the identity): a move of
  // any size of object costs this, and no vertex upload.
  const std::span<const GpuObjectTransform> table = store.ObjectTransforms();
  GpuObjectTransform identity{{{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}}};
  const void* data = table.empty() ? &identity : table.data();
  const size_t bytes = table.empty() ? sizeof identity : table.size_bytes();
  glBindBuffer(GL_TEXTURE_BUFFER, objectBuffer_.id());
  glBufferData(GL_TEXTURE_BUFFER, GLsizeiptr(bytes), data, GL_DYNAMIC_DRAW);
  glBindTexture(GL_TEXTURE_BUFFER, objectTexture_.id());
  glTexBuffer(GL_TEXTURE_BUFFER, GL_RGBA32F, objectBuffer_.id());
  lastUploadBytes_ += bytes;
}

void MeshRenderer::UploadTexture(const ReceivedTexture& texture) {
  if (texture.index + 1 >= groups_.size()) return;  // not of this scene
  GroupBuffers& group = groups_[texture.index + 1];
  group.albedo = MakeTexture();
  glBindTexture(GL_TEXTURE_2D, group.albedo.id());
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
  glTexImage2D(GL_TEXTURE_2D, 0, GL_SRGB8, texture.width, texture.height, 0, GL_RGB, GL_UNSIGNED_BYTE,
               texture.rgb8.data());
  glGenerateMipmap(GL_TEXTURE_2D);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_REPEAT);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_REPEAT);
  // Anisotropic filtering (chosen at Create, texture_filtering.h): the
  // floors and walls of a walkthrough are seen at grazing angles, where
  // isotropic mipmapping blurs texture detail a camera would still resolve.
  group.anisotropy = anisotropy_;
  if (anisotropy_ > 1.0f) glTexParameterf(GL_TEXTURE_2D, GL_TEXTURE_MAX_ANISOTROPY_EXT, anisotropy_);
  group.albedoWidth = texture.width;
  group.albedoHeight = texture.height;
  lastUploadBytes_ += texture.rgb8.size();
}

void MeshRenderer::SyncVertices(MeshStore& store) {
  const std::span<const GpuVertex> slots = store.VertexSlots();
  glBindBuffer(GL_TEXTURE_BUFFER, vertexBuffer_.id());
  if (slots.size() > vertexCapacity_ || vertexCapacity_ == 0) {
    vertexCapacity_ = GrownCapacity(uint32_t(slots.size()), vertexCapacity_);
    glBufferData(GL_TEXTURE_BUFFER, GLsizeiptr(vertexCapacity_ * sizeof(GpuVertex)), nullptr, GL_DYNAMIC_DRAW);
    glBufferSubData(GL_TEXTURE_BUFFER, 0, GLsizeiptr(slots.size_bytes()), slots.data());
    lastUploadBytes_ += slots.size_bytes();
    store.DirtyVertices().Clear();  // all uploaded
    glBindTexture(GL_TEXTURE_BUFFER, vertexTexture_.id());
    glTexBuffer(GL_TEXTURE_BUFFER, GL_RGBA32F, vertexBuffer_.id());
    return;
  }
  for (const SlotRange& r : store.DirtyVertices().Take(kMergeGapSlots)) {
    glBufferSubData(GL_TEXTURE_BUFFER, GLintptr(r.first * sizeof(GpuVertex)), GLsizeiptr(r.count * sizeof(GpuVertex)),
                    &slots[r.first]);
    lastUploadBytes_ += r.count * sizeof(GpuVertex);
  }
}

void MeshRenderer::SyncGroup(TriangleGroup& group, GroupBuffers& gpu) {
  const uint32_t used = group.allocator.HighWater();
  gpu.drawnSlots = used;
  if (!gpu.vao.id()) {
    gpu.vao = MakeVertexArray();
    gpu.corners = MakeBuffer();
    glBindVertexArray(gpu.vao.id());
    glBindBuffer(GL_ARRAY_BUFFER, gpu.corners.id());
    constexpr GLsizei stride = sizeof(GpuCorner);
    glEnableVertexAttribArray(0);
    glVertexAttribIPointer(0, 1, GL_UNSIGNED_INT, stride, reinterpret_cast<void*>(offsetof(GpuCorner, vertexSlot)));
    glEnableVertexAttribArray(1);
    glVertexAttribIPointer(1, 1, GL_UNSIGNED_INT, stride, reinterpret_cast<void*>(offsetof(GpuCorner, material)));
    glEnableVertexAttribArray(2);
    glVertexAttribPointer(2, 2, GL_FLOAT, GL_FALSE, stride, reinterpret_cast<void*>(offsetof(GpuCorner, uv)));
    glBindVertexArray(0);
  }
  glBindBuffer(GL_ARRAY_BUFFER, gpu.corners.id());
  if (used > gpu.capacity) {
    gpu.capacity = GrownCapacity(used, gpu.capacity);
    glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(gpu.capacity * sizeof(GpuTriangle)), nullptr, GL_DYNAMIC_DRAW);
    glBufferSubData(GL_ARRAY_BUFFER, 0, GLsizeiptr(used * sizeof(GpuTriangle)), group.slots.data());
    lastUploadBytes_ += used * sizeof(GpuTriangle);
    group.dirty.Clear();
    return;
  }
  for (const SlotRange& r : group.dirty.Take(kMergeGapSlots)) {
    if (r.first >= used) continue;  // slots beyond the high-water mark are not drawn
    const uint32_t count = std::min(r.count, used - r.first);
    glBufferSubData(GL_ARRAY_BUFFER, GLintptr(r.first * sizeof(GpuTriangle)), GLsizeiptr(count * sizeof(GpuTriangle)),
                    &group.slots[r.first]);
    lastUploadBytes_ += count * sizeof(GpuTriangle);
  }
}

void MeshRenderer::DrawGroups(const Program& program, const glm::mat4& worldToClip, bool textures,
                              int onlyGroup) const {
  glUseProgram(program.id());
  glUniformMatrix4fv(glGetUniformLocation(program.id(), "uWorldToClip"), 1, GL_FALSE, glm::value_ptr(worldToClip));
  const GLint textured = glGetUniformLocation(program.id(), "uTextured");
  glActiveTexture(GL_TEXTURE0 + kVertexUnit);
  glBindTexture(GL_TEXTURE_BUFFER, vertexTexture_.id());
  glActiveTexture(GL_TEXTURE0 + kMaterialUnit);
  glBindTexture(GL_TEXTURE_BUFFER, materialTexture_.id());
  glActiveTexture(GL_TEXTURE0 + kObjectUnit);
  glBindTexture(GL_TEXTURE_BUFFER, objectTexture_.id());
  glActiveTexture(GL_TEXTURE0 + kAlbedoUnit);
  for (size_t g = 0; g < groups_.size(); ++g) {
    const GroupBuffers& group = groups_[g];
    if (group.drawnSlots == 0 || (onlyGroup >= 0 && size_t(onlyGroup) != g)) continue;
    const bool useTexture = textures && group.albedo.id() != 0;
    if (textured >= 0) glUniform1i(textured, useTexture ? 1 : 0);
    glBindTexture(GL_TEXTURE_2D, useTexture ? group.albedo.id() : 0);
    glBindVertexArray(group.vao.id());
    glDrawArrays(GL_TRIANGLES, 0, GLsizei(group.drawnSlots * 3));
  }
  glBindVertexArray(0);
  glActiveTexture(GL_TEXTURE0);
}

void MeshRenderer::DrawRadiance(const glm::mat4& worldToClip) const {
  if (vertexCapacity_ == 0) return;  // nothing synced yet
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  DrawGroups(radiance_, worldToClip, /*textures=*/true);
  glDisable(GL_DEPTH_TEST);
}

std::vector<MeshRenderer::GroupDrawTime> MeshRenderer::TimeGroupDraws(const glm::mat4& worldToClip) {
  std::vector<GroupDrawTime> times;
  auto timed = [&](int g, bool textures) {
    glFinish();
    const auto start = std::chrono::steady_clock::now();
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    DrawGroups(radiance_, worldToClip, textures, g);
    glDisable(GL_DEPTH_TEST);
    glFinish();
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  };
  for (size_t g = 0; g < groups_.size(); ++g) {
    GroupBuffers& group = groups_[g];
    if (group.drawnSlots == 0) continue;
    GroupDrawTime t;
    t.texture = int32_t(g) - 1;
    t.textureWidth = group.albedoWidth;
    t.textureHeight = group.albedoHeight;
    t.slots = group.drawnSlots;
    t.seconds = timed(int(g), true);
    t.secondsUntextured = timed(int(g), false);
    if (group.albedo.id() && group.anisotropy > 1.0f) {
      glActiveTexture(GL_TEXTURE0 + kAlbedoUnit);
      glBindTexture(GL_TEXTURE_2D, group.albedo.id());
      glTexParameterf(GL_TEXTURE_2D, GL_TEXTURE_MAX_ANISOTROPY_EXT, 1.0f);
      t.secondsIsotropic = timed(int(g), true);
      glActiveTexture(GL_TEXTURE0 + kAlbedoUnit);
      glBindTexture(GL_TEXTURE_2D, group.albedo.id());
      glTexParameterf(GL_TEXTURE_2D, GL_TEXTURE_MAX_ANISOTROPY_EXT, group.anisotropy);
      glBindTexture(GL_TEXTURE_2D, 0);
      glActiveTexture(GL_TEXTURE0);
    } else {
      t.secondsIsotropic = t.seconds;
    }
    times.push_back(t);
  }
  return times;
}

void MeshRenderer::DrawWireframe(const glm::mat4& worldToClip, const glm::vec4& colour) const {
  if (vertexCapacity_ == 0) return;
  glUseProgram(wire_.id());
  glUniform4fv(glGetUniformLocation(wire_.id(), "uColour"), 1, glm::value_ptr(colour));
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LEQUAL);
  glDepthMask(GL_FALSE);
  // Lines are pulled toward the viewer so the surface they lie on passes them.
  glEnable(GL_POLYGON_OFFSET_LINE);
  glPolygonOffset(-1.0f, -1.0f);
  glPolygonMode(GL_FRONT_AND_BACK, GL_LINE);
  glEnable(GL_BLEND);
  glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
  DrawGroups(wire_, worldToClip, /*textures=*/false);
  glDisable(GL_BLEND);
  glPolygonMode(GL_FRONT_AND_BACK, GL_FILL);
  glDisable(GL_POLYGON_OFFSET_LINE);
  glDepthMask(GL_TRUE);
  glDisable(GL_DEPTH_TEST);
}

}  // namespace penumbra::client::gl
