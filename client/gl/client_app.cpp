#include "gl/client_app.h"

#include <algorithm>
#include <cstdlib>
#include <cmath>
#include <cctype>
#include <csignal>
#include <ctime>
#include <thread>

#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <fmt/format.h>

#include "gl/frame_targets.h"
#include "gl/hud.h"
#include "gl/mesh_renderer.h"
#include "gl/sky_renderer.h"
#include "penumbra/client/client_model.h"
#include "penumbra/client/fly_camera.h"
#include "penumbra/client/object_moves.h"
#include "penumbra/client/path_player.h"
#include "penumbra/client/progress.h"
#include "penumbra/client/projection.h"
#include "penumbra/client/session.h"
#include "penumbra/client/raster_load.h"
#include "penumbra/client/stats_line.h"
#include "penumbra/common/image_io.h"
#include "penumbra/common/logging.h"

// The GL code sees the client core's domain types (ClientScene, the mesh
// store, the session's events), never the wire's protobuf messages: this
// fails the build if an include brings them back.
#ifdef GOOGLE_PROTOBUF_INCLUDED_penumbra_2fwire_2eproto
#error "penumbra/wire.pb.h reached the GL code; keep protobuf types inside the client core's .cpp files"
#endif

namespace penumbra::client::gl {

namespace {

using Clock = std::chrono::steady_clock;
using Seconds = std::chrono::duration<double>;

volatile std::sig_atomic_t gStopSignal = 0;
void OnStopSignal(int signal) { gStopSignal = signal; }

constexpr float kTurnRadiansPerPixel = 0.0025f;
constexpr float kSpeedStep = 1.25f;
constexpr float kSpeedPerSceneSize = 0.15f;  // default walking speed: scene diagonals per second
constexpr float kExposureStep = 1.0f / 3.0f;
constexpr float kGammaStep = 0.1f;
constexpr double kAdaptationSeconds = 0.5;  // window: time constant of the adaptation to a new view
constexpr auto kRateWindow = std::chrono::milliseconds(500);
constexpr auto kNoticeDuration = std::chrono::seconds(6);
// A first Esc with the mouse free only arms quitting: one stray key must not
// close the window (and, under run.sh, the stack and its cache with it).
constexpr auto kQuitConfirmWindow = std::chrono::seconds(2);
const glm::vec4 kWireColour(1.0f, 0.75f, 0.2f, 0.55f);
// A mouse-wheel step moves a dragged object this fraction of the scene's
// diagonal along the view direction.
constexpr float kDragDepthStepPerSceneSize = 0.02f;


bool SameView(const CameraView& a, const CameraView& b) {
  return a.pose.eye == b.pose.eye && a.pose.target == b.pose.target && a.pose.up == b.pose.up &&
         a.fovYDeg == b.fovYDeg && a.width == b.width && a.height == b.height;
}

std::string LocalTimestamp() {
  const std::time_t now = std::time(nullptr);
  std::tm local{};
  localtime_r(&now, &local);
  char text[32];
  std::strftime(text, sizeof text, "%Y%m%d-%H%M%S", &local);
  return text;
}

}  // namespace

class ClientApp {
 public:
  explicit ClientApp(const ClientOptions& options)
      : options_(options),
        log_(Logger("client")),
        tone_(options.tone),
        start_(Clock::now()),
        headlessRun_(options.goal, options.sma.ToString(), start_),
        snapshots_(Seconds(options.headless ? options.snapshotEvery : 0.0), options.snapshotPrefix) {
    SmaSessionOptions session;
    session.sma = options.sma;
    session.authToken = options.authToken;
    session.tls = options.tls;
    session_ = std::make_unique<SmaSession>(session);
  }

  Status Init();
  int Run();

 private:
  // Per frame, in order.
  bool EnsureCamera();
  void HandleInput(double seconds);
  void UpdateDrag(bool pressed, double scroll, Clock::time_point now);
  void SendMove(uint32_t object, const RigidTransform& t);
  void UpdateObjects(Clock::time_point now);
  bool PlayMoves(Clock::time_point now);
  std::string ObjectsLine() const;
  void OnKey(const KeyPress& key);
  std::optional<CameraView> CurrentView(Clock::time_point now) const;
  void UpdateAdaptation(double seconds);
  HeadlessObservation ObserveHeadless(Clock::time_point now) const;
  Bounds3 DepthBounds() const;
  void ExplainSlowFrame(double seconds, Clock::time_point now);
  void Render();
  void DrawHud();
  void UpdateRates(Clock::time_point now);
  void WriteStats(Clock::time_point now);
  int Finish();

  void ApplyPreset(int index);
  Status WriteScreenshot(const std::filesystem::path& path);
  void CycleCriterion();
  void SetCriterion(const std::string& criterion);
  bool SnapshotDue(Clock::time_point now) const;  // a --snapshot-every file is written this frame
  void MaybeWriteSnapshot(Clock::time_point now);
  void WritePathSnapshot(double pathTime);
  void SaveInteractiveScreenshot();
  int Failed(const std::string& message) const;

  const ClientOptions options_;
  std::shared_ptr<spdlog::logger> log_;
  std::unique_ptr<SmaSession> session_;
  ClientModel model_;

  // GL: the context first, so that the objects below are destroyed before it.
  std::unique_ptr<Context> context_;
  Window* window_ = nullptr;  // context_, when it is a GLFW window
  std::optional<MeshRenderer> renderer_;
  std::optional<SkyRenderer> sky_;
  std::optional<ToneMapper> toneMapper_;
  std::unique_ptr<Hud> hud_;
  HudControls hudControls_;
  FrameTargets targets_;
  std::optional<StatsLineWriter> stats_;

