#pragma once
// The heads-up display, drawn with Dear ImGui (Debian's libimgui-dev and its
// GLFW and OpenGL 3 backends): a compact, collapsible panel in the top-left
// corner -- connection, stage 1 and refinement progress bars with counts,
// rates and time left, the mesh and network figures, and the controls
// (refinement criterion, exposure, tone mapping, wireframe) -- plus a help
// overlay. The panel stays out of the top centre of the window, where the
// light of a ceiling-lit room such as the Cornell box is in the default view.
//
// Why ImGui rather than the 5x7 bitmap font it replaces: proportional,
// antialiased text at any size, progress bars, and controls that take the
// mouse, from a maintained Debian package, in less code than the hand-drawn
// font and its renderer took.
//
// Threads: render thread, with the window's context current. Windows only:
// the headless client (EGL, no GLFW) draws no HUD and never creates one.

#include <optional>
#include <string>
#include <vector>

#include "gl/context.h"
#include "penumbra/client/hud_text.h"
#include "penumbra/common/expected.h"

struct ImFont;

namespace penumbra::client::gl {

using client::HudState;

/// What the user changed in the panel this frame.
struct HudControls {
  std::string criterion;  // "" = the SMA's default
  float exposureStops = 0.0f;
  bool dragoToneMapping = true;
  float gamma = 2.2f;
  bool wireframe = false;
};

class Hud {
 public:
  /// Sets up ImGui on `window` (its input callbacks are chained after the
  /// window's own). One Hud per process at a time (ImGui's backends keep
  /// global state).
  static Expected<std::unique_ptr<Hud>> Create(Window& window);
  ~Hud();
  Hud(const Hud&) = delete;
  Hud& operator=(const Hud&) = delete;

  /// Builds and draws the HUD into the default framebuffer; `controls` is
  /// read and updated with what the user changed. Returns true when a
  /// control changed.
  bool Draw(const HudState& state, HudControls& controls, bool showHelp);

  /// ImGui wants the mouse (it hovers the panel) or the keyboard (a text
  /// field has focus): the camera should not take it this frame.
  bool WantsMouse() const;
  bool WantsKeyboard() const;
  /// While the cursor turns the camera, ImGui must not see it.
  void SetMouseEnabled(bool enabled);

 private:
  Hud() = default;
  void DrawHelp();
  bool initialisedGlfw_ = false;
  bool initialisedGl_ = false;
};

}  // namespace penumbra::client::gl
