#include "penumbra/client/mesh_store.h"

#include <algorithm>
#include <array>
#include <cmath>

#include <fmt/format.h>

#include "penumbra/common/check.h"
#include "penumbra/common/math.h"
#include "penumbra/wire.pb.h"

namespace penumbra::client {

namespace {

bool AllFinite(const google::protobuf::RepeatedField<float>& values) {
  return std::all_of(values.begin(), values.end(), [](float v) { return std::isfinite(v); });
}

Rgb RgbAt(const google::protobuf::RepeatedField<float>& values, int index) {
  return Rgb(values[3 * index], values[3 * index + 1], values[3 * index + 2]);
}

float SlotLuminance(const GpuVertex& v) { return Luminance(Rgb(v.radiance[0], v.radiance[1], v.radiance[2])); }

// The object id a slot's position.w holds (exact: ids are at most kMaxClientSceneObjects).
uint32_t SlotObject(const GpuVertex& v) { return uint32_t(v.position[3]); }

bool IsTransformOnly(wire::DeltaKind kind) {
  return kind == wire::DELTA_KIND_STATUS || kind == wire::DELTA_KIND_IMPROVED || kind == wire::DELTA_KIND_MOVED ||
         kind == wire::DELTA_KIND_RESHADED;
}

}  // namespace

void MeshStore::Reset(std::span<const int32_t> materialTextures, uint32_t textureCount,
                      std::span<const RigidTransform> objectToWorld, uint64_t sceneEpoch) {
  materialTextures_.assign(materialTextures.begin(), materialTextures.end());
  for (int32_t t : materialTextures_)
    PENUMBRA_CHECK(t >= -1 && t < int64_t(textureCount), "material texture index checked with the SceneInfo");
  vertices_.clear();
  triangles_.clear();
  vertexSlots_.clear();
  vertexSlotIds_.clear();
  vertexAllocator_.Clear();
  dirtyVertices_.Clear();
  groups_.assign(size_t(textureCount) + 1, TriangleGroup{});
  for (uint32_t t = 0; t < textureCount; ++t) groups_[t + 1].texture = int32_t(t);
  sequence_ = viewId_ = 0;
  pendingSamples_ = 0;
  converged_ = false;
  refining_ = false;
  progress_ = ViewProgress{};
  trianglesAdded_ = 0;
  luminanceCount_ = 0;
  logLuminanceSum_ = 0.0;
  maxLuminance_ = 0.0f;
  maxStale_ = false;
  objectToWorld_.assign(objectToWorld.begin(), objectToWorld.end());
  localTransform_.assign(objectToWorld_.size(), std::nullopt);
  objectSlots_.assign(objectToWorld_.size() + 1, GpuObjectTransform{});
  for (uint32_t id = 0; id <= ObjectCount(); ++id) WriteObjectSlot(id);
  objectsChanged_ = true;
  sceneEpoch_ = sceneEpoch;
  movesApplied_ = 0;
  vertexBounds_.clear();
}

Status MeshStore::SetVertexBounds(std::span<const Bounds3> spaceBounds) {
  if (spaceBounds.size() != size_t(ObjectCount()) + 1)
    return Fail(fmt::format("{} vertex bounds for {} spaces (the static part and {} movable objects)",
                            spaceBounds.size(), ObjectCount() + 1, ObjectCount()));
  std::vector<Bounds3> grown;
  grown.reserve(spaceBounds.size());
  for (size_t i = 0; i < spaceBounds.size(); ++i) {
    const Bounds3& b = spaceBounds[i];
    const bool finite = std::isfinite(b.min.x) && std::isfinite(b.min.y) && std::isfinite(b.min.z) &&
                        std::isfinite(b.max.x) && std::isfinite(b.max.y) && std::isfinite(b.max.z);
    if (!finite || b.Empty())
      return Fail(fmt::format("the vertex bounds of space {} are empty or not finite", i));
    const float margin = std::max(1e-3f * glm::length(b.Diagonal()), 1e-6f);
    grown.push_back(Bounds3{b.min - Vec3(margin), b.max + Vec3(margin)});
  }
  vertexBounds_ = std::move(grown);
  return Status::Ok();
}

RigidTransform MeshStore::ConfirmedTransform(uint32_t id) const {
  if (id == 0 || id > ObjectCount()) return RigidTransform::Identity();
  return objectToWorld_[id - 1];
}

RigidTransform MeshStore::DisplayedTransform(uint32_t id) const {
  if (id == 0 || id > ObjectCount()) return RigidTransform::Identity();
  return localTransform_[id - 1] ? *localTransform_[id - 1] : objectToWorld_[id - 1];
}

void MeshStore::SetLocalTransform(uint32_t id, const std::optional<RigidTransform>& t) {
  if (id == 0 || id > ObjectCount() || localTransform_[id - 1] == t) return;  // unchanged: no upload
  localTransform_[id - 1] = t;
  WriteObjectSlot(id);
}

void MeshStore::WriteObjectSlot(uint32_t id) {
  const std::array<float, 12> m = DisplayedTransform(id).ToRowMajor();
  GpuObjectTransform& slot = objectSlots_[id];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) slot.rows[r][c] = m[size_t(4 * r + c)];
  objectsChanged_ = true;
}

