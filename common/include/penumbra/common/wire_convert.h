#pragma once
// The one layer between wire messages and the domain values the tiers work
// with: SceneInfo <-> ClientScene, ToneMapping <-> DragoParams,
// SessionOptions <-> RefinementRequest. Conversions from the wire validate
// once, here, and fail with a message naming the field: every count bounds
// what it allocates, every number the far side relies on is finite and in
// range. Plain code, no sockets; unit-tested in common/tests/wire_convert_test.cpp
// and fuzzed through the client and SMA targets (tests/fuzz).
//
// Threads: pure functions; any thread.

#include <cstdint>

#include "penumbra/common/client_scene.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/common/refinement_params.h"
#include "penumbra/common/rigid_transform.h"
#include "penumbra/common/tonemap.h"
#include "penumbra/wire.pb.h"

namespace penumbra {

void ToWire(const Vec3& v, wire::Vec3* out);
inline Vec3 FromWire(const wire::Vec3& v) { return Vec3(v.x(), v.y(), v.z()); }

void ToWire(const DragoParams& params, wire::ToneMapping* out);
/// Refused unless bias is in (0, 1) and exposure and display luminance are
/// finite and positive.
Expected<DragoParams> ToneMappingFromWire(const wire::ToneMapping& tm);

/// A transform as 12 row-major floats (MovableObjectInfo.object_to_world,
/// MoveObject, Delta.moved_object_transforms, ShadeRequest.object_transforms).
void ToWire(const RigidTransform& t, google::protobuf::RepeatedField<float>* out);
/// RigidTransform::FromRowMajor of the field: refused unless it has 12
/// finite numbers forming a rigid transform.
Expected<RigidTransform> RigidTransformFromWire(const google::protobuf::RepeatedField<float>& m12);

/// Everything but `identity` (the Welcome carries it).
void ToWire(const ClientScene& scene, wire::SceneInfo* out);
/// The SceneInfo as a ClientScene with `identity` (the Welcome's
/// scene_hash), or why it cannot be drawn: bounds, presets or colours that
/// are not finite; more than kMaxSceneTextures textures; a material naming
/// a texture that does not exist; a sky whose up is not a unit vector or
/// whose radiance is negative; tone mapping out of range; more than
/// kMaxClientSceneObjects movable objects, an object whose id is not its
/// position (1, 2, ...), whose bounds are not finite or whose transform is
/// not rigid (RigidTransform::FromRowMajor). Messages start
/// with "scene_info: ". What is allocated is bounded by the textures'
/// count and the message's own size (cameras, materials).
Expected<ClientScene> ClientSceneFromWire(const wire::SceneInfo& info, uint64_t identity);

/// Only the fields that are set (an unset criterion is "": keep it).
void ToWire(const RefinementRequest& request, wire::SessionOptions* out);
/// The request, or why not (an unknown criterion name). Ranges are checked
/// when it is applied (RefinementRequest::AppliedTo).
Expected<RefinementRequest> RefinementRequestFromWire(const wire::SessionOptions& options);
/// `current` with the SessionOptions' fields that are set replaced, or why
/// they are refused (an unknown criterion, a value out of range). Any thread.
Expected<RefinementParams> ApplySessionOptions(const RefinementParams& current, const wire::SessionOptions& options);

}  // namespace penumbra
