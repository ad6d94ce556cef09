#include "gl/context.h"

#include <algorithm>
#include <cstdlib>
#include <cstring>

#include <epoxy/egl.h>
#include <epoxy/gl.h>
// GLFW after epoxy: epoxy's header must come first, and GLFW must not pull
// in the system GL header.
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <fmt/format.h>

#include "penumbra/common/logging.h"

// Leak checking is off in ASan builds of every process that links the GL
// client (penumbra-client, client_gl_test). Mesa's driver, loaded and
// unloaded inside EGL/GLX, leaves two 56-byte blocks at exit, allocated on
// its own threads by code unloaded by then: LeakSanitizer can neither name
// them nor be told to skip them, and a scoped disabler around context
// creation does not reach those threads. AddressSanitizer still checks every
// access; the client core's leaks are checked in client_core_test (no GL).
#if defined(__SANITIZE_ADDRESS__)
extern "C" const char* __lsan_default_options() { return "detect_leaks=0"; }
#endif

namespace penumbra::client::gl {

namespace {

std::string GlDescription() {
  const auto* renderer = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  const auto* version = reinterpret_cast<const char*>(glGetString(GL_VERSION));
  return fmt::format("{}, OpenGL {}", renderer ? renderer : "?", version ? version : "?");
}

// GLFW reports errors through a callback; the last one explains a failure.
std::string& LastGlfwError() {
  static std::string error;
  return error;
}

void OnGlfwError(int code, const char* description) {
  LastGlfwError() = description ? description : fmt::format("GLFW error 0x{:x}", code);
  Logger("client.gl")->debug("GLFW: {}", LastGlfwError());
}

class SurfacelessContext final : public Context {
 public:
  SurfacelessContext(EGLDisplay display, EGLContext context) : display_(display), context_(context) {}
  ~SurfacelessContext() override {
    eglMakeCurrent(display_, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    eglDestroyContext(display_, context_);
    eglTerminate(display_);
  }
  std::string Describe() const override { return "EGL surfaceless (" + GlDescription() + ")"; }

 private:
  EGLDisplay display_;
  EGLContext context_;
};

}  // namespace

HeadlessBackend ResolveHeadlessBackend(HeadlessBackend requested) {
  if (requested != HeadlessBackend::kAuto) return requested;
  const char* display = std::getenv("DISPLAY");
  return display && *display ? HeadlessBackend::kGlfw : HeadlessBackend::kEgl;
}

Expected<std::unique_ptr<Context>> CreateSurfacelessContext() {
  const char* clientExtensions = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
  if (!clientExtensions || !std::strstr(clientExtensions, "EGL_MESA_platform_surfaceless"))
    return Fail("EGL: the surfaceless platform (EGL_MESA_platform_surfaceless) is not available");
  EGLDisplay display = eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
  if (display == EGL_NO_DISPLAY) return Fail("EGL: no surfaceless display");
  EGLint major = 0, minor = 0;
  if (!eglInitialize(display, &major, &minor))
    return Fail(fmt::format("EGL: cannot initialize the surfaceless display (0x{:x})", eglGetError()));
  if (!eglBindAPI(EGL_OPENGL_API)) {
    eglTerminate(display);
    return Fail("EGL: desktop OpenGL is not available");
  }
  const EGLint attributes[] = {EGL_CONTEXT_MAJOR_VERSION, 3, EGL_CONTEXT_MINOR_VERSION, 3,
                               EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
  // Surfaceless displays offer no configs; a context without one renders
  // into framebuffer objects only, which is all the client needs.
  EGLContext context = eglCreateContext(display, EGL_NO_CONFIG_KHR, EGL_NO_CONTEXT, attributes);
  if (context == EGL_NO_CONTEXT) {
    eglTerminate(display);
    return Fail(fmt::format("EGL: cannot create an OpenGL 3.3 core context (0x{:x})", eglGetError()));
  }
  if (!eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context)) {
    eglDestroyContext(display, context);
    eglTerminate(display);
    return Fail(fmt::format("EGL: cannot make the context current (0x{:x})", eglGetError()));
  }
  return std::unique_ptr<Context>(new SurfacelessContext(display, context));
}

// --- Window -------------------------------------------------------------------

Expected<std::unique_ptr<Window>> Window::Open(int width, int height, const std::string& title, bool visible) {
  glfwSetErrorCallback(OnGlfwError);
  if (!glfwInit()) return Fail(fmt::format("GLFW cannot start: {}", LastGlfwError()));
  glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
  glfwWindowHint(GLFW_VISIBLE, visible ? GLFW_TRUE : GLFW_FALSE);
  GLFWwindow* window = glfwCreateWindow(width, height, title.c_str(), nullptr, nullptr);
  if (!window) {
    const std::string error = LastGlfwError();
    glfwTerminate();
    return Fail(fmt::format("GLFW cannot open an OpenGL 3.3 core window: {}", error));
  }
  glfwMakeContextCurrent(window);
  glfwSwapInterval(1);
  std::unique_ptr<Window> w(new Window(window));
  glfwSetWindowUserPointer(window, w.get());
  glfwSetKeyCallback(window, OnKey);
  glfwSetCursorPosCallback(window, OnCursor);
  glfwSetScrollCallback(window, OnScroll);
  glfwSetMouseButtonCallback(window, OnButton);
  return w;
}

Window::~Window() {
  glfwDestroyWindow(window_);
  glfwTerminate();
}

std::string Window::Describe() const { return "GLFW window (" + GlDescription() + ")"; }
bool Window::ShouldClose() const { return glfwWindowShouldClose(window_); }
void Window::RequestClose() { glfwSetWindowShouldClose(window_, GLFW_TRUE); }
void Window::PollEvents() { glfwPollEvents(); }
void Window::SwapBuffers() { glfwSwapBuffers(window_); }
void Window::SetTitle(const std::string& title) { glfwSetWindowTitle(window_, title.c_str()); }

glm::ivec2 Window::FramebufferSize() const {
  glm::ivec2 size(0);
  glfwGetFramebufferSize(window_, &size.x, &size.y);
  return size;
}

float Window::ContentScale() const {
  float x = 1.0f, y = 1.0f;
  glfwGetWindowContentScale(window_, &x, &y);
  return std::max(x, y);
}

bool Window::KeyHeld(int key) const { return glfwGetKey(window_, key) == GLFW_PRESS; }
std::vector<KeyPress> Window::TakeKeyPresses() { return std::exchange(presses_, {}); }
glm::vec2 Window::TakeMouseMotion() { return std::exchange(motion_, glm::vec2(0.0f)); }
double Window::TakeScroll() { return std::exchange(scroll_, 0.0); }
bool Window::TakeClick() { return std::exchange(clicked_, false); }

glm::vec2 Window::CursorPixel() const {
  double x = 0.0, y = 0.0;
  glfwGetCursorPos(window_, &x, &y);
  // Cursor positions are in screen units; the framebuffer may be larger (HiDPI).
  int windowWidth = 1, windowHeight = 1;
  glfwGetWindowSize(window_, &windowWidth, &windowHeight);
  const glm::ivec2 framebuffer = FramebufferSize();
  return glm::vec2(float(x) * float(framebuffer.x) / float(std::max(windowWidth, 1)),
                   float(y) * float(framebuffer.y) / float(std::max(windowHeight, 1)));
}

bool Window::LeftButtonHeld() const { return glfwGetMouseButton(window_, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS; }

void Window::SetCursorCaptured(bool captured) {
  captured_ = captured;
  glfwSetInputMode(window_, GLFW_CURSOR, captured ? GLFW_CURSOR_DISABLED : GLFW_CURSOR_NORMAL);
  haveCursor_ = false;  // the first position after a mode change is a jump, not a motion
}

void Window::OnKey(GLFWwindow* w, int key, int, int action, int mods) {
  auto* self = static_cast<Window*>(glfwGetWindowUserPointer(w));
  if (action == GLFW_PRESS || action == GLFW_REPEAT) self->presses_.push_back(KeyPress{key, mods, action == GLFW_REPEAT});
}

void Window::OnCursor(GLFWwindow* w, double x, double y) {
  auto* self = static_cast<Window*>(glfwGetWindowUserPointer(w));
  const glm::dvec2 position(x, y);
  if (self->captured_ && self->haveCursor_) self->motion_ += glm::vec2(position - self->lastCursor_);
  self->lastCursor_ = position;
  self->haveCursor_ = true;
}

void Window::OnScroll(GLFWwindow* w, double, double dy) {
  static_cast<Window*>(glfwGetWindowUserPointer(w))->scroll_ += dy;
}

void Window::OnButton(GLFWwindow* w, int button, int action, int) {
  if (button == GLFW_MOUSE_BUTTON_LEFT && action == GLFW_PRESS)
    static_cast<Window*>(glfwGetWindowUserPointer(w))->clicked_ = true;
}

}  // namespace penumbra::client::gl