std::optional<uint32_t> MeshStore::VertexObject(uint64_t id) const {
  auto it = vertices_.find(id);
  if (it == vertices_.end()) return std::nullopt;
  return SlotObject(vertexSlots_[it->second.slot]);
}

std::optional<Vec3> MeshStore::WorldPosition(uint64_t id) const {
  auto it = vertices_.find(id);
  if (it == vertices_.end()) return std::nullopt;
  return WorldPositionOfSlot(it->second.slot);
}

Vec3 MeshStore::WorldPositionOfSlot(uint32_t slot) const {
  const GpuVertex& v = vertexSlots_[slot];
  const Vec3 p(v.position[0], v.position[1], v.position[2]);
  const uint32_t object = SlotObject(v);
  return object == 0 ? p : DisplayedTransform(object).ApplyPoint(p);
}

std::optional<uint32_t> MeshStore::VertexRefs(uint64_t id) const {
  auto it = vertices_.find(id);
  if (it == vertices_.end()) return std::nullopt;
  return it->second.refs;
}

Status MeshStore::CheckShape(const wire::Delta& d) const {
  if (d.sequence() != sequence_ + 1)
    return Fail(fmt::format("delta sequence {} follows {} (a gap)", d.sequence(), sequence_));
  if (!wire::DeltaKind_IsValid(d.kind()) || d.kind() == wire::DELTA_KIND_UNSPECIFIED)
    return Fail(fmt::format("delta {}: unknown kind {}", d.sequence(), int(d.kind())));
  const int nv = d.vertex_ids_size();
  const int nt = d.triangle_ids_size();
  const int nu = d.updated_vertex_ids_size();
  if (IsTransformOnly(d.kind()) && (nv > 0 || nt > 0 || d.removed_triangles_size() > 0))
    return Fail(fmt::format("delta {}: a {} delta carries triangles or new vertices", d.sequence(),
                            wire::DeltaKind_Name(d.kind())));
  if (d.updated_vertex_radiance_size() != 3 * nu || d.updated_vertex_irradiance_size() != 3 * nu)
    return Fail(fmt::format("delta {}: {} updated vertex ids but {} / {} radiance / irradiance values (3 per vertex)",
                            d.sequence(), nu, d.updated_vertex_radiance_size(), d.updated_vertex_irradiance_size()));
  if (d.vertex_positions_size() != 3 * nv || d.vertex_radiance_size() != 3 * nv ||
      d.vertex_irradiance_size() != 3 * nv)
    return Fail(fmt::format("delta {}: {} vertex ids but {} / {} / {} position / radiance / irradiance values "
                            "(3 per vertex)",
                            d.sequence(), nv, d.vertex_positions_size(), d.vertex_radiance_size(),
                            d.vertex_irradiance_size()));
  if (d.triangle_vertices_size() != 3 * nt || d.triangle_materials_size() != nt)
    return Fail(fmt::format("delta {}: {} triangle ids but {} corner vertex ids (3 per triangle) and {} materials",
                            d.sequence(), nt, d.triangle_vertices_size(), d.triangle_materials_size()));
  int textured = 0;
  for (int i = 0; i < nt; ++i) {
    const uint32_t m = d.triangle_materials(i);
    if (m >= materialTextures_.size())
      return Fail(fmt::format("delta {}: triangle {} has material {} but the scene has {}", d.sequence(),
                              d.triangle_ids(i), m, materialTextures_.size()));
    if (materialTextures_[m] >= 0) ++textured;
  }
  if (d.triangle_uvs_size() != 6 * textured)
    return Fail(fmt::format("delta {}: {} texture coordinates for {} textured triangles (6 each)", d.sequence(),
                            d.triangle_uvs_size(), textured));
  if (!AllFinite(d.vertex_positions()) || !AllFinite(d.vertex_radiance()) || !AllFinite(d.vertex_irradiance()) ||
      !AllFinite(d.triangle_uvs()) || !AllFinite(d.updated_vertex_radiance()) ||
      !AllFinite(d.updated_vertex_irradiance()))
    return Fail(fmt::format("delta {}: a vertex position, radiance, irradiance or texture coordinate is not finite",
                            d.sequence()));
  if (auto ok = CheckObjects(d); !ok) return ok;
  return CheckPositions(d);
}

