#include "penumbra/client/headless_run.h"

#include <algorithm>
#include <cctype>

#include <fmt/format.h>

#include "penumbra/common/check.h"

namespace penumbra::client {

HeadlessRun::HeadlessRun(HeadlessGoal goal, std::string smaAddress, Clock::time_point start)
    : goal_(goal), smaAddress_(std::move(smaAddress)), start_(start) {}

bool HeadlessRun::GoalMet(const HeadlessObservation& seen, Clock::time_point now) {
  switch (goal_.stopWhen) {
    case StopWhen::kFrames: return seen.framesDrawn + 1 >= goal_.frames;
    case StopWhen::kSeconds: return std::chrono::duration<double>(now - start_).count() >= goal_.seconds;
    case StopWhen::kConverged: break;
  }
  if (!seen.pathFinished || !seen.converged) {
    convergedSince_.reset();
    return false;
  }
  if (!convergedSince_) convergedSince_ = now;
  return seen.countersCurrent || now - *convergedSince_ >= goal_.countersGrace;
}

std::optional<std::string> HeadlessRun::Failure(const HeadlessObservation& seen, Clock::time_point now) const {
  if (seen.connection != ConnectionState::kConnected && now - seen.disconnectedSince > goal_.connectTimeout)
    return fmt::format("no connection to the SMA at {} for {} s (last error: {})", smaAddress_,
                       goal_.connectTimeout.count(), seen.lastError.empty() ? "none" : seen.lastError);
  if (goal_.stopWhen == StopWhen::kConverged && now - start_ > goal_.convergeTimeout)
    return fmt::format("the view did not converge within {} s ({} samples pending, {} triangles held)",
                       goal_.convergeTimeout.count(), seen.samplesPending, seen.trianglesHeld);
  return std::nullopt;
}

SnapshotSchedule::SnapshotSchedule(std::chrono::duration<double> every, std::filesystem::path prefix)
    : every_(every), prefix_(std::move(prefix)) {}

std::optional<std::filesystem::path> SnapshotSchedule::Due(Clock::time_point now, uint64_t trianglesHeld,
                                                           uint64_t sequence, uint64_t frame) const {
  if (every_.count() <= 0.0 || stopped_) return std::nullopt;
  if (trianglesHeld == 0 || sequence == lastSequence_) return std::nullopt;
  if (last_ && now - *last_ < every_) return std::nullopt;
  return std::filesystem::path(prefix_.string() + fmt::format("_{:06}.exr", frame));
}

void SnapshotSchedule::Written(Clock::time_point now, uint64_t sequence) {
  last_ = now;
  lastSequence_ = sequence;
}

namespace {
std::string LowerExtension(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}
}  // namespace

bool IsRadianceFile(const std::filesystem::path& path) {
  const std::string ext = LowerExtension(path);
  return ext == ".exr" || ext == ".hdr";
}

bool StoresCoverage(const std::filesystem::path& path) { return LowerExtension(path) == ".exr"; }

std::string ScreenshotStem(std::string_view sceneName, std::string_view timestamp) {
  constexpr size_t kMaxNameChars = 64;
  std::string name;
  for (char c : sceneName.substr(0, kMaxNameChars)) {
    const auto u = static_cast<unsigned char>(c);
    const bool safe = (u < 0x80 && std::isalnum(u)) || c == '-' || c == '_' || c == '.';
    name.push_back(safe ? c : '_');
  }
  if (!name.empty() && name.front() == '.') name.front() = '_';  // no hidden file, no "." or ".."
  if (name.empty()) name = "scene";
  return fmt::format("penumbra-{}-{}", name, timestamp);
}

std::vector<float> BoxFilter(std::span<const float> pixels, int width, int height, int n, int channels) {
  if (n <= 1) return std::vector<float>(pixels.begin(), pixels.end());
  const int w = width / n, h = height / n;
  const auto k = size_t(channels);
  PENUMBRA_CHECK(pixels.size() == size_t(width) * size_t(height) * k,
                 fmt::format("BoxFilter: {} values for {}x{} pixels of {} channels", pixels.size(), width, height, k));
  std::vector<float> filtered(size_t(w) * size_t(h) * k, 0.0f);
  const float weight = 1.0f / float(n * n);
  for (int y = 0; y < h * n; ++y)
    for (int x = 0; x < w * n; ++x)
      for (size_t c = 0; c < k; ++c)
        filtered[(size_t(y / n) * size_t(w) + size_t(x / n)) * k + c] +=
            weight * pixels[(size_t(y) * size_t(width) + size_t(x)) * k + c];
  return filtered;
}

}  // namespace penumbra::client
