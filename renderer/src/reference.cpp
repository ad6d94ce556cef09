// Reference images; the contract is in reference.h.

#include "penumbra/renderer/reference.h"

#include <algorithm>
#include <atomic>
#include <charconv>
#include <limits>
#include <string_view>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include "penumbra/common/rng.h"
#include "penumbra/renderer/ray_scene.h"

namespace penumbra {

namespace {

// The sample for a camera ray's hit: on the side facing the camera, with the
// smooth normal the SMA's vertex samples would interpolate to, placed by the
// pose (a movable object's vertices are in its own space).
ShadeInput SampleAtHit(const Scene& scene, const ScenePose& pose, const RayHit& hit, const Vec3& direction,
                       uint64_t sampleId) {
  const Vec3 faceNormal = glm::normalize(hit.normal);
  const Vec3 towardCamera = glm::dot(faceNormal, direction) < 0.0f ? faceNormal : -faceNormal;
  const Triangle& tri = scene.triangles[hit.triangle];
  const Vec3 interpolated = pose.Of(scene.ObjectOfTriangle(hit.triangle))
                                .ApplyVector((1.0f - hit.b1 - hit.b2) * scene.vertices[tri.v[0]].normal +
                                             hit.b1 * scene.vertices[tri.v[1]].normal +
                                             hit.b2 * scene.vertices[tri.v[2]].normal);
  const float length = glm::length(interpolated);
  Vec3 normal = length > 0.0f ? interpolated / length : towardCamera;
  if (glm::dot(normal, towardCamera) < 0.0f) normal = -normal;

  ShadeInput in;
  in.sampleId = sampleId;
  in.position = WorldPointAt(scene, pose, hit.triangle, hit.b1, hit.b2);
  in.normal = normal;
  in.triangle = hit.triangle;
  in.b1 = hit.b1;
  in.b2 = hit.b2;
  return in;
}

// Mixed into the seed for the jitter streams, so that they are not the
// shader's streams of the same ids.
constexpr uint64_t kJitterStream = 0x6a09e667f3bcc909ull;
// The same for progressive passes (AddProgressivePass).
constexpr uint64_t kProgressiveStream = 0xbb67ae8584caa73bull;

// The radiance along the camera ray through image point (px, py) of
// `camera`, from pathCount paths of sample `sampleId` (0: the shader's
// paths per sample); the sky's where the ray escapes.
Rgb RadianceThrough(const Shader& shader, const PosedRayScene& rays, const PinholeCamera& camera, float px, float py,
                    uint64_t sampleId, int pathCount, ShadeCounters* counters) {
  constexpr float kInfinity = std::numeric_limits<float>::infinity();
  const Scene& scene = shader.GetScene();
  const Vec3 direction = camera.DirectionThrough(px, py);
  if (const auto hit = rays.Intersect(camera.Origin(), direction, 0.0f, kInfinity))
    return shader.Shade(rays, SampleAtHit(scene, rays.Pose(), *hit, direction, sampleId), pathCount, counters)
        .radiance;
  return scene.sky ? scene.sky->Radiance(direction) : Rgb(0.0f);
}

// Runs perRow(y, counters) for every row of a view `height` rows tall on
// `threads` workers, rows going to whichever worker is free (every pixel
// depends only on its own sample ids, so the assignment does not show).
template <typename PerRow>
void ForEachRow(int height, int threads, ShadeCounters* counters, PerRow perRow) {
  std::atomic<int> nextRow{0};
  const int workerCount = std::max(1, threads);
  std::vector<ShadeCounters> work(static_cast<size_t>(workerCount));
  std::vector<std::thread> workers;
  for (int w = 0; w < workerCount; ++w) {
    workers.emplace_back([&, w] {
      EnableFlushToZero();
      for (int y; (y = nextRow.fetch_add(1)) < height;) perRow(y, &work[size_t(w)]);
    });
  }
  for (std::thread& t : workers) t.join();
  if (counters)
    for (const ShadeCounters& c : work) *counters += c;
}

}  // namespace

Image RenderReference(const Shader& shader, const PosedRayScene& rays, const CameraView& view, int threads,
                      ShadeCounters* counters, PixelFilter filter) {
  const PinholeCamera camera(view);
  Image image;
  image.width = view.width;
  image.height = view.height;
  image.rgb.assign(size_t(view.width) * size_t(view.height) * 3, 0.0f);
  image.storedAsFloat = true;

  const int paths = shader.Settings().pathsPerSample;
  ForEachRow(view.height, threads, counters, [&](int y, ShadeCounters* work) {
    for (int x = 0; x < view.width; ++x) {
      const uint64_t pixel = uint64_t(y) * uint64_t(view.width) + uint64_t(x);
      Rgb radiance(0.0f);
      if (filter == PixelFilter::kCentre) {
        radiance = RadianceThrough(shader, rays, camera, float(x) + 0.5f, float(y) + 0.5f, pixel, 0, work);
      } else {
        Pcg32 jitter = Pcg32::ForSample(shader.Settings().seed ^ kJitterStream, pixel);
        for (int k = 0; k < paths; ++k) {
          const float px = float(x) + jitter.NextFloat();
          const float py = float(y) + jitter.NextFloat();
          radiance += RadianceThrough(shader, rays, camera, px, py, pixel * uint64_t(paths) + uint64_t(k), 1, work);
        }
        radiance /= float(paths);
      }
      float* out = image.rgb.data() + 3 * pixel;
      out[0] = radiance.r;
      out[1] = radiance.g;
      out[2] = radiance.b;
    }
  });
  return image;
}

void AddProgressivePass(const Shader& shader, const PosedRayScene& rays, const CameraView& view, int threads,
                        uint64_t pass, std::vector<float>* sum, ShadeCounters* counters) {
  const size_t pixelCount = size_t(view.width) * size_t(view.height);
  if (sum->size() != pixelCount * 3) sum->assign(pixelCount * 3, 0.0f);
  const PinholeCamera camera(view);
  // Pass p's ids follow every id of passes before it, and its jitter comes
  // from a stream apart from the kBox image's (kProgressiveStream), so no
  // two passes, and no pass and a reference, share a random stream.
  const uint64_t firstId = pass * uint64_t(pixelCount);
  ForEachRow(view.height, threads, counters, [&](int y, ShadeCounters* work) {
    for (int x = 0; x < view.width; ++x) {
      const uint64_t pixel = uint64_t(y) * uint64_t(view.width) + uint64_t(x);
      Pcg32 jitter = Pcg32::ForSample(shader.Settings().seed ^ kProgressiveStream, firstId + pixel);
      const float px = float(x) + jitter.NextFloat();
      const float py = float(y) + jitter.NextFloat();
      const Rgb radiance = RadianceThrough(shader, rays, camera, px, py, firstId + pixel, 1, work);
      float* out = sum->data() + 3 * pixel;
      out[0] += radiance.r;
      out[1] += radiance.g;
      out[2] += radiance.b;
    }
  });
}

void PlaceAnimatedObjects(const Scene& scene, double timeS, ScenePose* pose) {
  for (size_t i = 0; i < scene.objects.size(); ++i)
    if (scene.objects[i].animation) pose->objectToWorld[i] = scene.objects[i].animation->At(timeS);
}

Status PlaceObject(const Scene& scene, const std::string& spec, ScenePose* pose) {
  const size_t equals = spec.find('=');
  if (equals == std::string::npos)
    return Fail(fmt::format("--object '{}': expected NAME=12 numbers or NAME=translate:x,y,z", spec));
  const std::string name = spec.substr(0, equals);
  const uint32_t object = scene.FindObject(name);
  if (object == kStaticObject) {
    std::string known;
    for (const MovableObject& o : scene.objects) known += (known.empty() ? "" : ", ") + o.name;
    return Fail(fmt::format("--object '{}': the scene has no movable object '{}' ({})", spec, name,
                            known.empty() ? "it has none" : "it has " + known));
  }
  std::string_view numbers = std::string_view(spec).substr(equals + 1);
  constexpr std::string_view kTranslate = "translate:";
  const bool translate = numbers.starts_with(kTranslate);
  if (translate) numbers.remove_prefix(kTranslate.size());
  std::vector<float> values;
  for (size_t begin = 0; begin <= numbers.size();) {
    size_t end = numbers.find(',', begin);
    if (end == std::string_view::npos) end = numbers.size();
    const std::string_view text = numbers.substr(begin, end - begin);
    // from_chars takes no leading '+'; a person may well write one.
    const std::string_view digits = text.starts_with('+') ? text.substr(1) : text;
    float value = 0.0f;
    const auto [at, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), value);
    if (digits.empty() || ec != std::errc() || at != digits.data() + digits.size())
      return Fail(fmt::format("--object '{}': '{}' is not a number", spec, text));
    values.push_back(value);
    if (values.size() > 12) break;
    begin = end + 1;
  }
  const size_t expected = translate ? 3 : 12;
  if (values.size() != expected)
    return Fail(fmt::format("--object '{}': expected {} numbers, got {}", spec, expected,
                            values.size() > 12 ? "more" : std::to_string(values.size())));
  RigidTransform& place = pose->objectToWorld[object];
  if (translate) {
    // Through FromRowMajor too, so that a translation out of range is refused alike.
    RigidTransform moved = place;
    moved.translation += Vec3(values[0], values[1], values[2]);
    const auto m = moved.ToRowMajor();
    values.assign(m.begin(), m.end());
  }
  auto transform = RigidTransform::FromRowMajor(values);
  if (!transform) return Fail(fmt::format("--object '{}': {}", spec, transform.error().message));
  place = *transform;
  return Status::Ok();
}

}  // namespace penumbra