  // Camera.
  FlyCamera camera_;
  bool cameraReady_ = false;
  float fovYDeg_ = 60.0f;
  float speed_ = 1.0f;
  std::optional<PathPlayer> player_;
  std::optional<Clock::time_point> pathStart_;  // when the first connection came up
  std::optional<CameraView> sentView_;
  uint64_t viewSerial_ = 0;

  // Movable objects (object_moves.h): the window's drag, the headless script.
  bool moveMode_ = false;
  std::optional<ObjectDrag> drag_;
  RigidTransform lastOffered_;  // the drag's last transform offered to the throttle
  MoveThrottle moveThrottle_;
  MoveTracker moveTracker_;
  uint64_t movesConnection_ = 0;  // the connection moveTracker_ counts on
  std::optional<MovesPlayer> movesPlayer_;
  std::optional<Clock::time_point> movesStart_;

  // Display state.
  ToneSettings tone_;
  ViewLuminance adaptation_;
  bool adapted_ = false;
  bool wireframe_ = false;
  std::string criterion_;  // the refinement criterion asked of the SMA; empty: its default
  std::optional<RefinementRequest> refinement_;  // what the SMA session was last asked for
  bool showHelp_ = false;
  bool screenshotRequested_ = false;
  std::string notice_;
  Clock::time_point noticeUntil_;
  Clock::time_point nextSlowFrameLog_;
  std::optional<Clock::time_point> quitArmedAt_;
  bool permanentFailureLogged_ = false;
  ProgressRate stage1Rate_;
  ProgressRate refinementRate_;

