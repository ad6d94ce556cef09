#pragma once
// The OpenGL camera matrices for a CameraView, in common/camera.h's
// conventions: the rasteriser's pixel centres see exactly the rays
// PinholeCamera::DirectionThrough gives, so the client draws what the SMA's
// visibility saw. Pure math, no GL.

#include <glm/mat4x4.hpp>

#include "penumbra/common/camera.h"
#include "penumbra/common/math.h"

namespace penumbra::client {

/// World space to clip space (OpenGL: depth in [-1, 1]). Near and far
/// enclose `sceneBounds` seen from the eye, so nothing of the scene is clipped
/// by depth; near is at least 1e-4 of far, for depth precision.
glm::mat4 WorldToClip(const CameraView& view, const Bounds3& sceneBounds);

}  // namespace penumbra::client
