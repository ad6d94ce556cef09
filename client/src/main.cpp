// penumbra-client: the walkthrough client. Connects to an SMA, shows what it
// streams in a window (or renders it headless along a camera path), and
// keeps the SMA informed of the camera. See client/README.md.

#include <cstdio>
#include <cstdlib>

#include <CLI/CLI.hpp>

#include "gl/client_app.h"
#include "penumbra/common/version.h"
#include "penumbra/client/path_player.h"
#include "penumbra/common/auth.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/refinement_params.h"
#include "penumbra/common/tls.h"

namespace {

int Usage(const std::string& message) {
  std::fprintf(stderr, "penumbra-client: %s (see --help)\n", message.c_str());
  return 2;
}

bool ParseSize(const std::string& text, glm::ivec2* size) {
  int w = 0, h = 0;
  char x = 0, extra = 0;
  if (std::sscanf(text.c_str(), "%d%c%d%c", &w, &x, &h, &extra) != 3 || (x != 'x' && x != 'X')) return false;
  if (w < 1 || h < 1 || w > 16384 || h > 16384) return false;
  *size = {w, h};
  return true;
}

// Where the screenshot key writes: $XDG_PICTURES_DIR/penumbra, else
// ~/Pictures/penumbra -- never the current folder (under run.sh, the
// repository), unless there is no home either.
std::string DefaultScreenshotDir() {
  if (const char* pictures = std::getenv("XDG_PICTURES_DIR"); pictures && *pictures)
    return std::string(pictures) + "/penumbra";
  if (const char* home = std::getenv("HOME"); home && *home) return std::string(home) + "/Pictures/penumbra";
  return "penumbra-screenshots";
}

}  // namespace

