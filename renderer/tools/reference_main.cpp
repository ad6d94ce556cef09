// penumbra-reference: path-traces every pixel of a view of a scene with the
// renderer's Shader and writes the image -- the ground truth for comparisons,
// and a way to look at a scene. See reference.h for what a pixel holds.
//
//   penumbra-reference --scene scenes/cornell-box.json --camera front --out cornell.png

#include <map>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <thread>

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

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"penumbra-reference: path-trace every pixel of a view with the renderer's shader"};
  std::string scenePath, cameraName, cameraPathFile, outPath, logLevel = "info";
  double timeSeconds = 0.0;
  int width = 640, height = 480;
  int threads = 0;
  float exposureStops = 0.0f;
  ShadingSettings shading;
  shading.pathsPerSample = 256;

  app.add_option("--scene", scenePath, "Scene description (.json) or mesh file")->required();
  auto* camera = app.add_option("--camera", cameraName, "Camera preset of the scene, by name");
  auto* path = app.add_option("--camera-path", cameraPathFile, "Camera path file (.json, docs/scenes.md)");
  camera->excludes(path);
  app.add_option("--time", timeSeconds, "Time along --camera-path, in seconds")->capture_default_str();
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
  app.add_option("--out", outPath, "Output image: .exr/.hdr linear radiance, .png/.jpg clamped and sRGB-encoded")
      ->required();
  app.add_option("--log-level", logLevel, "trace, debug, info, warn, error, critical or off")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  if (!SetupLogging(logLevel)) return Exit("unknown --log-level '" + logLevel + "'");
  if (cameraName.empty() && cameraPathFile.empty()) return Exit("give --camera NAME or --camera-path FILE");

  auto scene = LoadScene(scenePath);
  if (!scene) return Exit(scene.error().message);
  CameraView view;
  if (!cameraName.empty()) {
    const CameraPreset* preset = scene->FindCamera(cameraName);
    if (!preset) return Exit("the scene has no camera named '" + cameraName + "'");
    view.pose = preset->pose;
    view.fovYDeg = preset->fovYDeg;
    view.width = width;
    view.height = height;
  } else {
    auto cameraPath = LoadCameraPath(cameraPathFile);
    if (!cameraPath) return Exit(cameraPath.error().message);
    if (cameraPath->keyframes.empty()) return Exit(cameraPathFile + ": the path has no keyframes");
    view = cameraPath->ViewAt(timeSeconds);
  }
  if (auto ok = ValidateCameraView(view); !ok) return Exit(ok.error().message);

  // Fail now rather than after a long render if the output cannot be
  // written (unknown extension, missing folder); the render overwrites it.
  const float probe[3] = {0.0f, 0.0f, 0.0f};
  if (auto ok = WriteImage(outPath, 1, 1, probe); !ok) return Exit(ok.error().message);

  auto rays = RayScene::Build(*scene);
  if (!rays) return Exit(rays.error().message);
  const Shader shader(*scene, **rays, shading);
  const int workers = threads > 0 ? threads : int(std::max(1u, std::thread::hardware_concurrency()));

  const auto start = std::chrono::steady_clock::now();
  ShadeCounters work;
  Image image = RenderReference(shader, **rays, view, workers, &work, filter);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  Logger("reference")->info("{}x{} at {} paths/pixel in {:.3f} s ({:.2f} Mrays/s, {} thread(s))", view.width,
                            view.height, shading.pathsPerSample, seconds, double(work.rays) / seconds * 1e-6, workers);

  const float scale = std::exp2(exposureStops);
  for (float& v : image.rgb) v *= scale;
  if (auto ok = WriteImage(outPath, image.width, image.height, image.rgb); !ok) return Exit(ok.error().message);
  return 0;
}
