#pragma once
// penumbra-client's main loop: the session's events are applied between
// frames, the GPU copy is synced, the camera (keys and mouse, or a scripted
// path) is sent when it changes, and the frame is drawn: radiance, tone
// mapping, wireframe, HUD. The same loop runs in a window and headless.
//
// Threads: RunClient runs on the main thread (GLFW's requirement) and is
// the render thread; the SmaSession it owns runs the network thread.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <optional>

#include <glm/vec2.hpp>

#include "gl/context.h"
#include "gl/tone_mapper.h"
#include "penumbra/client/headless_run.h"
#include "penumbra/client/moves_file.h"
#include "penumbra/common/camera.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/refinement_params.h"
#include "penumbra/common/tls.h"

namespace penumbra::client::gl {

struct ClientOptions {
  HostPort sma;
  bool headless = false;
  HeadlessBackend backend = HeadlessBackend::kAuto;
  /// Headless: the camera path to play (its size is the image's); none: a
  /// still view from the SMA's camera preset `cameraPreset` at `size`.
  std::optional<CameraPath> cameraPath;
  /// Preset to start from (window) or to show (headless); empty: the first.
  std::string cameraPreset;
  glm::ivec2 size{1280, 720};  // window size, or a headless still view's
  /// Headless: render (and ask the SMA for visibility) at this many samples
  /// per pixel side, and write images box-filtered down to the view's size:
  /// the pixel filter of offline references (a box of one pixel).
  int supersample = 1;
  /// Anisotropic texture filtering, 1-16; nullopt: 16 on a GPU, 1 on a
  /// software rasteriser (texture_filtering.h says why).
  std::optional<float> anisotropy;
  /// Headless: written when the run ends; .exr/.hdr hold linear radiance,
  /// .png/.jpg the tone-mapped image. Empty: none.
  std::filesystem::path screenshot;
  /// One JSON line per frame (stats_line.h). Empty: none.
  std::filesystem::path statsPath;
  /// Headless: when the run is done or has failed (headless_run.h).
  HeadlessGoal goal;
  /// Frame-rate cap; 0: 60 in a window (plus vsync), 30 headless, so a
  /// headless client leaves the CPU to the renderers it shares a host with.
  double maxFps = 0.0;
  /// Headless: rasterise only the frames written to a file (path-time and
  /// periodic snapshots, the final screenshot). Every frame still applies
  /// what arrived, uploads it and sends its view; a frame nobody sees is
  /// not drawn. Off: every frame is drawn (the cost of a display, measured).
  bool drawOnlyWrittenFrames = false;
  ToneSettings tone;
  /// Where the screenshot key writes its PNG and EXR (made when missing).
  std::filesystem::path screenshotDir = "penumbra-screenshots";
  /// Headless: every this many seconds, when the image has changed, write
  /// the linear radiance to <snapshotPrefix>_<frame>.exr, the frame being the
  /// stats line's (experiments measure convergence from these). 0: none.
  double snapshotEvery = 0.0;
  /// Headless, with a camera path: at path times 0, S, 2S, ... draw the pose
  /// of exactly that time and write the linear radiance shown to
  /// <snapshotPrefix>_t<milliseconds>.exr, changed or not (a walkthrough
  /// compares these with references of the same poses). 0: none.
  double snapshotPathInterval = 0.0;
  std::filesystem::path snapshotPrefix;
  /// Headless: object moves to send (--moves), timed from the first view's
  /// convergence (or the connection: movesFromConnection); their names are resolved against the SMA's scene, and one
  /// it lacks fails the run (exit 1). Empty: none.
  std::vector<ScriptedMove> moves;
  /// Headless: time 0 of the moves is the first connection (the camera
  /// path's time 0) instead of the first converged view (--moves-start).
  bool movesFromConnection = false;
  /// Refinement settings for the SMA session (criterion, S_req, ...); none:
  /// the SMA's defaults. In a window, C cycles the criterion.
  std::optional<RefinementRequest> refinement;
  /// Sent to the SMA in the Hello (--auth-token-file); empty: none.
  std::string authToken;
  /// TLS to the SMA (--tls-ca); null: plain TCP.
  std::shared_ptr<net::ssl::context> tls;
};

/// Runs the client; returns the process exit code: 0 done (window closed,
/// or the headless goal met and the screenshot written), 1 failure (no
/// connection within the timeout, no convergence within the timeout, a GL
/// or file error; one clear line is logged), 128 + signal when a headless
/// run is interrupted (an interrupted window just closes: 0).
int RunClient(const ClientOptions& options);

}  // namespace penumbra::client::gl
