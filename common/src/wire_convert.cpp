#include "penumbra/common/wire_convert.h"

#include <array>
#include <cmath>
#include <span>

#include <fmt/format.h>

#include "penumbra/common/logging.h"

namespace penumbra {

namespace {

bool IsFinite(const wire::Vec3& v) { return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z()); }

bool IsNonNegative(const wire::Vec3& c) { return IsFinite(c) && c.x() >= 0.0f && c.y() >= 0.0f && c.z() >= 0.0f; }

}  // namespace

void ToWire(const Vec3& v, wire::Vec3* out) {
  out->set_x(v.x);
  out->set_y(v.y);
  out->set_z(v.z);
}

void ToWire(const DragoParams& params, wire::ToneMapping* out) {
  out->set_bias(params.bias);
  out->set_exposure(params.exposure);
  out->set_max_display_luminance(params.maxDisplayLuminance);
}

Expected<DragoParams> ToneMappingFromWire(const wire::ToneMapping& tm) {
  if (!(tm.bias() > 0.0f && tm.bias() < 1.0f) || !(tm.exposure() > 0.0f) || !std::isfinite(tm.exposure()) ||
      !(tm.max_display_luminance() > 0.0f) || !std::isfinite(tm.max_display_luminance()))
    return Fail(fmt::format("tone mapping bias {} (must be in (0,1)), exposure {} and display luminance {} "
                            "(must be positive)",
                            tm.bias(), tm.exposure(), tm.max_display_luminance()));
  DragoParams params;
  params.bias = tm.bias();
  params.exposure = tm.exposure();
  params.maxDisplayLuminance = tm.max_display_luminance();
  return params;
}

void ToWire(const ClientScene& scene, wire::SceneInfo* info) {
  info->set_name(scene.name);
  ToWire(scene.bounds.min, info->mutable_bounds_min());
  ToWire(scene.bounds.max, info->mutable_bounds_max());
  for (const CameraPreset& c : scene.cameras) {
    auto* p = info->add_cameras();
    p->set_name(c.name);
    ToWire(c.pose.eye, p->mutable_eye());
    ToWire(c.pose.target, p->mutable_target());
    ToWire(c.pose.up, p->mutable_up());
    p->set_fov_y_deg(c.fovYDeg);
  }
  for (const ClientMaterial& m : scene.materials) {
    auto* mi = info->add_materials();
    ToWire(m.albedo, mi->mutable_albedo());
    ToWire(m.emission, mi->mutable_emission());
    mi->set_texture(m.texture);
  }
  ToWire(scene.toneMapping, info->mutable_tone_mapping());
  info->set_texture_count(scene.textureCount);
  if (scene.sky) {
    auto* sky = info->mutable_sky();
    ToWire(scene.sky->up, sky->mutable_up());
    ToWire(scene.sky->zenith, sky->mutable_zenith());
    ToWire(scene.sky->horizon, sky->mutable_horizon());
    ToWire(scene.sky->ground, sky->mutable_ground());
  }
  for (size_t i = 0; i < scene.objects.size(); ++i) {
    const ClientObject& o = scene.objects[i];
    auto* oi = info->add_objects();
    oi->set_object(uint32_t(i + 1));
    oi->set_name(o.name);
    ToWire(o.objectBounds.min, oi->mutable_bounds_min());
    ToWire(o.objectBounds.max, oi->mutable_bounds_max());
    ToWire(o.objectToWorld, oi->mutable_object_to_world());
    oi->set_animated(o.animated);
  }
  info->set_scene_epoch(scene.sceneEpoch);
}

void ToWire(const RigidTransform& t, google::protobuf::RepeatedField<float>* out) {
  const std::array<float, 12> m = t.ToRowMajor();
  out->Clear();
  out->Add(m.begin(), m.end());
}

Expected<RigidTransform> RigidTransformFromWire(const google::protobuf::RepeatedField<float>& m12) {
  return RigidTransform::FromRowMajor(std::span<const float>(m12.data(), size_t(m12.size())));
}

