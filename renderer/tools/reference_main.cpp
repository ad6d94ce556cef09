// penumbra-reference: path-traces every pixel of a view of a scene with the
// renderer's Shader and writes the image -- the ground truth for comparisons,
// and a way to look at a scene. See reference.h for what a pixel holds.
//
//   penumbra-reference --scene scenes/cornell-box.json --camera front --out cornell.png
//
// With --progressive S it is instead the per-pixel path tracer a walkthrough
// is compared against: it plays --camera-path in real time, adds one path
// per pixel per pass to a running mean, starts the mean afresh whenever the
// pose changes, and at path times 0, S, 2S, ... writes the image it shows
// then (bench/walkthrough/).
//
// --object NAME=... (repeatable) places a movable object elsewhere than the
// scene file does, and --animation-time T puts the animated ones where their
// animations have them at T: a from-scratch reference of a moved scene.

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include <CLI/CLI.hpp>

#include "penumbra/common/camera.h"
#include "penumbra/common/image_io.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"
#include "penumbra/renderer/ray_scene.h"
#include "penumbra/renderer/reference.h"
#include "penumbra/renderer/shading.h"

namespace {

using namespace penumbra;

// One line on stderr and exit code 1.
int Exit(const std::string& message) {
  std::fprintf(stderr, "penumbra-reference: %s\n", message.c_str());
  return 1;
}

bool SamePose(const CameraPose& a, const CameraPose& b) {
  return a.eye == b.eye && a.target == b.target && a.up == b.up;
}

// The --progressive mode: returns the exit code. The image shown at a
// snapshot time t is the running mean for the pose at t; when that pose is
// new (the camera moved), the frame is the first pass at it, as a
// progressive viewer's first frame after a move.
int RunProgressive(const Shader& shader, const PosedRayScene& rays, const CameraPath& path, double interval,
                   double duration, const std::string& prefix, int workers, const std::string& startFile) {
  auto log = Logger("reference");
  if (!startFile.empty()) {
    // Several tracers sharing the cores start their paths together.
    log->info("ready; waiting for {}", startFile);
    const auto giveUp = std::chrono::steady_clock::now() + std::chrono::minutes(30);
    std::error_code ec;
    while (!std::filesystem::exists(startFile, ec)) {
      if (std::chrono::steady_clock::now() > giveUp) return Exit(startFile + " did not appear within 30 minutes");
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  }
  const int snapshots = int(std::floor(duration / interval + 1e-9)) + 1;
  std::vector<float> sum, mean;
  CameraView shown;
  uint64_t passes = 0, totalPasses = 0, restarts = 0;
  ShadeCounters work;
  const auto start = std::chrono::steady_clock::now();
  for (int k = 0; k < snapshots;) {
    const double now = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    const double snapshotTime = k * interval;
    const bool snapshotDue = now >= snapshotTime;
    const CameraView view = path.ViewAt(snapshotDue ? snapshotTime : now);
    if (passes == 0 || !SamePose(view.pose, shown.pose)) {
      shown = view;
      passes = 0;
      sum.assign(size_t(view.width) * size_t(view.height) * 3, 0.0f);
      ++restarts;
    }
    if (!snapshotDue || passes == 0) {
      AddProgressivePass(shader, rays, shown, workers, passes, &sum, &work);
      ++passes;
      ++totalPasses;
    }
    if (!snapshotDue) continue;
    mean.resize(sum.size());
    for (size_t i = 0; i < sum.size(); ++i) mean[i] = sum[i] / float(passes);
    const std::string out = fmt::format("{}_t{:06}.exr", prefix, std::llround(snapshotTime * 1000.0));
    if (auto ok = WriteImage(out, shown.width, shown.height, mean); !ok) return Exit(ok.error().message);
    log->debug("t = {:.3f} s: {} passes at this pose, written {:.3f} s late", snapshotTime, passes,
               std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() - snapshotTime);
    ++k;
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  log->info("progressive: {} snapshots, {} passes ({} restarts) in {:.2f} s, {:.2f} Mrays/s, {} thread(s)",
            snapshots, totalPasses, restarts, seconds, double(work.rays) / seconds * 1e-6, workers);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"penumbra-reference: path-trace every pixel of a view with the renderer's shader"};
  std::string scenePath, cameraName, cameraPathFile, outPath, logLevel = "info";
  int width = 640, height = 480;
  int threads = 0;
  float exposureStops = 0.0f;
  ShadingSettings shading;
  shading.pathsPerSample = 256;

  app.add_option("--scene", scenePath, "Scene description (.json) or mesh file")->required();
  auto* camera = app.add_option("--camera", cameraName, "Camera preset of the scene, by name");
  auto* path = app.add_option("--camera-path", cameraPathFile, "Camera path file (.json, docs/scenes.md)");
  camera->excludes(path);
  std::vector<double> times;
  app.add_option("--time", times,
                 "Time along --camera-path, in seconds (default 0); several render one image each, to --out with "
                 "{t} replaced by the time in milliseconds (one scene load for all)")
      ->expected(1, 1 << 20);
  app.add_option("--width", width, "Image width for --camera (a path gives its own)")
      ->check(CLI::Range(1, 16384))->capture_default_str();
  app.add_option("--height", height, "Image height for --camera (a path gives its own)")
      ->check(CLI::Range(1, 16384))->capture_default_str();
  app.add_option("--spp", shading.pathsPerSample, "Paths per pixel")->check(CLI::Range(1, 1 << 20))->capture_default_str();
  PixelFilter filter = PixelFilter::kBox;
  app.add_option("--pixel-filter", filter,
                 "box: every path through its own random point of the pixel (antialiased, the default); "
                 "centre: one ray through the pixel's centre, all paths from its hit")
      ->transform(CLI::CheckedTransformer(
          std::map<std::string, PixelFilter>{{"box", PixelFilter::kBox}, {"centre", PixelFilter::kCentre},
                                             {"center", PixelFilter::kCentre}},
          CLI::ignore_case));
  app.add_option("--max-bounces", shading.maxBounces,
                 "Most surfaces a path reflects from after the first (0: direct light only); Russian roulette ends "
                 "paths long before the default cap, so the default is unbiased")
      ->check(CLI::Range(0, 1024))->capture_default_str();
  app.add_option("--seed", shading.seed, "Seed mixed into every pixel's random stream")->capture_default_str();
  app.add_option("--threads", threads, "Worker threads (0: one per hardware thread)")
      ->check(CLI::Range(0, 1024))->capture_default_str();
  app.add_option("--exposure", exposureStops, "Multiply the image by 2^stops before writing it")
      ->capture_default_str();
  auto* outOption =
      app.add_option("--out", outPath, "Output image: .exr/.hdr linear radiance, .png/.jpg clamped and sRGB-encoded");
  double progressiveInterval = 0.0, duration = -1.0;
  std::string snapshotPrefix, startFile;
  auto* progressive =
      app.add_option("--progressive", progressiveInterval,
                     "Play --camera-path in real time as a progressive path tracer (one path per pixel per pass, "
                     "restarted whenever the pose changes) and write the image shown at path times 0, S, 2S, ... "
                     "to PREFIX_t<milliseconds>.exr")
          ->check(CLI::Range(0.01, 3600.0));
  auto* prefixOption = app.add_option("--snapshot-prefix", snapshotPrefix, "--progressive: path prefix of its images");
  auto* durationOption = app.add_option("--duration", duration, "--progressive: seconds to play (default: the path's)")
                             ->check(CLI::Range(0.0, 86400.0));
  auto* startOption = app.add_option("--start-file", startFile,
                                     "--progressive: after loading, wait until this file exists to start the path");
  progressive->needs(path)->needs(prefixOption);
  startOption->needs(progressive);
  prefixOption->needs(progressive);
  durationOption->needs(progressive);
  std::vector<std::string> objectSpecs;
  app.add_option("--object", objectSpecs,
                 "Place a movable object of the scene elsewhere: NAME=r00,r01,r02,tx,r10,r11,r12,ty,r20,r21,r22,tz "
                 "(its object-to-world transform, 3x4 row-major, rigid) or NAME=translate:x,y,z (moved by x,y,z "
                 "from where the scene puts it); repeatable")
      ->take_all();
  double animationTime = -1.0;
  app.add_option("--animation-time", animationTime,
                 "Place every animated object where its animation has it this many seconds after it starts (before "
                 "--object, which may then move one elsewhere)")
      ->check(CLI::Range(0.0, 1e9));
  app.add_option("--log-level", logLevel, "trace, debug, info, warn, error, critical or off")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  if (!SetupLogging(logLevel)) return Exit("unknown --log-level '" + logLevel + "'");
  if (cameraName.empty() && cameraPathFile.empty()) return Exit("give --camera NAME or --camera-path FILE");
  if (progressive->count() == 0 && outOption->count() == 0) return Exit("give --out FILE (or --progressive S)");
  if (progressive->count() != 0 && outOption->count() != 0) return Exit("--out and --progressive exclude each other");

  auto scene = LoadScene(scenePath);
  if (!scene) return Exit(scene.error().message);
  CameraView view;
  CameraPath cameraPath;
  if (!cameraName.empty()) {
    const CameraPreset* preset = scene->FindCamera(cameraName);
    if (!preset) return Exit("the scene has no camera named '" + cameraName + "'");
    view.pose = preset->pose;
    view.fovYDeg = preset->fovYDeg;
    view.width = width;
    view.height = height;
  } else {
    auto loaded = LoadCameraPath(cameraPathFile);
    if (!loaded) return Exit(loaded.error().message);
    if (loaded->keyframes.empty()) return Exit(cameraPathFile + ": the path has no keyframes");
    cameraPath = std::move(*loaded);
    view = cameraPath.ViewAt(times.empty() ? 0.0 : times.front());
  }
  if (auto ok = ValidateCameraView(view); !ok) return Exit(ok.error().message);

  // Fail now rather than after a long render if the output cannot be
  // written (unknown extension, missing folder); the render overwrites it.
  const float probe[3] = {0.0f, 0.0f, 0.0f};
  if (times.size() > 1 && outPath.find("{t}") == std::string::npos) return Exit("several --time values need {t} in --out");
  // The image path of time t (--out, with {t} replaced when there are several).
  const auto outAt = [&](double t) {
    std::string out = outPath;
    if (const size_t at = out.find("{t}"); times.size() > 1 && at != std::string::npos)
      out.replace(at, 3, fmt::format("{:06}", std::llround(t * 1000.0)));
    return out;
  };
  const std::string probePath =
      progressive->count() != 0 ? snapshotPrefix + "_t000000.exr" : outAt(times.empty() ? 0.0 : times.front());
  if (auto ok = WriteImage(probePath, 1, 1, probe); !ok) return Exit(ok.error().message);

  ScenePose pose = ScenePose::Initial(*scene);
  if (animationTime >= 0.0) PlaceAnimatedObjects(*scene, animationTime, &pose);
  for (const std::string& spec : objectSpecs)
    if (auto ok = PlaceObject(*scene, spec, &pose); !ok) return Exit(ok.error().message);

  auto rays = RayScene::Build(*scene);
  if (!rays) return Exit(rays.error().message);
  const Shader shader(*scene, **rays, shading);
  auto posed = (*rays)->AtPose(pose);
  if (!posed) return Exit(posed.error().message);
  for (size_t i = 0; i < scene->objects.size(); ++i)
    Logger("reference")->info("object '{}': {}", scene->objects[i].name, Describe(pose.objectToWorld[i]));
  const int workers = threads > 0 ? threads : int(std::max(1u, std::thread::hardware_concurrency()));
  if (progressive->count() != 0)
    return RunProgressive(shader, **posed, cameraPath, progressiveInterval,
                          duration >= 0.0 ? duration : cameraPath.DurationSeconds(), snapshotPrefix, workers,
                          startFile);

  // One image per time (one when a preset gives the view).
  if (times.empty() || !cameraName.empty()) times.assign(1, 0.0);
  for (const double t : times) {
    if (cameraName.empty()) view = cameraPath.ViewAt(t);
    const auto start = std::chrono::steady_clock::now();
    ShadeCounters work;
    Image image = RenderReference(shader, **posed, view, workers, &work, filter);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    Logger("reference")->info("{}x{} at {} paths/pixel in {:.3f} s ({:.2f} Mrays/s, {} thread(s))", view.width,
                              view.height, shading.pathsPerSample, seconds, double(work.rays) / seconds * 1e-6,
                              workers);
    const float scale = std::exp2(exposureStops);
    for (float& v : image.rgb) v *= scale;
    if (auto ok = WriteImage(outAt(t), image.width, image.height, image.rgb); !ok) return Exit(ok.error().message);
  }
  return 0;
}
