#pragma once
// Reference images: every pixel path-traced with the same Shader that shades
// the SMA's vertex samples -- the ground truth that walkthrough images are
// compared against, and a way to look at a scene.
//
// Pixel (x, y) casts one ray through its centre from a pinhole camera
// (camera.h conventions). Where the ray hits a surface, the pixel is L_out
// at the hit, shaded on the side facing the camera with the vertex normals
// interpolated across the triangle (as the SMA's samples are), under sample
// id y * width + x. Where it escapes, the pixel is the sky's radiance in
// that direction (black without a sky). The sun's disc is not drawn.

#include "penumbra/common/camera.h"
#include "penumbra/common/image_io.h"
#include "penumbra/renderer/shading.h"

namespace penumbra {

class RayScene;

/// Renders `view` with `threads` worker threads (at least one), each pixel
/// with the shader's paths per sample. Returns linear radiance, row 0 at the
/// top; adds the work done to `counters` when it is not null. The view must
/// have passed ValidateCameraView. Deterministic: the image does not depend
/// on the thread count. Blocks until done; call from any one thread.
Image RenderReference(const Shader& shader, const RayScene& rays, const CameraView& view, int threads,
                      ShadeCounters* counters = nullptr);

}  // namespace penumbra