Status MeshStore::CheckPositions(const wire::Delta& d) const {
  if (vertexBounds_.empty()) return Status::Ok();
  for (int i = 0; i < d.vertex_ids_size(); ++i) {
    // CheckObjects bounded the object ids by ObjectCount().
    const uint32_t object = d.vertex_objects_size() > 0 ? d.vertex_objects(i) : 0;
    const Rgb p = RgbAt(d.vertex_positions(), i);
    const Bounds3& b = vertexBounds_[object];
    if (p.x < b.min.x || p.y < b.min.y || p.z < b.min.z || p.x > b.max.x || p.y > b.max.y || p.z > b.max.z)
      return Fail(fmt::format("delta {}: vertex {} at ({}, {}, {}) lies outside {} ({}, {}, {})-({}, {}, {})",
                              d.sequence(), d.vertex_ids(i), p.x, p.y, p.z,
                              object == 0 ? std::string("the scene's bounds")
                                          : fmt::format("object {}'s bounds", object),
                              b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z));
  }
  return Status::Ok();
}

Status MeshStore::CheckObjects(const wire::Delta& d) const {
  const int nv = d.vertex_ids_size();
  // A static scene's deltas may leave vertex_objects out; a scene with
  // movable objects must say, for every new vertex, which space it is in.
  if (ObjectCount() > 0 ? d.vertex_objects_size() != nv : d.vertex_objects_size() != 0 && d.vertex_objects_size() != nv)
    return Fail(fmt::format("delta {}: {} vertex objects for {} new vertices (one each, in a scene with {} movable "
                            "objects)",
                            d.sequence(), d.vertex_objects_size(), nv, ObjectCount()));
  for (int i = 0; i < d.vertex_objects_size(); ++i)
    if (d.vertex_objects(i) > ObjectCount())
      return Fail(fmt::format("delta {}: vertex {} belongs to object {}, but the scene has {} movable objects",
                              d.sequence(), d.vertex_ids(i), d.vertex_objects(i), ObjectCount()));
  if (d.kind() != wire::DELTA_KIND_MOVED) {
    if (d.moved_objects_size() > 0 || d.moved_object_transforms_size() > 0)
      return Fail(fmt::format("delta {}: a {} delta carries moved objects (only MOVED does)", d.sequence(),
                              wire::DeltaKind_Name(d.kind())));
    return Status::Ok();
  }
  if (d.updated_vertex_ids_size() > 0)
    return Fail(fmt::format("delta {}: a MOVED delta carries radiance updates (RESHADED does)", d.sequence()));
  if (d.moved_object_transforms_size() != 12 * d.moved_objects_size())
    return Fail(fmt::format("delta {}: {} moved objects but {} transform values (12 each)", d.sequence(),
                            d.moved_objects_size(), d.moved_object_transforms_size()));
  if (d.scene_epoch() < sceneEpoch_)
    return Fail(fmt::format("delta {}: MOVED to scene epoch {}, older than the epoch {} already shown", d.sequence(),
                            d.scene_epoch(), sceneEpoch_));
  for (int i = 0; i < d.moved_objects_size(); ++i) {
    const uint32_t id = d.moved_objects(i);
    if (id == 0 || id > ObjectCount())
      return Fail(fmt::format("delta {}: moves object {}, but the scene's movable objects are 1..{}", d.sequence(), id,
                              ObjectCount()));
    auto t = RigidTransform::FromRowMajor(std::span<const float>(d.moved_object_transforms().data() + 12 * i, 12));
    if (!t) return Fail(fmt::format("delta {}: object {}'s new transform: {}", d.sequence(), id, t.error().message));
  }
  return Status::Ok();
}

void MeshStore::ApplyMoves(const wire::Delta& d) {
  // CheckObjects accepted every transform.
  for (int i = 0; i < d.moved_objects_size(); ++i) {
    const uint32_t id = d.moved_objects(i);
    objectToWorld_[id - 1] =
        *RigidTransform::FromRowMajor(std::span<const float>(d.moved_object_transforms().data() + 12 * i, 12));
    WriteObjectSlot(id);
  }
  sceneEpoch_ = d.scene_epoch();
  ++movesApplied_;
}

