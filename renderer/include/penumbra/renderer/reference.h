#pragma once
// Reference images: every pixel path-traced with the same Shader that shades
// the SMA's vertex samples -- the ground truth that walkthrough images are
// compared against, and a way to look at a scene.
//
// A pixel is the mean radiance over its area (PixelFilter::kBox, the
// default): each of its paths starts with its own camera ray through a
// uniformly random point of the pixel, so edges and texture detail finer than
// a pixel are averaged as a camera's sensor averages them -- the ground truth
// a client's filtered textures approximate. With PixelFilter::kCentre one
// ray goes through the pixel's centre and all the paths start from its hit
// (camera.h conventions; aliased, but exactly what the SMA's visibility
// sees). Where a ray hits a surface, its radiance is L_out at the hit,
// shaded on the side facing the camera with the vertex normals interpolated
// across the triangle (as the SMA's samples are). Where it escapes, it is
// the sky's radiance in that direction (black without a sky). The sun's disc
// is not drawn.
//
// Movable objects: an image shows the scene at one pose, the PosedRayScene
// passed in (RayScene::Initial() for the scene as loaded, AtPose() for the
// objects placed elsewhere: a from-scratch reference of a moved scene).
//
// Sample ids: pixel p = y * width + x uses id p for kCentre and
// p * paths + k for its k-th path under kBox; the jitter of pixel p comes
// from its own stream too, so images do not depend on the thread count.

#include <cstdint>
#include <string>
#include <vector>

#include "penumbra/common/camera.h"
#include "penumbra/common/image_io.h"
#include "penumbra/renderer/shading.h"

namespace penumbra {

class PosedRayScene;

enum class PixelFilter { kBox, kCentre };

/// Renders `view` of the scene at the pose `rays` (of the shader's RayScene)
/// with `threads` worker threads (at least one), each pixel
/// with the shader's paths per sample. Returns linear radiance, row 0 at the
/// top; adds the work done to `counters` when it is not null. The view must
/// have passed ValidateCameraView. Deterministic: the image does not depend
/// on the thread count. Blocks until done; call from any one thread.
Image RenderReference(const Shader& shader, const PosedRayScene& rays, const CameraView& view, int threads,
                      ShadeCounters* counters = nullptr, PixelFilter filter = PixelFilter::kBox);

/// One pass of progressive per-pixel path tracing: adds one path per pixel of
/// `view`, through a uniformly random point of the pixel (as kBox), to `sum`
/// (linear radiance, view.width * view.height * 3, row 0 at the top; resized
/// and zeroed when it has another size). The mean of passes 0..n-1 is an
/// n-path box-filtered image that converges to RenderReference's; every pass
/// has random streams of its own (ids pass * pixels + pixel), so an image
/// restarted at pass 0 repeats itself. Threads and blocking as
/// RenderReference.
void AddProgressivePass(const Shader& shader, const PosedRayScene& rays, const CameraView& view, int threads,
                        uint64_t pass, std::vector<float>* sum, ShadeCounters* counters = nullptr);

/// Places every animated movable object of `scene` where its animation has
/// it `timeS` seconds after it starts (ObjectAnimation::At: looped or held);
/// the others keep their place in `pose` (penumbra-reference
/// --animation-time). `pose` must have one transform per movable object.
void PlaceAnimatedObjects(const Scene& scene, double timeS, ScenePose* pose);

/// Places one movable object of `scene` in `pose` from a command-line
/// spec (penumbra-reference --object):
///   NAME=r00,r01,r02,tx,r10,r11,r12,ty,r20,r21,r22,tz
///       its object-to-world transform, 3x4 row-major as on the wire, rigid;
///   NAME=translate:x,y,z
///       moved by (x, y, z) in world space from its place in `pose`.
/// Fails, naming the spec and the problem, for an unknown object, a number
/// that does not parse, the wrong count, or a transform that is not rigid.
/// `pose` must have one transform per movable object.
Status PlaceObject(const Scene& scene, const std::string& spec, ScenePose* pose);

}  // namespace penumbra
