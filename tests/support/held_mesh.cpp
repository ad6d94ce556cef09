#include "support/held_mesh.h"

#include <cmath>

#include <fmt/format.h>

namespace penumbra::testing {

std::set<uint64_t> HeldMesh::TriangleIds() const {
  std::set<uint64_t> ids;
  for (const auto& [id, v] : triangles_) ids.insert(id);
  return ids;
}

Status HeldMesh::Apply(const wire::Delta& d) {
  if (d.sequence() != sequence_ + 1)
    return Fail(fmt::format("delta sequence {} after {}", d.sequence(), sequence_));
  const int nv = d.vertex_ids_size();
  const int nt = d.triangle_ids_size();
  if (d.vertex_positions_size() != 3 * nv || d.vertex_radiance_size() != 3 * nv || d.vertex_irradiance_size() != 3 * nv)
    return Fail("vertex arrays disagree in length");
  if (d.triangle_vertices_size() != 3 * nt || d.triangle_materials_size() != nt)
    return Fail("triangle arrays disagree in length");
  if (d.triangle_uvs_size() % 6 != 0 || d.triangle_uvs_size() / 6 > nt) return Fail("triangle_uvs length");
  if (d.vertex_objects_size() != 0 && d.vertex_objects_size() != nv) return Fail("vertex_objects length");
  if (d.scene_epoch() < sceneEpoch_)
    return Fail(fmt::format("delta at scene epoch {} after epoch {}", d.scene_epoch(), sceneEpoch_));
  if (d.kind() == wire::DELTA_KIND_MOVED &&
      (nv > 0 || nt > 0 || d.removed_triangles_size() > 0 || d.updated_vertex_ids_size() > 0 ||
       d.moved_object_transforms_size() != 12 * d.moved_objects_size()))
    return Fail("a MOVED delta carries triangles or vertices, or its transforms disagree in length");
  if (d.kind() == wire::DELTA_KIND_RESHADED && (nv > 0 || nt > 0 || d.removed_triangles_size() > 0))
    return Fail("a RESHADED delta carries triangles or new vertices");
  sequence_ = d.sequence();
  sceneEpoch_ = d.scene_epoch();

  for (uint64_t id : d.removed_triangles()) {
    auto it = triangles_.find(id);
    if (it == triangles_.end()) return Fail(fmt::format("removal of triangle {} not held", id));
    for (uint64_t v : it->second) {
      auto vit = vertices_.find(v);
      if (vit == vertices_.end()) return Fail("held triangle uses a vertex not held");
      if (--vit->second.refs == 0) vertices_.erase(vit);
    }
    triangles_.erase(it);
    ++removed[d.kind()];
  }
  for (int i = 0; i < nv; ++i) {
    const uint64_t id = d.vertex_ids(i);
    if (vertices_.contains(id)) return Fail(fmt::format("vertex {} sent while held", id));
    Vertex v;
    v.position = Vec3(d.vertex_positions(3 * i), d.vertex_positions(3 * i + 1), d.vertex_positions(3 * i + 2));
    v.radiance = Rgb(d.vertex_radiance(3 * i), d.vertex_radiance(3 * i + 1), d.vertex_radiance(3 * i + 2));
    v.irradiance = Rgb(d.vertex_irradiance(3 * i), d.vertex_irradiance(3 * i + 1), d.vertex_irradiance(3 * i + 2));
    v.object = d.vertex_objects_size() == nv ? d.vertex_objects(i) : 0;
    if (!IsFinite(v.position) || !IsFinite(v.radiance) || !IsFinite(v.irradiance))
      return Fail(fmt::format("vertex {} is not finite", id));
    vertices_.emplace(id, v);
  }
  for (int i = 0; i < nt; ++i) {
    const uint64_t id = d.triangle_ids(i);
    if (triangles_.contains(id)) return Fail(fmt::format("triangle {} added while held", id));
    std::array<uint64_t, 3> corners{};
    for (int c = 0; c < 3; ++c) {
      corners[size_t(c)] = d.triangle_vertices(3 * i + c);
      auto vit = vertices_.find(corners[size_t(c)]);
      if (vit == vertices_.end())
        return Fail(fmt::format("triangle {} uses vertex {} not held", id, corners[size_t(c)]));
      ++vit->second.refs;
    }
    triangles_.emplace(id, corners);
    ++added[d.kind()];
  }
  // A vertex sent but used by no triangle would leak on the client.
  for (const auto& [id, v] : vertices_)
    if (v.refs == 0) return Fail(fmt::format("vertex {} held by no triangle", id));
  const int nu = d.updated_vertex_ids_size();
  if (d.updated_vertex_radiance_size() != 3 * nu || d.updated_vertex_irradiance_size() != 3 * nu)
    return Fail("updated vertex arrays disagree in length");
  if (d.kind() == wire::DELTA_KIND_IMPROVED && (nv > 0 || nt > 0 || d.removed_triangles_size() > 0))
    return Fail("an IMPROVED delta carries triangles or new vertices");
  for (int i = 0; i < nu; ++i) {
    auto it = vertices_.find(d.updated_vertex_ids(i));
    if (it == vertices_.end()) return Fail(fmt::format("update of vertex {} not held", d.updated_vertex_ids(i)));
    const Rgb radiance(d.updated_vertex_radiance(3 * i), d.updated_vertex_radiance(3 * i + 1),
                       d.updated_vertex_radiance(3 * i + 2));
    const Rgb irradiance(d.updated_vertex_irradiance(3 * i), d.updated_vertex_irradiance(3 * i + 1),
                         d.updated_vertex_irradiance(3 * i + 2));
    if (!IsFinite(radiance) || !IsFinite(irradiance)) return Fail("an updated vertex is not finite");
    it->second.radiance = radiance;
    it->second.irradiance = irradiance;
    ++updates;
  }
  viewId_ = d.view_id();
  converged_ = d.converged();
  pending_ = d.pending_samples();
  return Status::Ok();
}

size_t HeldMesh::CountTVertices(uint64_t firstId) const {
  size_t count = 0;
  for (const auto& [id, corners] : triangles_) {
    for (int k = 0; k < 3; ++k) {
      const Vec3 a = vertices_.at(corners[size_t(k)]).position;
      const Vec3 b = vertices_.at(corners[size_t((k + 1) % 3)]).position;
      const Vec3 ab = b - a;
      const float len2 = glm::dot(ab, ab);
      if (!(len2 > 0.0f)) continue;
      for (auto it = vertices_.lower_bound(firstId); it != vertices_.end(); ++it) {
        const Vertex& v = it->second;
        const float t = glm::dot(v.position - a, ab) / len2;
        if (t <= 1e-4f || t >= 1.0f - 1e-4f) continue;
        if (glm::length(v.position - (a + t * ab)) < 1e-5f * std::sqrt(len2)) ++count;
      }
    }
  }
  return count;
}

}  // namespace penumbra::testing
