#include "gl/hud.h"

#include <algorithm>
#include <filesystem>

#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>
#include <fmt/format.h>
#include <imgui.h>

#include "penumbra/common/logging.h"
#include "penumbra/common/refinement_params.h"

namespace penumbra::client::gl {

namespace {

// A readable proportional font from fonts-dejavu-core; ImGui's built-in
// bitmap font (13 px) scaled up is the fallback.
constexpr const char* kFontPaths[] = {
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
};
constexpr float kFontPixels = 15.0f;
constexpr float kPanelWidth = 400.0f;  // of 1280: the top centre stays clear
constexpr float kMargin = 8.0f;

const ImVec4 kWarning(1.0f, 0.55f, 0.35f, 1.0f);
const ImVec4 kGood(0.55f, 0.9f, 0.55f, 1.0f);
const ImVec4 kDim(0.75f, 0.75f, 0.75f, 1.0f);

const char* const kHelp[][2] = {
    {"W A S D / arrows", "move"},
    {"E Q / PgUp PgDn", "up / down"},
    {"Shift (held)", "move 4x faster"},
    {"[ ] or mouse wheel", "walking speed"},
    {"click or Tab", "capture the mouse to look around"},
    {"Esc", "release the mouse; with the mouse free, Esc twice quits"},
    {"1 .. 9", "camera presets"},
    {"R / Home", "back to the first preset"},
    {"F", "wireframe (the refinement mesh)"},
    {"C", "next refinement criterion"},
    {"T", "tone mapping: Drago 2003 / exposure + gamma"},
    {"- =", "exposure down / up (1/3 stop)"},
    {"G / Shift+G", "gamma up / down"},
    {"P / F12", "screenshot: tone-mapped PNG + linear EXR"},
    {"M", "move mode: left-drag a movable object (wheel: farther / nearer)"},
    {"H / F1", "this help"},
};

void ProgressLine(float fraction, const std::string& overlay) {
  ImGui::ProgressBar(std::clamp(fraction, 0.0f, 1.0f), ImVec2(-FLT_MIN, 0.0f), overlay.c_str());
}

}  // namespace

Expected<std::unique_ptr<Hud>> Hud::Create(Window& window) {
  std::unique_ptr<Hud> hud(new Hud());
  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGuiIO& io = ImGui::GetIO();
  io.IniFilename = nullptr;  // nothing written into the current folder
  io.LogFilename = nullptr;
  ImGui::StyleColorsDark();
  ImGuiStyle& style = ImGui::GetStyle();
  style.WindowRounding = 4.0f;
  style.FrameRounding = 3.0f;
  style.Colors[ImGuiCol_WindowBg].w = 0.72f;
  // A mid blue bar keeps its white overlay text readable over both parts.
  style.Colors[ImGuiCol_PlotHistogram] = ImVec4(0.20f, 0.45f, 0.78f, 1.0f);

  const float scale = std::max(1.0f, window.ContentScale());
  bool fontLoaded = false;
  for (const char* path : kFontPaths) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) continue;
    // Latin-1 and general punctuation (the dashes the HUD's text uses).
    static const ImWchar kRanges[] = {0x0020, 0x00FF, 0x2010, 0x2027, 0};
    if (io.Fonts->AddFontFromFileTTF(path, kFontPixels * scale, nullptr, kRanges)) {
      fontLoaded = true;
      break;
    }
  }
  if (!fontLoaded) {
    Logger("client.gl")->info("HUD: DejaVu Sans not found (package fonts-dejavu-core); using ImGui's built-in font");
    ImFontConfig config;
    config.SizePixels = 13.0f * scale;
    io.Fonts->AddFontDefault(&config);
  }
  style.ScaleAllSizes(scale);

  hud->initialisedGlfw_ = ImGui_ImplGlfw_InitForOpenGL(window.Handle(), /*install_callbacks=*/true);
  if (!hud->initialisedGlfw_) return Fail("HUD: ImGui's GLFW backend did not start");
  hud->initialisedGl_ = ImGui_ImplOpenGL3_Init("#version 330 core");
  if (!hud->initialisedGl_) return Fail("HUD: ImGui's OpenGL 3 backend did not start");
  return hud;
}

Hud::~Hud() {
  if (initialisedGl_) ImGui_ImplOpenGL3_Shutdown();
  if (initialisedGlfw_) ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
}

bool Hud::WantsMouse() const { return ImGui::GetIO().WantCaptureMouse; }
bool Hud::WantsKeyboard() const { return ImGui::GetIO().WantCaptureKeyboard; }

void Hud::SetMouseEnabled(bool enabled) {
  ImGuiIO& io = ImGui::GetIO();
  if (enabled)
    io.ConfigFlags &= ~ImGuiConfigFlags_NoMouse;
  else
    io.ConfigFlags |= ImGuiConfigFlags_NoMouse;
}