Status MeshStore::Apply(const wire::Delta& d) {
  if (auto ok = CheckShape(d); !ok) return ok;
  sequence_ = d.sequence();
  if (d.kind() == wire::DELTA_KIND_MOVED) ApplyMoves(d);

  for (uint64_t id : d.removed_triangles())
    if (auto ok = RemoveTriangle(id); !ok) return Fail(fmt::format("delta {}: {}", d.sequence(), ok.error().message));
  for (int i = 0; i < d.vertex_ids_size(); ++i)
    if (auto ok = AddVertex(d, i); !ok) return Fail(fmt::format("delta {}: {}", d.sequence(), ok.error().message));
  int uvIndex = 0;
  for (int i = 0; i < d.triangle_ids_size(); ++i) {
    const bool textured = materialTextures_[d.triangle_materials(i)] >= 0;
    if (auto ok = AddTriangle(d, i, textured ? uvIndex++ : -1); !ok)
      return Fail(fmt::format("delta {}: {}", d.sequence(), ok.error().message));
  }
  // The SMA never sends a vertex no triangle uses: a client would leak it.
  for (uint64_t id : d.vertex_ids())
    if (vertices_.at(id).refs == 0)
      return Fail(fmt::format("delta {}: vertex {} sent but used by no triangle", d.sequence(), id));
  for (int i = 0; i < d.updated_vertex_ids_size(); ++i)
    if (auto ok = UpdateVertex(d, i); !ok) return Fail(fmt::format("delta {}: {}", d.sequence(), ok.error().message));

  // A MOVED before any view (view id 0) says nothing of a view's progress.
  if (d.kind() == wire::DELTA_KIND_MOVED && d.view_id() == 0) return Status::Ok();
  viewId_ = d.view_id();
  pendingSamples_ = d.pending_samples();
  converged_ = d.converged();
  refining_ = d.refining();
  progress_.renderersConnected =
      d.has_renderers_connected() ? std::optional<uint32_t>(d.renderers_connected()) : std::nullopt;
  progress_.stage1Total = d.stage1_samples_total();
  progress_.stage1Done = std::min(d.stage1_samples_done(), d.stage1_samples_total());
  progress_.refinementTotal = d.refinement_samples_total();
  progress_.refinementDone = std::min(d.refinement_samples_done(), d.refinement_samples_total());
  trianglesAdded_ += uint64_t(d.triangle_ids_size());
  return Status::Ok();
}

Status MeshStore::RemoveTriangle(uint64_t id) {
  auto it = triangles_.find(id);
  if (it == triangles_.end()) return Fail(fmt::format("removal of triangle {}, which is not held", id));
  const TriangleRecord record = it->second;
  triangles_.erase(it);
  TriangleGroup& group = groups_[record.group];
  GpuTriangle& slot = group.slots[record.slot];
  for (const GpuCorner& corner : slot.corners) {
    const uint64_t vertexId = vertexSlotIds_[corner.vertexSlot];
    VertexRecord& vertex = vertices_.at(vertexId);
    if (--vertex.refs == 0) ReleaseVertex(vertexId, vertex.slot);
  }
  slot = GpuTriangle{};  // an empty slot draws nothing
  group.allocator.Release(record.slot);
  group.dirty.Mark(record.slot);
  return Status::Ok();
}

void MeshStore::ReleaseVertex(uint64_t id, uint32_t slot) {
  UncountLuminance(SlotLuminance(vertexSlots_[slot]));
  // Zeroed so that a luminance rescan over all slots skips it; no triangle
  // refers to it, so the GPU copy need not change.
  vertexSlots_[slot] = GpuVertex{};
  vertexAllocator_.Release(slot);
  vertices_.erase(id);
}

Status MeshStore::AddVertex(const wire::Delta& d, int i) {
  const uint64_t id = d.vertex_ids(i);
  if (vertices_.contains(id)) return Fail(fmt::format("vertex {} sent while already held", id));
  const uint32_t slot = vertexAllocator_.Allocate();
  if (slot >= vertexSlots_.size()) {
    vertexSlots_.resize(size_t(slot) + 1);
    vertexSlotIds_.resize(size_t(slot) + 1);
  }
  GpuVertex& v = vertexSlots_[slot];
  const Rgb position = RgbAt(d.vertex_positions(), i);
  const Rgb radiance = RgbAt(d.vertex_radiance(), i);
  const Rgb irradiance = RgbAt(d.vertex_irradiance(), i);
  const uint32_t object = d.vertex_objects_size() > 0 ? d.vertex_objects(i) : 0;
  v = GpuVertex{{position.x, position.y, position.z, float(object)},
                {radiance.r, radiance.g, radiance.b, 0.0f},
                {irradiance.r, irradiance.g, irradiance.b, 0.0f}};
  vertexSlotIds_[slot] = id;
  vertices_.emplace(id, VertexRecord{slot, 0});
  dirtyVertices_.Mark(slot);
  CountLuminance(Luminance(radiance));
  return Status::Ok();
}

