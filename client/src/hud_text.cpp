#include "penumbra/client/hud_text.h"

#include <algorithm>

#include <fmt/format.h>

#include "penumbra/client/progress.h"

namespace penumbra::client {

HudProgressText DescribeProgress(const HudState& s) {
  HudProgressText out;
  if (!s.connected) return out;
  const ViewProgress& p = s.progress;
  if (p.renderersConnected) {
    if (*p.renderersConnected == 0 && s.pendingSamples > 0 && !s.converged)
      out.warning = fmt::format("No renderer connected \u2014 {} samples waiting", FormatCount(s.pendingSamples));
    else
      out.renderers = fmt::format("{} renderer{} connected", *p.renderersConnected,
                                  *p.renderersConnected == 1 ? "" : "s");
  }
  if (s.converged) {
    out.stage = "Done: the image is final until the camera moves";
    return out;
  }
  // Before the first delta there is no count to show: say what is going on
  // (on a large scene the SMA's first trace and stage-1 plan take a while).
  if (s.scene.empty()) {
    out.stage = "Waiting for the scene's description from the SMA";
    return out;
  }
  if (!s.refining && s.triangles == 0 && s.progress.stage1Total == 0) {
    out.stage = "Finding the visible triangles: the SMA traces the view";
    return out;
  }
  out.showBar = true;
  if (!s.refining) {
    out.stage = "Shading the view";
    out.barFraction = p.stage1Total > 0 ? float(p.stage1Done) / float(p.stage1Total) : 0.0f;
    out.barText = fmt::format("{} of {} samples", FormatCount(p.stage1Done), FormatCount(p.stage1Total));
    if (!out.warning.empty()) return out;  // no rate to speak of
    out.rate = s.stage1PerSecond ? fmt::format("{:.0f} samples/s", *s.stage1PerSecond) : "measuring the speed";
    if (s.stage1Left) out.rate += ", about " + FormatDuration(*s.stage1Left) + " left";
  } else {
    out.stage = "Refining: finer triangles where the light varies";
    out.barFraction = p.refinementTotal > 0 ? float(p.refinementDone) / float(p.refinementTotal) : 0.0f;
    out.barText = fmt::format("{} of {} new samples", FormatCount(p.refinementDone), FormatCount(p.refinementTotal));
    out.rate = (s.refinementPerSecond ? fmt::format("{:.0f} samples/s; ", *s.refinementPerSecond) : std::string()) +
               "more may follow as it finds detail";
  }
  out.barFraction = std::clamp(out.barFraction, 0.0f, 1.0f);
  return out;
}

std::vector<std::string> DescribeFigures(const HudState& s) {
  std::vector<std::string> lines;
  lines.push_back(fmt::format("{} triangles, {} vertices held", FormatCount(s.triangles), FormatCount(s.vertices)));
  // A slow software GL shows tenths rather than "0 frames/s".
  const std::string fps =
      s.framesPerSecond < 10.0 ? fmt::format("{:.1f}", s.framesPerSecond) : fmt::format("{:.0f}", s.framesPerSecond);
  lines.push_back(fmt::format("{} frames/s, receiving {}", fps, FormatBytesPerSecond(s.bytesPerSecond)));
  if (s.moveToFirstUpdateMs)
    lines.push_back(fmt::format("Response to the last camera move: {:.0f} ms", *s.moveToFirstUpdateMs));
  if (!s.scene.empty())  // the speed follows the scene's size: none before it is known
    lines.push_back(fmt::format("Walking speed: {:.2f} scene units/s", s.walkSpeed));
  return lines;
}

}  // namespace penumbra::client