  // Counters.
  const Clock::time_point start_;
  uint64_t frames_ = 0;
  uint64_t framesDrawn_ = 0;  // rasterised (ClientOptions::drawOnlyWrittenFrames)
  HeadlessRun headlessRun_;
  SnapshotSchedule snapshots_;
  uint64_t pathSnapshots_ = 0;     // path-time snapshots written (--snapshot-path-interval)
  bool pathSnapshotsFailed_ = false;
  Clock::time_point rateWindowStart_ = start_;
  uint64_t rateWindowFrames_ = 0;
  uint64_t rateWindowBytes_ = 0;
  double fps_ = 0.0;
  double bytesPerSecond_ = 0.0;
};

Status ClientApp::Init() {
  if (!options_.headless) {
    auto window = Window::Open(options_.size.x, options_.size.y, "Penumbra", /*visible=*/true);
    if (!window) return window.error();
    window_ = window->get();
    context_ = std::move(*window);
  } else if (ResolveHeadlessBackend(options_.backend) == HeadlessBackend::kGlfw) {
    auto window = Window::Open(64, 64, "penumbra-client", /*visible=*/false);
    if (!window) return Fail(window.error().message + " (without an X server, use --gl egl)");
    window_ = window->get();
    context_ = std::move(*window);
  } else {
    auto context = CreateSurfacelessContext();
    if (!context) return context.error();
    context_ = std::move(*context);
  }
  log_->info("OpenGL: {}", context_->Describe());
  auto renderer = MeshRenderer::Create(options_.anisotropy);
  if (!renderer) return renderer.error();
  renderer_.emplace(std::move(*renderer));
  log_->info("textures filtered {}", renderer_->Anisotropy() > 1.0f
                                         ? fmt::format("with {:g}x anisotropy", renderer_->Anisotropy())
                                         : std::string("isotropically (--anisotropy N to change)"));
  auto sky = SkyRenderer::Create();
  if (!sky) return sky.error();
  sky_.emplace(std::move(*sky));
  auto toneMapper = ToneMapper::Create();
  if (!toneMapper) return toneMapper.error();
  toneMapper_.emplace(std::move(*toneMapper));
  if (!options_.headless) {
    auto hud = Hud::Create(*window_);
    if (!hud) return hud.error();
    hud_ = std::move(*hud);
  }
  if (options_.headless && options_.cameraPath) {
    player_.emplace(*options_.cameraPath);
    if (auto ok = targets_.Resize({options_.cameraPath->width * options_.supersample,
                                   options_.cameraPath->height * options_.supersample});
        !ok)
      return ok;
  }
  if (!options_.statsPath.empty()) {
    auto stats = StatsLineWriter::Open(options_.statsPath);
    if (!stats) return stats.error();
    stats_.emplace(std::move(*stats));
  }
  refinement_ = options_.refinement;
  if (refinement_) {
    if (refinement_->criterion) criterion_ = CriterionName(*refinement_->criterion);
    session_->SetSessionOptions(*refinement_);
  }
  session_->Start();
  log_->info("connecting to SMA {}", options_.sma.ToString());
  return Status::Ok();
}

int ClientApp::Run() {
  auto last = Clock::now();
  while (true) {
    const auto now = Clock::now();
    const double seconds = Seconds(now - last).count();
    last = now;
    ExplainSlowFrame(seconds, now);
    if (gStopSignal) {
      log_->info("stopping on signal {}", int(gStopSignal));
      return options_.headless ? 128 + int(gStopSignal) : 0;
    }
    if (window_) {
      window_->PollEvents();
      if (!options_.headless && window_->ShouldClose()) return permanentFailureLogged_ ? 1 : 0;
    }
    model_.Apply(session_->TakeEvents(), *session_);
    UpdateObjects(now);
    if (!PlayMoves(now)) return 1;
    if (auto ok = renderer_->Sync(model_); !ok) return Failed(ok.error().message);
    if (const std::string failure = session_->Status().permanentError; !failure.empty()) {
      // Retrying cannot fix it (another role, version or scene; a missing or
      // wrong token, TLS required): headless
      // ends with the reason as its last line; a window shows it until closed.
      if (options_.headless) return Failed(failure);
      permanentFailureLogged_ = true;
    }
    if (!EnsureCamera()) return 1;
    if (!options_.headless) {
      HandleInput(seconds);
      if (auto ok = targets_.Resize(window_->FramebufferSize()); !ok) {
        // A minimised window has no pixels: draw nothing, keep the session.
        window_->SwapBuffers();
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        continue;
      }
    }
    // A path-time snapshot frame shows the pose of exactly its time.
    std::optional<double> pathSnapshotTime;
    if (options_.headless && options_.snapshotPathInterval > 0.0 && pathStart_ && !pathSnapshotsFailed_) {
      const double time = double(pathSnapshots_) * options_.snapshotPathInterval;
      if (Seconds(now - *pathStart_).count() >= time) pathSnapshotTime = time;
    }
    const auto viewTime =
        pathSnapshotTime ? *pathStart_ + std::chrono::duration_cast<Clock::duration>(Seconds(*pathSnapshotTime)) : now;
    if (auto view = CurrentView(viewTime); view && (!sentView_ || !SameView(*view, *sentView_))) {
      viewSerial_ = session_->SetView(*view);
      sentView_ = view;
    }
    UpdateAdaptation(seconds);
    bool finishing = false;
    if (options_.headless) {
      const HeadlessObservation seen = ObserveHeadless(now);
      finishing = headlessRun_.GoalMet(seen, now);
      if (auto failure = headlessRun_.Failure(seen, now)) return Failed(*failure);
    }

    // Headless frames that no file will hold are seen by nobody: with
    // --draw-only-written-frames they are not rasterised.
    const bool written = pathSnapshotTime || finishing || SnapshotDue(now);
    if (!options_.headless || !options_.drawOnlyWrittenFrames || written) {
      Render();
      ++framesDrawn_;
    }
    if (screenshotRequested_) SaveInteractiveScreenshot();
    if (window_ && !options_.headless) {
      targets_.BlitToDefault(window_->FramebufferSize());
      DrawHud();
      window_->SwapBuffers();
    }
    ++frames_;
    MaybeWriteSnapshot(now);
    if (pathSnapshotTime) WritePathSnapshot(*pathSnapshotTime);
    UpdateRates(now);
    WriteStats(now);
    if (finishing) return Finish();

    const double maxFps = options_.maxFps > 0.0 ? options_.maxFps : (options_.headless ? 30.0 : 60.0);
    std::this_thread::sleep_until(now + std::chrono::duration_cast<Clock::duration>(Seconds(1.0 / maxFps)));
  }
}

// Places the camera once the first SceneInfo names the presets. Returns false
// (after logging why) when a headless run asked for a preset the SMA lacks.
bool ClientApp::EnsureCamera() {
  const ClientScene* scene = model_.Scene();
  if (!scene) return true;
  if (!pathStart_ && model_.Online()) pathStart_ = Clock::now();
  if (cameraReady_ || (options_.headless && player_)) return true;

  int preset = 0;
  if (!options_.cameraPreset.empty()) {
    preset = -1;
    std::string names;
    for (size_t i = 0; i < scene->cameras.size(); ++i) {
      if (scene->cameras[i].name == options_.cameraPreset) preset = int(i);
      names += (names.empty() ? "" : ", ") + scene->cameras[i].name;
    }
    if (preset < 0) {
      if (options_.headless) {
        Failed(fmt::format("the SMA's scene has no camera preset '{}' (it has: {})", options_.cameraPreset, names));
        return false;
      }
      log_->warn("no camera preset '{}' (the scene has: {}); starting at the first", options_.cameraPreset, names);
      preset = 0;
    }
  }
  if (options_.headless) {
    if (scene->cameras.empty()) {
      Failed("the SMA's scene has no camera preset; give --camera-path");
      return false;
    }
    player_.emplace(StillPath(scene->cameras[size_t(preset)], options_.size.x, options_.size.y));
    if (auto ok = targets_.Resize(options_.size * options_.supersample); !ok) {
      Failed(ok.error().message);
      return false;
    }
    return true;
  }
  const Vec3 lo = scene->bounds.min, hi = scene->bounds.max;
  speed_ = std::max(kSpeedPerSceneSize * glm::length(hi - lo), 0.01f);
  if (!scene->cameras.empty()) {
    ApplyPreset(preset);
  } else {
    // No preset: look at the middle of the scene from outside its bounds.
    const Vec3 centre = 0.5f * (lo + hi);
    camera_.SetPose(CameraPose{centre + Vec3(0.0f, 0.0f, glm::length(hi - lo)), centre, Vec3(0.0f, 1.0f, 0.0f)});
  }
  cameraReady_ = true;
  window_->SetTitle(fmt::format("Penumbra - {}", scene->name));
  return true;
}

void ClientApp::UpdateDrag(bool pressed, double scroll, Clock::time_point now) {
  const ClientScene* scene = model_.Scene();
  if (!scene || !sentView_ || !model_.Online()) {
    drag_.reset();
    moveThrottle_ = MoveThrottle();  // nothing of a drag on a lost connection is sent
    return;
  }
  MeshStore& mesh = model_.Mesh();
  const PinholeCamera camera(*sentView_);
  const glm::vec2 cursor = window_->CursorPixel();
  const Ray ray{camera.Origin(), camera.DirectionThrough(cursor.x, cursor.y)};
  if (!drag_ && pressed) {
    // The objects' boxes first: a ray that misses them all needs no scan of
    // the held triangles. Then the triangles, as drawn: the visible surface
    // under the cursor decides (a wall in front of the box hides it).
    std::vector<Bounds3> worldBounds;
    worldBounds.reserve(scene->objects.size());
    for (uint32_t id = 1; id <= scene->objects.size(); ++id)
      worldBounds.push_back(mesh.DisplayedTransform(id).ApplyBounds(scene->objects[id - 1].objectBounds));
    const auto pick = PickObjectBounds(ray, worldBounds) ? PickHeldTriangle(ray, mesh) : std::nullopt;
    if (!pick || pick->object == 0) {
      notice_ = "No movable object under the cursor";
      noticeUntil_ = now + std::chrono::seconds(2);
      return;
    }
    const ClientObject& object = scene->objects[pick->object - 1];
    if (object.animated) {
      notice_ = fmt::format("'{}' follows its animation path and cannot be moved", object.name);
      noticeUntil_ = now + std::chrono::seconds(3);
      return;
    }
    drag_.emplace(pick->object, mesh.DisplayedTransform(pick->object), pick->point, camera.Forward());
    lastOffered_ = mesh.DisplayedTransform(pick->object);
    log_->info("grabbed object {} ('{}')", pick->object, object.name);
  }
  if (!drag_) return;
  if (scroll != 0.0) drag_->Push(float(scroll) * kDragDepthStepPerSceneSize * glm::length(scene->bounds.Diagonal()));
  const RigidTransform t = drag_->At(ray);
  // Optimistic: drawn where the mouse put it at once (object_moves.h).
  mesh.SetLocalTransform(drag_->Object(), t);
  if (!(t == lastOffered_)) {
    moveThrottle_.Offer(drag_->Object(), t);
    lastOffered_ = t;
  }
  const bool released = !window_->LeftButtonHeld();
  if (auto due = moveThrottle_.Due(now, /*flush=*/released)) SendMove(due->object, due->transform);
  if (released) {
    log_->info("released object {} at {}", drag_->Object(), Describe(t));
    drag_.reset();
  }
}

void ClientApp::SendMove(uint32_t object, const RigidTransform& t) {
  const uint64_t requestId = session_->MoveObject(object, t);
  moveTracker_.Sent(object, t, requestId);
}

void ClientApp::UpdateObjects(Clock::time_point now) {
  MeshStore& mesh = model_.Mesh();
  if (model_.ConnectionNumber() != movesConnection_) {
    // A new connection emptied the mesh: nothing sent before is pending, and
    // the SceneInfo says where everything is now.
    movesConnection_ = model_.ConnectionNumber();
    moveTracker_.Clear();
    drag_.reset();
    moveThrottle_ = MoveThrottle();
  }
  for (const SmaErrorReceived& error : model_.TakeSmaErrors()) {
    notice_ = error.message;
    noticeUntil_ = now + kNoticeDuration;
    if (!error.move) continue;
    // A refused move changed nothing: the object goes back where the SMA has it.
    if (const uint32_t object = moveTracker_.Refused(error.requestId); object != 0)
      log_->warn("move of object {} refused; it stays where the SMA has it", object);
  }
  moveTracker_.Confirm(mesh);
  for (uint32_t object : moveTracker_.Expire(now))
    log_->warn("the SMA neither confirmed nor refused the last move of object {} within {} s (another client's move "
               "may have won); showing it where the SMA has it",
               object, kMovePendingTimeout.count());
  // Headless images show what the SMA confirmed, so that a snapshot after a
  // scripted move is the SMA's state, not the script's.
  if (options_.headless) return;
  for (uint32_t id = 1; id <= mesh.ObjectCount(); ++id) {
    if (drag_ && drag_->Object() == id) continue;
    // Until the SMA confirms the last move sent, the object stays where it was sent.
    mesh.SetLocalTransform(id, moveTracker_.LastSent(id));
  }
}

bool ClientApp::PlayMoves(Clock::time_point now) {
  if (options_.moves.empty() || !options_.headless) return true;
  if (!movesPlayer_) {
    // By default the script starts on a converged image, so what a move
    // changes is not mixed up with the first view still arriving; or with
    // the camera path, from the first connection.
    if (!model_.Scene() || !model_.Online()) return true;
    if (!options_.movesFromConnection && !model_.Converged(viewSerial_)) return true;
    auto bound = BindMoves(options_.moves, *model_.Scene());
    if (!bound) {
      Failed("--moves: " + bound.error().message);
      return false;
    }
    movesPlayer_.emplace(std::move(*bound));
    movesStart_ = options_.movesFromConnection && pathStart_ ? *pathStart_ : now;
    log_->info("{}: playing {} scripted moves",
               options_.movesFromConnection ? "from the first connection" : "first view converged",
               movesPlayer_->Total());
  }
  for (const BoundMove& move : movesPlayer_->Due(now - *movesStart_)) {
    log_->info("scripted move (line {}) at {:.2f} s: object {} ('{}') to {}", move.line,
               Seconds(now - *movesStart_).count(), move.object, model_.Scene()->objects[move.object - 1].name,
               Describe(move.objectToWorld));
    SendMove(move.object, move.objectToWorld);
  }
  return true;
}

std::string ClientApp::ObjectsLine() const {
  const ClientScene* scene = model_.Scene();
  if (!scene || scene->objects.empty()) return "";
  if (drag_)
    return fmt::format("Moving '{}' (wheel: farther / nearer)", scene->objects[drag_->Object() - 1].name);
  if (moveMode_) return "Move mode (M): left-drag a movable object";
  return fmt::format("{} movable object{}: M to move them", scene->objects.size(),
                     scene->objects.size() == 1 ? "" : "s");
}

void ClientApp::ApplyPreset(int index) {
  const ClientScene* scene = model_.Scene();
  if (!scene || index < 0 || size_t(index) >= scene->cameras.size()) return;
  const CameraPreset& preset = scene->cameras[size_t(index)];
  camera_.SetPose(preset.pose);
  fovYDeg_ = preset.fovYDeg;
}

void ClientApp::HandleInput(double seconds) {
  const bool hudHasKeyboard = hud_->WantsKeyboard();
  for (const KeyPress& key : window_->TakeKeyPresses())
    if (!hudHasKeyboard) OnKey(key);
  // A click on the HUD is the HUD's; elsewhere it captures the mouse to look,
  // or, in move mode, grabs the object under the cursor.
  const bool hudHasMouse = hud_->WantsMouse() && !window_->CursorCaptured();
  const bool click = window_->TakeClick() && !window_->CursorCaptured() && !hudHasMouse;
  const double scroll = window_->TakeScroll();
  if (moveMode_ && !window_->CursorCaptured()) {
    UpdateDrag(click, hudHasMouse ? 0.0 : scroll, Clock::now());
  } else {
    if (click) window_->SetCursorCaptured(true);
    if (!hudHasMouse) speed_ *= std::pow(kSpeedStep, float(scroll));
  }
  const glm::vec2 motion = window_->TakeMouseMotion();
  if (!cameraReady_) return;
  camera_.Turn(motion.x, motion.y, kTurnRadiansPerPixel);
  auto axis = [&](std::initializer_list<int> plus, std::initializer_list<int> minus) {
    float value = 0.0f;
    for (int k : plus) value += window_->KeyHeld(k) ? 1.0f : 0.0f;
    for (int k : minus) value -= window_->KeyHeld(k) ? 1.0f : 0.0f;
    return std::clamp(value, -1.0f, 1.0f);
  };
  MoveInput move;
  move.forward = axis({GLFW_KEY_W, GLFW_KEY_UP}, {GLFW_KEY_S, GLFW_KEY_DOWN});
  move.right = axis({GLFW_KEY_D, GLFW_KEY_RIGHT}, {GLFW_KEY_A, GLFW_KEY_LEFT});
  move.up = axis({GLFW_KEY_E, GLFW_KEY_PAGE_UP}, {GLFW_KEY_Q, GLFW_KEY_PAGE_DOWN});
  const bool fast = window_->KeyHeld(GLFW_KEY_LEFT_SHIFT) || window_->KeyHeld(GLFW_KEY_RIGHT_SHIFT);
  camera_.Move(move, speed_ * (fast ? 4.0f : 1.0f), float(seconds));
}

void ClientApp::OnKey(const KeyPress& key) {
  switch (key.key) {
    case GLFW_KEY_ESCAPE: {
      if (key.repeat) return;  // holding Esc is one press
      // Esc releases the mouse; with the mouse free, a second Esc within
      // two seconds quits (closing the window quits at once).
      const auto now = Clock::now();
      if (window_->CursorCaptured()) {
        window_->SetCursorCaptured(false);
        quitArmedAt_.reset();
      } else if (quitArmedAt_ && now - *quitArmedAt_ < kQuitConfirmWindow) {
        window_->RequestClose();
      } else {
        quitArmedAt_ = now;
        log_->info("Esc: press it again within {} s to quit", kQuitConfirmWindow.count());
      }
      return;
    }
    case GLFW_KEY_TAB: window_->SetCursorCaptured(!window_->CursorCaptured()); return;
    case GLFW_KEY_R:
    case GLFW_KEY_HOME: ApplyPreset(0); return;
    case GLFW_KEY_F: wireframe_ = !wireframe_; return;
    case GLFW_KEY_C: CycleCriterion(); return;
    case GLFW_KEY_T:
      tone_.op = tone_.op == ToneOperator::kDrago ? ToneOperator::kExposureGamma : ToneOperator::kDrago;
      return;
    case GLFW_KEY_MINUS:
    case GLFW_KEY_KP_SUBTRACT: tone_.exposureStops -= kExposureStep; return;
    case GLFW_KEY_EQUAL:
    case GLFW_KEY_KP_ADD: tone_.exposureStops += kExposureStep; return;
    case GLFW_KEY_G:
      tone_.gamma = std::clamp(tone_.gamma + ((key.mods & GLFW_MOD_SHIFT) ? -kGammaStep : kGammaStep), 1.0f, 3.0f);
      return;
    case GLFW_KEY_LEFT_BRACKET: speed_ /= kSpeedStep; return;
    case GLFW_KEY_RIGHT_BRACKET: speed_ *= kSpeedStep; return;
    case GLFW_KEY_P:
    case GLFW_KEY_F12: screenshotRequested_ = true; return;
    case GLFW_KEY_H:
    case GLFW_KEY_F1: showHelp_ = !showHelp_; return;
    case GLFW_KEY_M:
      if (key.repeat) return;
      if (!model_.Scene() || model_.Scene()->objects.empty()) {
        notice_ = "This scene has no movable objects";
        noticeUntil_ = Clock::now() + std::chrono::seconds(3);
        return;
      }
      moveMode_ = !moveMode_;
      // Dragging needs the cursor; looking around needs it captured.
      if (moveMode_) window_->SetCursorCaptured(false);
      if (!moveMode_ && drag_) {
        // Leaving the mode ends a drag where it is.
        if (auto due = moveThrottle_.Due(Clock::now(), /*flush=*/true)) SendMove(due->object, due->transform);
        drag_.reset();
      }
      return;
    default:
      if (key.key >= GLFW_KEY_1 && key.key <= GLFW_KEY_9) ApplyPreset(key.key - GLFW_KEY_1);
  }
}

std::optional<CameraView> ClientApp::CurrentView(Clock::time_point now) const {
  if (options_.headless) {
    if (!player_ || !pathStart_) return std::nullopt;
    // The SMA's visibility samples the pixel centres of what is rendered.
    CameraView view = player_->ViewAt(now - *pathStart_);
    view.width *= options_.supersample;
    view.height *= options_.supersample;
    return view;
  }
  if (!cameraReady_) return std::nullopt;
  return CameraView{camera_.Pose(), fovYDeg_, targets_.Size().x, targets_.Size().y};
}

void ClientApp::UpdateAdaptation(double seconds) {
  if (model_.Mesh().VertexCount() == 0) return;  // keep the last adaptation while nothing is held
  const ViewLuminance target = model_.Mesh().HeldLuminance();
  // Headless images adapt at once, so that a screenshot does not depend on timing.
  if (!adapted_ || options_.headless) {
    adaptation_ = target;
    adapted_ = true;
    return;
  }
  const float a = float(1.0 - std::exp(-seconds / kAdaptationSeconds));
  auto blend = [a](float from, float to) { return std::exp(glm::mix(std::log(from), std::log(to), a)); };
  adaptation_.max = blend(adaptation_.max, target.max);
  adaptation_.logAverage = blend(adaptation_.logAverage, target.logAverage);
}

HeadlessObservation ClientApp::ObserveHeadless(Clock::time_point now) const {
  const SessionStatus status = session_->Status();
  const MeshStore& mesh = model_.Mesh();
  const auto& report = model_.LastSmaReport();
  HeadlessObservation seen;
  seen.framesDrawn = frames_;
  // Scripted moves are part of the path: done once all are sent and the SMA
  // has confirmed (or refused) each.
  const bool movesDone = options_.moves.empty() || (movesPlayer_ && movesPlayer_->Finished() && moveTracker_.Empty());
  seen.pathFinished = player_ && pathStart_ && player_->Finished(now - *pathStart_) && movesDone;
  seen.converged = model_.Converged(viewSerial_);
  seen.countersCurrent = report && report->atSequence == mesh.LastSequence();
  seen.connection = status.state;
  seen.disconnectedSince = status.disconnectedSince;
  seen.lastError = status.lastError;
  seen.samplesPending = mesh.PendingSamples();
  seen.trianglesHeld = mesh.TriangleCount();
  return seen;
}

// Depth range: the scene as loaded, and wherever its objects are now.
Bounds3 ClientApp::DepthBounds() const {
  const ClientScene* scene = model_.Scene();
  Bounds3 bounds = scene ? scene->bounds : Bounds3{};
  if (scene)
    for (uint32_t id = 1; id <= scene->objects.size(); ++id) {
      const Bounds3 b = model_.Mesh().DisplayedTransform(id).ApplyBounds(scene->objects[id - 1].objectBounds);
      if (!b.Empty()) {
        bounds.Extend(b.min);
        bounds.Extend(b.max);
      }
    }
  return bounds;
}

// A frame that took seconds (a headless client on a software rasteriser has
// been seen to draw one frame a minute after a long walk, cause unknown):
// says what the mesh draw asked of the rasteriser, so the log tells an
// unusual mesh from a slow GL implementation. At most one line per 10 s.
void ClientApp::ExplainSlowFrame(double seconds, Clock::time_point now) {
  constexpr double kSlowFrameSeconds = 2.0;
  if (seconds < kSlowFrameSeconds || frames_ == 0 || !sentView_ || !model_.Scene() || now < nextSlowFrameLog_) return;
  nextSlowFrameLog_ = now + std::chrono::seconds(10);
  const glm::ivec2 size = targets_.Size();
  const RasterLoad load = MeasureRasterLoad(model_.Mesh(), WorldToClip(*sentView_, DepthBounds()), size.x, size.y);
  const CameraPose& pose = sentView_->pose;
  log_->warn("frame {} took {:.1f} s; view from ({:.3g} {:.3g} {:.3g}) to ({:.3g} {:.3g} {:.3g}), up ({:.3g} {:.3g} {:.3g}); {}",
             frames_, seconds, pose.eye.x, pose.eye.y, pose.eye.z, pose.target.x, pose.target.y, pose.target.z,
             pose.up.x, pose.up.y, pose.up.z, Describe(load, size.x, size.y));
  if (std::getenv("PENUMBRA_CLIENT_TIME_SLOW_FRAMES")) {
    targets_.BeginRadiance();
    for (const auto& t : renderer_->TimeGroupDraws(WorldToClip(*sentView_, DepthBounds())))
      log_->warn("  group of texture {} ({}x{}), {} slots: {:.3f} s drawn, {:.3f} s untextured, {:.3f} s isotropic",
                 t.texture, t.textureWidth, t.textureHeight, t.slots, t.seconds, t.secondsUntextured,
                 t.secondsIsotropic);
  }
}

void ClientApp::Render() {
  if (targets_.Size().x == 0) return;
  const ClientScene* scene = model_.Scene();
  const std::optional<glm::mat4> worldToClip =
      sentView_ && scene ? std::optional(WorldToClip(*sentView_, DepthBounds())) : std::nullopt;
  targets_.BeginRadiance();
  if (worldToClip && scene->sky) sky_->Draw(*worldToClip, *scene->sky);
  if (worldToClip) renderer_->DrawRadiance(*worldToClip);
  targets_.BeginDisplay();
  toneMapper_->Draw(targets_.RadianceTexture(), adaptation_, scene ? scene->toneMapping : DragoParams{}, tone_);
  if (wireframe_ && worldToClip) renderer_->DrawWireframe(*worldToClip, kWireColour);
}

void ClientApp::DrawHud() {
  const auto now = Clock::now();
  const SessionStatus status = session_->Status();
  const ClientScene* scene = model_.Scene();
  const MeshStore& mesh = model_.Mesh();
  HudState hud;
  hud.scene = scene ? scene->name : "";
  hud.sma = options_.sma.ToString();
  hud.connected = status.state == ConnectionState::kConnected;
  hud.connection = status.state == ConnectionState::kWaiting ? "reconnecting (" + status.lastError + ")"
                                                             : ToString(status.state);
  // An SMA listens only once its scene is loaded (a 2 M-triangle scene takes
  // 5-15 s): say so rather than leave a bare "connection refused".
  if (status.state == ConnectionState::kWaiting && status.lastError.find("refused") != std::string::npos)
    hud.connection += "; an SMA accepts clients once its scene is loaded";
  hud.permanentError = status.permanentError;
  hud.progress = mesh.Progress();
  hud.pendingSamples = mesh.PendingSamples();
  hud.converged = model_.Converged(viewSerial_);
  hud.refining = mesh.Refining();
  stage1Rate_.Update(hud.progress.stage1Done, hud.progress.stage1Total, now);
  refinementRate_.Update(hud.progress.refinementDone, hud.progress.refinementTotal, now);
  hud.stage1PerSecond = stage1Rate_.PerSecond();
  hud.stage1Left = stage1Rate_.TimeLeft();
  hud.refinementPerSecond = refinementRate_.PerSecond();
  hud.triangles = mesh.TriangleCount();
  hud.vertices = mesh.VertexCount();
  hud.framesPerSecond = fps_;
  hud.bytesPerSecond = bytesPerSecond_;
  hud.moveToFirstUpdateMs = status.viewToFirstDeltaMs;
  hud.walkSpeed = speed_;
  hud.objects = ObjectsLine();
  if (quitArmedAt_ && now - *quitArmedAt_ < kQuitConfirmWindow)
    hud.notice = "Press Esc again to quit (the mouse is free)";
  else if (!notice_.empty() && now < noticeUntil_)
    hud.notice = notice_;

  hudControls_.criterion = criterion_;
  hudControls_.exposureStops = tone_.exposureStops;
  hudControls_.dragoToneMapping = tone_.op == ToneOperator::kDrago;
  hudControls_.gamma = tone_.gamma;
  hudControls_.wireframe = wireframe_;
  hud_->SetMouseEnabled(!window_->CursorCaptured());
  if (!hud_->Draw(hud, hudControls_, showHelp_)) return;
  if (hudControls_.criterion != criterion_) SetCriterion(hudControls_.criterion);
  tone_.exposureStops = hudControls_.exposureStops;
  tone_.op = hudControls_.dragoToneMapping ? ToneOperator::kDrago : ToneOperator::kExposureGamma;
  tone_.gamma = hudControls_.gamma;
  wireframe_ = hudControls_.wireframe;
}

void ClientApp::UpdateRates(Clock::time_point now) {
  ++rateWindowFrames_;
  const double elapsed = Seconds(now - rateWindowStart_).count();
  if (now - rateWindowStart_ < kRateWindow && fps_ > 0.0) return;
  const uint64_t bytes = session_->Status().bytesReceived;
  if (elapsed > 0.0) {
    fps_ = double(rateWindowFrames_) / elapsed;
    bytesPerSecond_ = double(bytes - std::min(bytes, rateWindowBytes_)) / elapsed;
  }
  rateWindowStart_ = now;
  rateWindowFrames_ = 0;
  rateWindowBytes_ = bytes;
}

void ClientApp::WriteStats(Clock::time_point now) {
  if (!stats_) return;
  const SessionStatus status = session_->Status();
  const MeshStore& mesh = model_.Mesh();
  FrameStats s;
  s.frame = frames_;
  s.timeSeconds = Seconds(now - start_).count();
  s.trianglesHeld = mesh.TriangleCount();
  s.verticesHeld = mesh.VertexCount();
  s.bytesReceived = status.bytesReceived;
  s.samplesPending = mesh.PendingSamples();
  s.converged = model_.Converged(viewSerial_);
  s.refining = mesh.Refining();
  s.trianglesAdded = mesh.TrianglesAdded();
  s.viewToFirstDeltaMs = status.viewToFirstDeltaMs;
  s.fps = fps_;
  s.memory = ReadProcessMemory();
  s.connection = ToString(status.state);
  s.connections = status.connections;
  s.sma = model_.LastSmaReport();
  s.sceneEpoch = mesh.SceneEpoch();
  s.movesSent = moveTracker_.SentCount();
  s.movesPending = moveTracker_.Size();
  if (auto ok = stats_->Write(s); !ok) {
    log_->error("{}; no more statistics lines", ok.error().message);
    stats_.reset();
  }
}

void ClientApp::CycleCriterion() {
  const auto criteria = Criteria();
  size_t next = 0;
  for (size_t i = 0; i < criteria.size(); ++i)
    if (criterion_ == criteria[i].name) next = (i + 1) % criteria.size();
  SetCriterion(std::string(criteria[next].name));
}

void ClientApp::SetCriterion(const std::string& criterion) {
  auto parsed = ParseCriterion(criterion);
  if (!parsed) return;  // the panel offers only the table's names
  criterion_ = criterion;
  if (!refinement_) refinement_.emplace();
  refinement_->criterion = *parsed;
  session_->SetSessionOptions(*refinement_);
  notice_ = "refinement criterion: " + criterion_;
  noticeUntil_ = Clock::now() + std::chrono::seconds(3);
}

bool ClientApp::SnapshotDue(Clock::time_point now) const {
  const MeshStore& mesh = model_.Mesh();
  return snapshots_.Due(now, mesh.TriangleCount(), mesh.LastSequence(), frames_).has_value();
}

void ClientApp::MaybeWriteSnapshot(Clock::time_point now) {
  const MeshStore& mesh = model_.Mesh();
  const auto path = snapshots_.Due(now, mesh.TriangleCount(), mesh.LastSequence(), frames_);
  if (!path) return;
  if (auto ok = WriteScreenshot(*path); !ok) {
    log_->error("snapshot: {}; no more snapshots", ok.error().message);
    snapshots_.Stop();
    return;
  }
  snapshots_.Written(now, mesh.LastSequence());
}

void ClientApp::WritePathSnapshot(double pathTime) {
  const auto path = options_.snapshotPrefix.string() + fmt::format("_t{:06}.exr", std::llround(pathTime * 1000.0));
  if (auto ok = WriteScreenshot(path); !ok) {
    log_->error("snapshot: {}; no more snapshots", ok.error().message);
    pathSnapshotsFailed_ = true;
    return;
  }
  ++pathSnapshots_;
}

int ClientApp::Finish() {
  if (!options_.screenshot.empty()) {
    if (auto ok = WriteScreenshot(options_.screenshot); !ok) return Failed(ok.error().message);
  }
  const MeshStore& mesh = model_.Mesh();
  log_->info("done after {} frames ({} drawn): {} triangles and {} vertices held{}", frames_, framesDrawn_,
             mesh.TriangleCount(), mesh.VertexCount(),
             options_.screenshot.empty() ? "" : "; wrote " + options_.screenshot.string());
  return 0;
}

Status ClientApp::WriteScreenshot(const std::filesystem::path& path) {
  const glm::ivec2 size = targets_.Size();
  // An .exr carries the coverage as alpha (0 where nothing was drawn), so
  // that a surface shaded black is told from a hole in the mesh.
  const bool withCoverage = StoresCoverage(path);
  std::vector<float> coverage;
  std::vector<float> pixels = IsRadianceFile(path) ? targets_.ReadRadiance(withCoverage ? &coverage : nullptr)
                                                   : targets_.ReadDisplay();
  // A box of n x n samples per pixel (the display image too: an
  // approximation that resolves edges the way a multisampled display does).
  const int n = std::max(options_.supersample, 1);
  pixels = BoxFilter(pixels, size.x, size.y, n);
  if (withCoverage) coverage = BoxFilter(coverage, size.x, size.y, n, 1);
  return WriteImage(path, size.x / n, size.y / n, pixels, coverage);
}

void ClientApp::SaveInteractiveScreenshot() {
  screenshotRequested_ = false;
  const std::string stem = ScreenshotStem(model_.Scene() ? model_.Scene()->name : "empty", LocalTimestamp());
  const auto png = options_.screenshotDir / (stem + ".png");
  const auto exr = options_.screenshotDir / (stem + ".exr");
  std::error_code ec;
  std::filesystem::create_directories(options_.screenshotDir, ec);
  Status ok = ec ? Fail(fmt::format("cannot create the screenshot folder {}: {} (see --screenshot-dir)",
                                    options_.screenshotDir.string(), ec.message()))
                 : Status::Ok();
  if (ok) ok = WriteScreenshot(png);
  if (ok) ok = WriteScreenshot(exr);
  notice_ = ok ? fmt::format("Screenshot saved in {}: {}.png and .exr", options_.screenshotDir.string(), stem)
               : ok.error().message;
  noticeUntil_ = Clock::now() + kNoticeDuration;
  if (ok)
    log_->info("screenshot saved: {} and {}", png.string(), exr.string());
  else
    log_->error("screenshot: {}", notice_);
}

int ClientApp::Failed(const std::string& message) const {
  log_->error("{}", message);
  return 1;
}

int RunClient(const ClientOptions& options) {
  gStopSignal = 0;
  std::signal(SIGINT, OnStopSignal);
  std::signal(SIGTERM, OnStopSignal);
  ClientApp app(options);
  if (auto ok = app.Init(); !ok) {
    Logger("client")->error("{}", ok.error().message);
    return 1;
  }
  return app.Run();
}

}  // namespace penumbra::client::gl
