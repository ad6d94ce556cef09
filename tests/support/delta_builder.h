#pragma once
// Builds client-protocol Delta messages for tests that play the SMA (fake
// SMAs, client unit tests), valid or deliberately broken.

#include <array>
#include <cstdint>
#include <memory>
#include <optional>

#include "penumbra/common/math.h"
#include "penumbra/wire.pb.h"

namespace penumbra::testing {

class DeltaBuilder {
 public:
  DeltaBuilder(uint64_t sequence, uint64_t viewId, wire::DeltaKind kind = wire::DELTA_KIND_CACHED);

  DeltaBuilder& Remove(uint64_t triangle);
  DeltaBuilder& Vertex(uint64_t id, const Vec3& position, const Rgb& radiance, const Rgb& irradiance = Rgb(0.0f));
  /// Adds a triangle; `uvs` (u0 v0 u1 v1 u2 v2) only for textured materials.
  DeltaBuilder& Triangle(uint64_t id, const std::array<uint64_t, 3>& vertices, uint32_t material = 0,
                         const std::optional<std::array<float, 6>>& uvs = std::nullopt);
  /// A better estimate of a vertex the client holds (IMPROVED deltas).
  DeltaBuilder& Update(uint64_t id, const Rgb& radiance, const Rgb& irradiance = Rgb(0.0f));
  DeltaBuilder& Pending(uint32_t samples);
  DeltaBuilder& Converged(bool converged = true);

  const wire::Delta& Delta() const { return delta_; }
  /// A copy, as a client::DeltaReceived holds it.
  std::shared_ptr<const wire::Delta> Shared() const { return std::make_shared<const wire::Delta>(delta_); }
  /// Direct access, to break a rule the builder otherwise keeps.
  wire::Delta& Mutable() { return delta_; }
  wire::Envelope Envelope() const;

 private:
  wire::Delta delta_;
};

}  // namespace penumbra::testing