Status MeshStore::UpdateVertex(const wire::Delta& d, int i) {
  const uint64_t id = d.updated_vertex_ids(i);
  auto it = vertices_.find(id);
  if (it == vertices_.end()) return Fail(fmt::format("update of vertex {}, which is not held", id));
  GpuVertex& v = vertexSlots_[it->second.slot];
  UncountLuminance(SlotLuminance(v));
  const Rgb radiance = RgbAt(d.updated_vertex_radiance(), i);
  const Rgb irradiance = RgbAt(d.updated_vertex_irradiance(), i);
  for (int c = 0; c < 3; ++c) {
    v.radiance[c] = radiance[c];
    v.irradiance[c] = irradiance[c];
  }
  dirtyVertices_.Mark(it->second.slot);
  CountLuminance(Luminance(radiance));
  return Status::Ok();
}

Status MeshStore::AddTriangle(const wire::Delta& d, int i, int uvIndex) {
  const uint64_t id = d.triangle_ids(i);
  if (triangles_.contains(id)) return Fail(fmt::format("triangle {} added while already held", id));
  VertexRecord* corners[3];
  for (int c = 0; c < 3; ++c) {
    const uint64_t vertexId = d.triangle_vertices(3 * i + c);
    auto it = vertices_.find(vertexId);
    if (it == vertices_.end())
      return Fail(fmt::format("triangle {} uses vertex {}, which is neither held nor sent", id, vertexId));
    corners[c] = &it->second;
  }
  // An object's triangles use only its own vertices (their positions are in
  // its space); a triangle across two spaces would be torn apart by a move.
  const uint32_t object = SlotObject(vertexSlots_[corners[0]->slot]);
  if (SlotObject(vertexSlots_[corners[1]->slot]) != object || SlotObject(vertexSlots_[corners[2]->slot]) != object)
    return Fail(fmt::format("triangle {} joins vertices of different objects ({}, {}, {})", id, object,
                            SlotObject(vertexSlots_[corners[1]->slot]), SlotObject(vertexSlots_[corners[2]->slot])));
  const uint32_t material = d.triangle_materials(i);
  const uint32_t groupIndex = uint32_t(materialTextures_[material] + 1);
  TriangleGroup& group = groups_[groupIndex];
  const uint32_t slot = group.allocator.Allocate();
  if (slot >= group.slots.size()) group.slots.resize(size_t(slot) + 1);
  GpuTriangle& t = group.slots[slot];
  for (int c = 0; c < 3; ++c) {
    ++corners[c]->refs;
    GpuCorner& corner = t.corners[c];
    corner.vertexSlot = corners[c]->slot;
    corner.material = material;
    corner.uv[0] = uvIndex >= 0 ? d.triangle_uvs(6 * uvIndex + 2 * c) : 0.0f;
    corner.uv[1] = uvIndex >= 0 ? d.triangle_uvs(6 * uvIndex + 2 * c + 1) : 0.0f;
  }
  triangles_.emplace(id, TriangleRecord{groupIndex, slot});
  group.dirty.Mark(slot);
  return Status::Ok();
}

void MeshStore::CountLuminance(float luminance) {
  if (!(luminance > 0.0f)) return;
  ++luminanceCount_;
  logLuminanceSum_ += std::log(double(luminance));
  if (!maxStale_) maxLuminance_ = std::max(maxLuminance_, luminance);
}

void MeshStore::UncountLuminance(float luminance) {
  if (!(luminance > 0.0f)) return;
  if (--luminanceCount_ == 0) {
    logLuminanceSum_ = 0.0;  // no rounding residue once nothing is left
    maxLuminance_ = 0.0f;
    maxStale_ = false;
    return;
  }
  logLuminanceSum_ -= std::log(double(luminance));
  if (luminance >= maxLuminance_) maxStale_ = true;
}

ViewLuminance MeshStore::HeldLuminance() {
  if (luminanceCount_ == 0) return ViewLuminance{};
  if (maxStale_) {
    maxLuminance_ = 0.0f;
    for (const GpuVertex& v : VertexSlots()) maxLuminance_ = std::max(maxLuminance_, SlotLuminance(v));
    maxStale_ = false;
  }
  return ViewLuminance{maxLuminance_, float(std::exp(logLuminanceSum_ / double(luminanceCount_)))};
}

}  // namespace penumbra::client