int main(int argc, char** argv) {
  using namespace penumbra;
  using namespace penumbra::client;
  using gl::ClientOptions;

  CLI::App app{"penumbra-client: walk through a scene an SMA streams, shaded by Penumbra's renderers"};
  app.set_version_flag("--version", "penumbra-client " + std::string(kVersion));
  ClientOptions options;
  std::string connect;
  std::string backend = "auto";
  std::string cameraPath;
  std::string size;
  std::string tone = "drago";
  std::string logLevel = "info";
  bool untilConverged = false;
  int connectTimeout = int(options.goal.connectTimeout.count());
  int convergeTimeout = int(options.goal.convergeTimeout.count());
  std::string screenshot, stats, screenshotDir = DefaultScreenshotDir();
  std::string snapshotPrefix;
  std::string movesFile;
  std::string movesStart = "converged";
  std::string authTokenFile, tlsCa;
  // Refinement settings for this client's SMA session; unset: the SMA's.
  std::string criterion;
  std::optional<float> sReq, noiseZ, minPixels, pixelFraction;
  std::optional<uint32_t> refineBatch;

  app.add_option("--connect", connect, "SMA address, HOST:PORT")->required();
  app.add_option("--camera", options.cameraPreset,
                 "Camera preset of the scene to start from (window) or to show (headless); default: the first");
  app.add_option("--size", size, "Window size, or a headless still view's image size, WxH (default 1280x720)");
  app.add_option("--tone", tone, "Tone mapping: drago (Drago 2003) or exposure (exposure + gamma)")
      ->check(CLI::IsMember({"drago", "exposure"}))
      ->capture_default_str();
  app.add_option("--exposure", options.tone.exposureStops, "Exposure in stops added to the scene's")
      ->capture_default_str();
  app.add_option("--gamma", options.tone.gamma, "Gamma of the exposure + gamma tone mapping")
      ->check(CLI::Range(1.0f, 3.0f))
      ->capture_default_str();
  app.add_option("--stats", stats, "Write one JSON line of statistics per frame to this file");
  app.add_option("--screenshot-dir", screenshotDir, "Where the screenshot key (P) writes its PNG and EXR; made if missing")
      ->capture_default_str();
  app.add_option("--max-fps", options.maxFps, "Frame-rate cap (0: 60 in a window, 30 headless)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--log-level", logLevel, "trace, debug, info, warn, error, critical or off")->capture_default_str();
  app.add_option("--auth-token-file", authTokenFile,
                 "Present the token in this file to the SMA (its --auth-token-file); keep it mode 600");
  app.add_option("--tls-ca", tlsCa,
                 "Connect with TLS, trusting the CA certificate(s) in this PEM file; the SMA's certificate must name "
                 "the --connect host");

  std::vector<std::string> criterionNames;
  for (const CriterionEntry& entry : Criteria()) criterionNames.emplace_back(entry.name);
  app.add_option("--criterion", criterion,
                 "Refinement criterion for this client: " + CriterionNameList() + " (default: the SMA's)")
      ->check(CLI::IsMember(criterionNames));
  app.add_option("--s-req", sReq, "Refinement: S_req (default: the SMA's)");
  app.add_option("--noise-z", noiseZ, "Refinement: differences within this many standard errors are noise (0: the paper's S)");
  app.add_option("--min-pixels", minPixels, "Refinement: leaves covering fewer pixels are not split");
  app.add_option("--pixel-fraction", pixelFraction, "Refinement: NLD_IS / RND budget as a fraction of the pixels");
  app.add_option("--refine-batch", refineBatch, "Refinement: R, leaves chosen per step");
  auto* headless = app.add_flag("--headless", options.headless, "Render offscreen, without a window");
  auto* glOption = app.add_option("--gl", backend, "Headless OpenGL: auto (GLFW if DISPLAY is set, else EGL), glfw or egl")
                       ->check(CLI::IsMember({"auto", "glfw", "egl"}))
                       ->capture_default_str();
  auto* pathOption = app.add_option(
      "--camera-path", cameraPath,
      "Headless: camera path JSON (common/camera.h), or SCENE.json#NAME for a scene file's path; default: the "
      "--camera preset as a still view at --size");
  auto* screenshotOption = app.add_option(
      "--screenshot", screenshot, "Headless: image written at the end; .png tone-mapped, .exr linear radiance with coverage as alpha");
  auto* convergedFlag =
      app.add_flag("--until-converged", untilConverged,
                   "Headless: play the path, then stop once the SMA reports the final view converged (default)");
  auto* framesOption = app.add_option("--frames", options.goal.frames, "Headless: stop after N frames")
                           ->check(CLI::PositiveNumber);
  auto* secondsOption = app.add_option("--seconds", options.goal.seconds, "Headless: stop after S seconds")
                            ->check(CLI::PositiveNumber);
  convergedFlag->excludes(framesOption)->excludes(secondsOption);
  framesOption->excludes(secondsOption);
  auto* connectTimeoutOption =
      app.add_option("--connect-timeout", connectTimeout, "Headless: fail after S seconds without a connection")
          ->check(CLI::Range(1, 86400))
          ->capture_default_str();
  auto* timeoutOption =
      app.add_option("--timeout", convergeTimeout, "Headless, --until-converged: fail after S seconds")
          ->check(CLI::Range(1, 86400))
          ->capture_default_str();
  app.add_option("--anisotropy", options.anisotropy,
                 "Anisotropic texture filtering, 1 (off) to 16; default 16 on a GPU, 1 on a software rasteriser "
                 "(Mesa llvmpipe's takes seconds for some frames)")
      ->check(CLI::Range(1.0f, 16.0f));
  auto* supersampleOption =
      app.add_option("--supersample", options.supersample,
                     "Headless: N x N samples per pixel (the SMA's visibility too), images box-filtered to the "
                     "view's size, as offline references filter them")
          ->check(CLI::Range(1, 8))
          ->capture_default_str();
  auto* movesOption = app.add_option(
      "--moves", movesFile,
      "Headless: play the object moves in FILE (lines '<t_seconds> <object> [translate X Y Z] [rotate DEG about AX AY "
      "AZ]'), t counted from the first converged view (client/README.md)");
  auto* movesStartOption =
      app.add_option("--moves-start", movesStart,
                     "Headless: time 0 of --moves is the first converged view (converged) or the first connection, "
                     "as the camera path's (connected)")
          ->check(CLI::IsMember({"converged", "connected"}))
          ->capture_default_str();
  movesStartOption->needs(movesOption);
  auto* snapshotOption = app.add_option("--snapshot-every", options.snapshotEvery,
                                        "Headless: every S seconds, when the image changed, write the linear "
                                        "radiance to PREFIX_<frame>.exr (frame as in --stats)");
  auto* pathSnapshotOption =
      app.add_option("--snapshot-path-interval", options.snapshotPathInterval,
                     "Headless: at path times 0, S, 2S, ... draw exactly that time's pose and write the linear "
                     "radiance shown to PREFIX_t<milliseconds>.exr")
          ->check(CLI::Range(0.01, 3600.0));
  auto* prefixOption = app.add_option("--snapshot-prefix", snapshotPrefix,
                                      "Headless: path prefix of --snapshot-every's and --snapshot-path-interval's files");
  snapshotOption->needs(prefixOption);
  pathSnapshotOption->needs(prefixOption);
  auto* drawOnlyOption = app.add_flag(
      "--draw-only-written-frames", options.drawOnlyWrittenFrames,
      "Headless: draw only the frames written to a file (snapshots, the screenshot); the others still send their "
      "view and take their deltas, but nobody sees them, so they are not rasterised -- a bench's clients then leave "
      "the CPU to the stack they share it with, as clients on their own GPUs would");
  for (CLI::Option* o : {drawOnlyOption, glOption, pathOption, screenshotOption, convergedFlag, framesOption, secondsOption,
                         connectTimeoutOption, timeoutOption, snapshotOption, pathSnapshotOption, prefixOption,
                         supersampleOption, movesOption, movesStartOption})
    o->needs(headless);

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    return Usage(e.what());
  }

  if (!SetupLogging(logLevel)) return Usage("unknown --log-level '" + logLevel + "'");
  auto sma = ParseHostPort(connect);
  if (!sma) return Usage("--connect: " + sma.error().message);
  options.sma = *sma;
  if (!size.empty() && !ParseSize(size, &options.size)) return Usage("--size must be WxH, 1..16384 each: " + size);
  options.tone.op = tone == "drago" ? gl::ToneOperator::kDrago : gl::ToneOperator::kExposureGamma;
  options.backend = backend == "glfw" ? gl::HeadlessBackend::kGlfw
                    : backend == "egl" ? gl::HeadlessBackend::kEgl
                                       : gl::HeadlessBackend::kAuto;
  options.screenshot = screenshot;
  options.statsPath = stats;
  options.screenshotDir = screenshotDir;
  options.snapshotPrefix = snapshotPrefix;
  if (!criterion.empty() || sReq || noiseZ || minPixels || pixelFraction || refineBatch) {
    // The SMA validates the ranges (with its own limits on top) and answers
    // out-of-range values with an error.
    RefinementRequest refinement;
    if (!criterion.empty()) refinement.criterion = *ParseCriterion(criterion);  // checked by IsMember
    refinement.sReq = sReq;
    refinement.noiseZ = noiseZ;
    refinement.minPixels = minPixels;
    refinement.pixelFraction = pixelFraction;
    refinement.batch = refineBatch;
    options.refinement = refinement;
  }
  if (!authTokenFile.empty()) {
    auto token = ReadAuthTokenFile(authTokenFile);
    if (!token) return Usage("--auth-token-file: " + token.error().message);
    if (!token->warning.empty()) Logger("client")->warn("{}", token->warning);
    options.authToken = std::move(token->token);
  }
  if (!tlsCa.empty()) {
    auto context = net::MakeTlsClientContext(tlsCa);
    if (!context) return Usage("--tls-ca: " + context.error().message);
    options.tls = std::move(*context);
  }
  options.goal.connectTimeout = std::chrono::seconds(connectTimeout);
  options.goal.convergeTimeout = std::chrono::seconds(convergeTimeout);
  if (framesOption->count() > 0) options.goal.stopWhen = StopWhen::kFrames;
  if (secondsOption->count() > 0) options.goal.stopWhen = StopWhen::kSeconds;
  if (!cameraPath.empty()) {
    auto path = LoadCameraPathSpec(cameraPath);
    if (!path) return Usage("--camera-path: " + path.error().message);
    options.cameraPath = std::move(*path);
  }
  if (!movesFile.empty()) {
    auto moves = LoadMovesFile(movesFile);
    if (!moves) return Usage("--moves: " + moves.error().message);
    options.moves = std::move(*moves);
  }
  options.movesFromConnection = movesStart == "connected";

  const char* display = std::getenv("DISPLAY");
  if (!options.headless && !(display && *display)) {
    std::fprintf(stderr,
                 "penumbra-client: no display (DISPLAY is not set), so no window; render headless instead:\n"
                 "  %s --connect %s --headless --until-converged --screenshot penumbra.png\n",
                 argv[0], connect.c_str());
    return 1;
  }
  return gl::RunClient(options);
}
