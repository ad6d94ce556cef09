#pragma once
// What the HUD says, as plain text: the words and figures (each with its
// unit) for the connection, the renderers, and the progress of stage 1 and of
// refinement. No GL and no ImGui, so the wording is unit-tested; gl/hud.cpp
// lays it out.
//
// Threads: any (pure functions).

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>

#include "penumbra/client/mesh_store.h"

namespace penumbra::client {

/// Everything the HUD shows, gathered by the client each frame.
struct HudState {
  std::string scene;  // empty before the first SceneInfo
  std::string sma;    // HOST:PORT
  /// "connected", "connecting", "reconnecting (reason)".
  std::string connection;
  bool connected = false;
  std::string permanentError;  // non-empty: the session gave up; the panel says why
  ViewProgress progress;
  uint32_t pendingSamples = 0;
  bool converged = false;
  bool refining = false;
  std::optional<double> stage1PerSecond;  // samples per second
  std::optional<std::chrono::seconds> stage1Left;
  std::optional<double> refinementPerSecond;
  size_t triangles = 0;
  size_t vertices = 0;
  double framesPerSecond = 0.0;
  double bytesPerSecond = 0.0;
  std::optional<double> moveToFirstUpdateMs;  // last camera move -> first answer from the SMA
  float walkSpeed = 0.0f;                     // scene units per second
  std::string notice;                         // e.g. where a screenshot went; empty: none
  std::string objects;  // movable objects: the move mode, the object grabbed; empty: a static scene
};

/// The progress part of the HUD.
struct HudProgressText {
  /// A warning to show prominently ("No renderer connected: ..."); empty: none.
  std::string warning;
  std::string renderers;  // "2 renderers connected"; empty when unknown
  std::string stage;      // "Shading the view", "Refining ...", "Done: ..."; empty when not connected
  bool showBar = false;
  float barFraction = 0.0f;  // [0, 1]
  std::string barText;       // "1,234 of 5,678 samples"
  std::string rate;          // "850 samples/s, about 5 s left"
};

HudProgressText DescribeProgress(const HudState& state);

/// "12,345 triangles, 6,789 vertices held" and the like, one per line.
std::vector<std::string> DescribeFigures(const HudState& state);

}  // namespace penumbra::client