Expected<ClientScene> ClientSceneFromWire(const wire::SceneInfo& info, uint64_t identity) {
  if (!IsFinite(info.bounds_min()) || !IsFinite(info.bounds_max())) return Fail("scene_info: bounds are not finite");
  // Every count from the wire bounds what it allocates: a client keeps a
  // triangle group per texture. Cameras and materials are copied from the
  // message, so the frame size limit bounds them.
  if (info.texture_count() > kMaxSceneTextures)
    return Fail(fmt::format("scene_info: {} textures; at most {} are supported", info.texture_count(),
                            kMaxSceneTextures));
  ClientScene scene;
  scene.name = info.name();
  scene.identity = identity;
  scene.bounds.Extend(FromWire(info.bounds_min()));
  scene.bounds.Extend(FromWire(info.bounds_max()));
  scene.cameras.reserve(size_t(info.cameras_size()));
  for (int i = 0; i < info.cameras_size(); ++i) {
    const auto& c = info.cameras(i);
    if (!IsFinite(c.eye()) || !IsFinite(c.target()) || !IsFinite(c.up()) || !std::isfinite(c.fov_y_deg()))
      return Fail(fmt::format("scene_info: camera {} ('{}') is not finite", i, c.name()));
    scene.cameras.push_back(
        CameraPreset{c.name(), CameraPose{FromWire(c.eye()), FromWire(c.target()), FromWire(c.up())}, c.fov_y_deg()});
  }
  scene.textureCount = info.texture_count();
  scene.materials.reserve(size_t(info.materials_size()));
  for (int i = 0; i < info.materials_size(); ++i) {
    const auto& m = info.materials(i);
    if (m.texture() < -1 || m.texture() >= int64_t(info.texture_count()))
      return Fail(fmt::format("scene_info: material {} uses texture {} of {}", i, m.texture(), info.texture_count()));
    if (!IsFinite(m.albedo()) || !IsFinite(m.emission()))
      return Fail(fmt::format("scene_info: material {} has a colour that is not finite", i));
    scene.materials.push_back(ClientMaterial{FromWire(m.albedo()), FromWire(m.emission()), m.texture()});
  }
  if (info.has_sky()) {
    const auto& sky = info.sky();
    const float upLength =
        std::sqrt(sky.up().x() * sky.up().x() + sky.up().y() * sky.up().y() + sky.up().z() * sky.up().z());
    if (!IsFinite(sky.up()) || !(std::abs(upLength - 1.0f) < 1e-3f))
      return Fail(fmt::format("scene_info: sky up ({}, {}, {}) is not a unit vector", sky.up().x(), sky.up().y(),
                              sky.up().z()));
    if (!IsNonNegative(sky.zenith()) || !IsNonNegative(sky.horizon()) || !IsNonNegative(sky.ground()))
      return Fail("scene_info: sky radiance must be finite and non-negative");
    scene.sky = SkyLight{FromWire(sky.up()), FromWire(sky.zenith()), FromWire(sky.horizon()), FromWire(sky.ground())};
  }
  auto toneMapping = ToneMappingFromWire(info.tone_mapping());
  if (!toneMapping) return Fail("scene_info: " + toneMapping.error().message);
  scene.toneMapping = *toneMapping;
  if (uint32_t(info.objects_size()) > kMaxClientSceneObjects)
    return Fail(fmt::format("scene_info: {} movable objects; at most {} are supported", info.objects_size(),
                            kMaxClientSceneObjects));
  scene.objects.reserve(size_t(info.objects_size()));
  for (int i = 0; i < info.objects_size(); ++i) {
    const auto& o = info.objects(i);
    // Ids are positions: Delta.vertex_objects and MoveObject index by them.
    if (o.object() != uint32_t(i + 1))
      return Fail(fmt::format("scene_info: movable object {} ('{}') has id {}; ids are 1, 2, ... in order", i,
                              Printable(o.name(), 64), o.object()));
    if (!IsFinite(o.bounds_min()) || !IsFinite(o.bounds_max()))
      return Fail(fmt::format("scene_info: movable object {} ('{}') has bounds that are not finite", o.object(),
                              Printable(o.name(), 64)));
    const Vec3 lo = FromWire(o.bounds_min()), hi = FromWire(o.bounds_max());
    if (lo.x > hi.x || lo.y > hi.y || lo.z > hi.z)
      return Fail(fmt::format("scene_info: movable object {} ('{}') has bounds with min above max", o.object(),
                              Printable(o.name(), 64)));
    auto transform = RigidTransformFromWire(o.object_to_world());
    if (!transform)
      return Fail(fmt::format("scene_info: movable object {} ('{}'): {}", o.object(), Printable(o.name(), 64),
                              transform.error().message));
    Bounds3 bounds;
    bounds.Extend(lo);
    bounds.Extend(hi);
    scene.objects.push_back(ClientObject{o.name(), bounds, *transform, o.animated()});
  }
  scene.sceneEpoch = info.scene_epoch();
  return scene;
}

void ToWire(const RefinementRequest& r, wire::SessionOptions* out) {
  out->set_criterion(r.criterion ? std::string(CriterionName(*r.criterion)) : std::string());
  if (r.sReq) out->set_s_req(*r.sReq);
  if (r.batch) out->set_batch(*r.batch);
  if (r.minPixels) out->set_min_pixels(*r.minPixels);
  if (r.largeFraction) out->set_large_fraction(*r.largeFraction);
  if (r.aspectThreshold) out->set_aspect_threshold(*r.aspectThreshold);
  if (r.maxDepth) out->set_max_depth(*r.maxDepth);
  if (r.pixelFraction) out->set_pixel_fraction(*r.pixelFraction);
  if (r.noiseZ) out->set_noise_z(*r.noiseZ);
}

Expected<RefinementRequest> RefinementRequestFromWire(const wire::SessionOptions& o) {
  RefinementRequest r;
  if (!o.criterion().empty()) {
    auto c = ParseCriterion(o.criterion());
    if (!c) return c.error();
    r.criterion = *c;
  }
  if (o.has_s_req()) r.sReq = o.s_req();
  if (o.has_batch()) r.batch = o.batch();
  if (o.has_min_pixels()) r.minPixels = o.min_pixels();
  if (o.has_large_fraction()) r.largeFraction = o.large_fraction();
  if (o.has_aspect_threshold()) r.aspectThreshold = o.aspect_threshold();
  if (o.has_max_depth()) r.maxDepth = o.max_depth();
  if (o.has_pixel_fraction()) r.pixelFraction = o.pixel_fraction();
  if (o.has_noise_z()) r.noiseZ = o.noise_z();
  return r;
}

Expected<RefinementParams> ApplySessionOptions(const RefinementParams& current, const wire::SessionOptions& options) {
  auto request = RefinementRequestFromWire(options);
  if (!request) return request.error();
  return request->AppliedTo(current);
}

}  // namespace penumbra
