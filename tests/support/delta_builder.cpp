#include "support/delta_builder.h"

namespace penumbra::testing {

DeltaBuilder::DeltaBuilder(uint64_t sequence, uint64_t viewId, wire::DeltaKind kind) {
  delta_.set_sequence(sequence);
  delta_.set_view_id(viewId);
  delta_.set_kind(kind);
}

DeltaBuilder& DeltaBuilder::Remove(uint64_t triangle) {
  delta_.add_removed_triangles(triangle);
  return *this;
}

DeltaBuilder& DeltaBuilder::Vertex(uint64_t id, const Vec3& position, const Rgb& radiance, const Rgb& irradiance) {
  delta_.add_vertex_ids(id);
  for (int c = 0; c < 3; ++c) {
    delta_.add_vertex_positions(position[c]);
    delta_.add_vertex_radiance(radiance[c]);
    delta_.add_vertex_irradiance(irradiance[c]);
  }
  return *this;
}

DeltaBuilder& DeltaBuilder::Update(uint64_t id, const Rgb& radiance, const Rgb& irradiance) {
  delta_.add_updated_vertex_ids(id);
  for (int c = 0; c < 3; ++c) {
    delta_.add_updated_vertex_radiance(radiance[c]);
    delta_.add_updated_vertex_irradiance(irradiance[c]);
  }
  return *this;
}

DeltaBuilder& DeltaBuilder::Triangle(uint64_t id, const std::array<uint64_t, 3>& vertices, uint32_t material,
                                     const std::optional<std::array<float, 6>>& uvs) {
  delta_.add_triangle_ids(id);
  for (uint64_t v : vertices) delta_.add_triangle_vertices(v);
  delta_.add_triangle_materials(material);
  if (uvs)
    for (float f : *uvs) delta_.add_triangle_uvs(f);
  return *this;
}

DeltaBuilder& DeltaBuilder::Pending(uint32_t samples) {
  delta_.set_pending_samples(samples);
  return *this;
}

DeltaBuilder& DeltaBuilder::Converged(bool converged) {
  delta_.set_converged(converged);
  return *this;
}

wire::Envelope DeltaBuilder::Envelope() const {
  wire::Envelope e;
  *e.mutable_delta() = delta_;
  return e;
}

}  // namespace penumbra::testing
