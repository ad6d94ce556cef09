#include "penumbra/client/projection.h"

#include <algorithm>

#include <glm/gtc/matrix_transform.hpp>

namespace penumbra::client {

glm::mat4 WorldToClip(const CameraView& view, const Bounds3& sceneBounds) {
  const float radius = 0.5f * glm::length(sceneBounds.Diagonal());
  const float far = glm::length(view.pose.eye - sceneBounds.Center()) + radius + 1e-3f;
  const float near = std::max(far * 1e-4f, 1e-5f);
  const glm::mat4 projection =
      glm::perspective(glm::radians(view.fovYDeg), float(view.width) / float(view.height), near, far);
  // glm::lookAt builds the same right-handed frame as PinholeCamera:
  // right = forward x up, true up = right x forward.
  return projection * glm::lookAt(view.pose.eye, view.pose.target, view.pose.up);
}

}  // namespace penumbra::client
