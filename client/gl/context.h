#pragma once
// OpenGL 3.3 core contexts for the client, with libepoxy loading the
// functions: a GLFW window (visible for the walkthrough, hidden for headless
// runs under an X server such as Xvfb), or an EGL context on Mesa's
// surfaceless platform, which needs no X server at all. Headless rendering
// goes to framebuffer objects either way (FrameTargets), so the same drawing
// code serves every context.
//
// Threads: create, use and destroy a context on the render thread (for GLFW,
// the process's main thread).

#include <memory>
#include <string>
#include <vector>

#include <glm/vec2.hpp>

#include "penumbra/common/expected.h"

struct GLFWwindow;

namespace penumbra::client::gl {

/// A current OpenGL context; destroying it releases the context.
class Context {
 public:
  virtual ~Context() = default;
  /// "GLFW window" / "EGL surfaceless", with the GL renderer and version.
  virtual std::string Describe() const = 0;
};

enum class HeadlessBackend { kAuto, kGlfw, kEgl };

/// kAuto picks GLFW (a hidden window) when DISPLAY is set and EGL
/// surfaceless otherwise.
HeadlessBackend ResolveHeadlessBackend(HeadlessBackend requested);

/// An EGL context without any surface (EGL_PLATFORM_SURFACELESS_MESA).
Expected<std::unique_ptr<Context>> CreateSurfacelessContext();

struct KeyPress {
  int key = 0;   // GLFW_KEY_*
  int mods = 0;  // GLFW_MOD_*
  bool repeat = false;  // the key is held: an auto-repeat, not a new press
};

/// A GLFW window and its context, with the input gathered by PollEvents().
class Window final : public Context {
 public:
  /// Opens a window of `width` x `height` screen units; `visible` false
  /// gives a hidden window for offscreen rendering. Needs an X display.
  static Expected<std::unique_ptr<Window>> Open(int width, int height, const std::string& title, bool visible);
  ~Window() override;
  std::string Describe() const override;

  bool ShouldClose() const;
  void RequestClose();
  /// Processes window-system events; fills the input queues below.
  void PollEvents();
  void SwapBuffers();
  glm::ivec2 FramebufferSize() const;
  void SetTitle(const std::string& title);
  /// For libraries that take GLFW's window (the HUD's ImGui backend).
  GLFWwindow* Handle() const { return window_; }
  /// The monitor's content scale (1 on ordinary screens; 2 on HiDPI).
  float ContentScale() const;

  bool KeyHeld(int key) const;
  /// Key presses (and repeats) since the last call, in order.
  std::vector<KeyPress> TakeKeyPresses();
  /// Mouse motion in pixels since the last call, while the cursor is captured.
  glm::vec2 TakeMouseMotion();
  /// Vertical scroll since the last call.
  double TakeScroll();
  /// Whether the left button was pressed since the last call.
  bool TakeClick();
  /// The cursor's position in framebuffer pixels from the top-left corner.
  glm::vec2 CursorPixel() const;
  /// Whether the left mouse button is down now.
  bool LeftButtonHeld() const;
  /// A captured cursor is hidden and its motion turns the camera.
  void SetCursorCaptured(bool captured);
  bool CursorCaptured() const { return captured_; }

 private:
  explicit Window(GLFWwindow* window) : window_(window) {}
  static void OnKey(GLFWwindow* w, int key, int scancode, int action, int mods);
  static void OnCursor(GLFWwindow* w, double x, double y);
  static void OnScroll(GLFWwindow* w, double dx, double dy);
  static void OnButton(GLFWwindow* w, int button, int action, int mods);

  GLFWwindow* window_ = nullptr;
  std::vector<KeyPress> presses_;
  glm::dvec2 lastCursor_{0.0};
  bool haveCursor_ = false;
  glm::vec2 motion_{0.0f};
  double scroll_ = 0.0;
  bool clicked_ = false;
  bool captured_ = false;
};

}  // namespace penumbra::client::gl