bool Hud::Draw(const HudState& s, HudControls& controls, bool showHelp) {
  ImGui_ImplOpenGL3_NewFrame();
  ImGui_ImplGlfw_NewFrame();
  ImGui::NewFrame();
  bool changed = false;
  const float scale = ImGui::GetFontSize() / kFontPixels;

  ImGui::SetNextWindowPos(ImVec2(kMargin, kMargin), ImGuiCond_Always);
  ImGui::SetNextWindowSize(ImVec2(kPanelWidth * scale, 0.0f), ImGuiCond_Always);
  const std::string title = fmt::format("Penumbra  {}###hud", s.scene.empty() ? "(no scene yet)" : s.scene);
  if (ImGui::Begin(title.c_str(), nullptr,
                   ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoSavedSettings |
                       ImGuiWindowFlags_NoFocusOnAppearing)) {
    // Connection.
    if (!s.permanentError.empty()) {
      ImGui::PushStyleColor(ImGuiCol_Text, kWarning);
      ImGui::TextWrapped("Cannot continue: %s", s.permanentError.c_str());
      ImGui::PopStyleColor();
      ImGui::TextWrapped("Close the window (or press Esc twice) to exit; the exit code is 1.");
    } else {
      ImGui::TextColored(kDim, "SMA %s: %s", s.sma.c_str(), s.connection.c_str());
    }

    // Renderers, and how far the view has come.
    const HudProgressText progress = DescribeProgress(s);
    if (!progress.warning.empty()) {
      ImGui::PushStyleColor(ImGuiCol_Text, kWarning);
      ImGui::TextWrapped("%s", progress.warning.c_str());
      ImGui::PopStyleColor();
      ImGui::TextColored(kDim, "(the SMA keeps trying to reach its renderers; see its log)");
    }
    if (!progress.renderers.empty()) ImGui::TextColored(kDim, "%s", progress.renderers.c_str());
    if (!progress.stage.empty()) {
      if (s.converged)
        ImGui::TextColored(kGood, "%s", progress.stage.c_str());
      else
        ImGui::TextUnformatted(progress.stage.c_str());
    }
    if (progress.showBar) ProgressLine(progress.barFraction, progress.barText);
    if (!progress.rate.empty()) ImGui::TextColored(kDim, "%s", progress.rate.c_str());

    // Figures, each with its unit.
    ImGui::Separator();
    for (const std::string& line : DescribeFigures(s)) ImGui::TextUnformatted(line.c_str());

    // Controls.
    if (ImGui::CollapsingHeader("Controls")) {
      const std::string preview = controls.criterion.empty() ? "SMA default" : controls.criterion;
      if (ImGui::BeginCombo("Refinement", preview.c_str())) {
        // The criteria in the order of the C key, each with its meaning as a tooltip.
        for (const CriterionEntry& entry : Criteria()) {
          const std::string c(entry.name);
          if (ImGui::Selectable(c.c_str(), c == controls.criterion)) {
            changed |= c != controls.criterion;
            controls.criterion = c;
          }
          if (ImGui::IsItemHovered()) ImGui::SetTooltip("%.*s", int(entry.meaning.size()), entry.meaning.data());
        }
        ImGui::EndCombo();
      }
      changed |= ImGui::SliderFloat("Exposure (stops)", &controls.exposureStops, -8.0f, 8.0f, "%+.2f");
      int op = controls.dragoToneMapping ? 0 : 1;
      changed |= ImGui::RadioButton("Drago 2003", &op, 0);
      ImGui::SameLine();
      changed |= ImGui::RadioButton("exposure + gamma", &op, 1);
      controls.dragoToneMapping = op == 0;
      if (!controls.dragoToneMapping) changed |= ImGui::SliderFloat("Gamma", &controls.gamma, 1.0f, 3.0f, "%.1f");
      changed |= ImGui::Checkbox("Wireframe", &controls.wireframe);
      ImGui::TextColored(kDim, "Paths per sample are set on the SMA (--first-paths, --paths)");
    }
    if (!s.objects.empty()) ImGui::TextColored(kGood, "%s", s.objects.c_str());
    if (!s.notice.empty()) ImGui::TextWrapped("%s", s.notice.c_str());
    ImGui::TextColored(kDim, "H or F1: help");
  }
  ImGui::End();
  if (showHelp) DrawHelp();

  ImGui::Render();
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
  return changed;
}

void Hud::DrawHelp() {
  const ImGuiViewport* viewport = ImGui::GetMainViewport();
  ImGui::SetNextWindowPos(ImVec2(viewport->WorkPos.x + viewport->WorkSize.x * 0.5f,
                                 viewport->WorkPos.y + viewport->WorkSize.y * 0.5f),
                          ImGuiCond_Always, ImVec2(0.5f, 0.5f));
  ImGui::SetNextWindowBgAlpha(0.85f);
  if (ImGui::Begin("Keys (H or F1 closes)###help", nullptr,
                   ImGuiWindowFlags_AlwaysAutoResize | ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoCollapse |
                       ImGuiWindowFlags_NoSavedSettings)) {
    if (ImGui::BeginTable("keys", 2)) {
      for (const auto& row : kHelp) {
        ImGui::TableNextRow();
        ImGui::TableSetColumnIndex(0);
        ImGui::TextColored(kGood, "%s", row[0]);
        ImGui::TableSetColumnIndex(1);
        ImGui::TextUnformatted(row[1]);
      }
      ImGui::EndTable();
    }
    ImGui::Separator();
    ImGui::TextWrapped("Quit: close the window, or press Esc twice (with the mouse released).");
  }
  ImGui::End();
}

}  // namespace penumbra::client::gl
