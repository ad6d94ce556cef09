#include "penumbra/client/raster_load.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <glm/vec4.hpp>

namespace penumbra::client {

RasterLoad MeasureRasterLoad(const MeshStore& store, const glm::mat4& worldToClip, int width, int height) {
  RasterLoad load;
  const double viewportPixels = double(width) * double(height);
  for (const TriangleGroup& group : store.Groups()) {
    const uint32_t used = group.allocator.HighWater();
    load.slotsDrawn += used;
    for (uint32_t s = 0; s < used; ++s) {
      const GpuTriangle& triangle = group.slots[s];
      if (triangle.corners[0].material == kEmptyTriangleSlot) continue;
      ++load.trianglesLive;
      Vec3 world[3];
      glm::vec4 clip[3];
      bool behind = false;
      for (int k = 0; k < 3; ++k) {
        world[k] = store.WorldPositionOfSlot(triangle.corners[k].vertexSlot);
        clip[k] = worldToClip * glm::vec4(world[k], 1.0f);
        behind = behind || clip[k].w <= 0.0f;
      }
      double pixels = viewportPixels;
      if (behind) {
        ++load.trianglesCrossingEyePlane;
      } else {
        double x[3], y[3];
        for (int k = 0; k < 3; ++k) {
          x[k] = (double(clip[k].x) / clip[k].w + 1.0) * 0.5 * width;
          y[k] = (double(clip[k].y) / clip[k].w + 1.0) * 0.5 * height;
        }
        const double area = 0.5 * std::abs((x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0]));
        const double boxW = std::clamp(std::max({x[0], x[1], x[2]}), 0.0, double(width)) -
                            std::clamp(std::min({x[0], x[1], x[2]}), 0.0, double(width));
        const double boxH = std::clamp(std::max({y[0], y[1], y[2]}), 0.0, double(height)) -
                            std::clamp(std::min({y[0], y[1], y[2]}), 0.0, double(height));
        pixels = std::isfinite(area) ? std::min(area, boxW * boxH) : viewportPixels;
      }
      load.coveredPixels += pixels;
      if (pixels > load.largestPixels) {
        load.largestPixels = pixels;
        std::copy(world, world + 3, load.largestCorners);
      }
    }
  }
  return load;
}

std::string Describe(const RasterLoad& load, int width, int height) {
  const double viewport = std::max(1.0, double(width) * double(height));
  const Vec3* c = load.largestCorners;
  return fmt::format(
      "{} triangle slots drawn, {} live, {} with a corner at or behind the eye plane; they cover {:.3g} pixels "
      "({:.2f} x the {}x{} viewport); the largest covers {:.3g} pixels, corners ({:.3g} {:.3g} {:.3g}) "
      "({:.3g} {:.3g} {:.3g}) ({:.3g} {:.3g} {:.3g})",
      load.slotsDrawn, load.trianglesLive, load.trianglesCrossingEyePlane, load.coveredPixels,
      load.coveredPixels / viewport, width, height, load.largestPixels, c[0].x, c[0].y, c[0].z, c[1].x, c[1].y,
      c[1].z, c[2].x, c[2].y, c[2].z);
}

}  // namespace penumbra::client
