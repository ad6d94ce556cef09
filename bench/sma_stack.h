#pragma once
// Support shared by the end-to-end SMA benchmarks (sma_bench,
// sma_clients_bench, scaling_bench): starting a renderer and an SMA as real
// processes, timing one view from a scripted client, and the machine's load.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "penumbra/common/camera.h"
#include "penumbra/common/expected.h"
#include "support/service.h"
#include "support/sma_client.h"

namespace penumbra::bench {

using Clock = std::chrono::steady_clock;

inline double Ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

/// A renderer and an SMA on loopback.
struct SmaStack {
  testing::Service renderer;
  testing::Service sma;
};

struct SmaStackOptions {
  std::filesystem::path scene;
  std::string rendererExe;  // executables: a benchmark may time another build's servers
  std::string smaExe;
  int rendererThreads = 2;
  int spp = 64;
  int maxBounces = 64;
  std::vector<std::string> smaArgs;  // besides --scene and --renderer; --log-level warn unless given
};

/// Starts the renderer, then the SMA pointed at it, and waits until the SMA
/// reports its renderer link (so that the first view is not timed against a
/// link still connecting).
Expected<SmaStack> StartSmaStack(const SmaStackOptions& options);

/// Milliseconds from sending a view until the first delta for it, until
/// stage 1 ends (every initially visible triangle shaded: the first delta
/// saying the view is refining or converged) and until it is converged.
struct ViewTiming {
  double firstDeltaMs = -1.0;
  double stage1Ms = -1.0;
  double completeMs = -1.0;
  uint64_t bytes = 0;
};

/// Sends `view` as `viewId` and applies every envelope until the view
/// converges (or `timeout` passes: an error). While waiting it sends a
/// Heartbeat every 5 s, as the protocol asks of a waiting client, so that
/// a wait longer than the SMA's read timeout keeps the connection.
/// `untilStage1`: stop at the end of stage 1 instead of convergence.
Expected<ViewTiming> TimeView(testing::SmaTestClient& client, const CameraView& view, uint64_t viewId,
                              std::chrono::milliseconds timeout = std::chrono::minutes(10), bool untilStage1 = false);

/// Applies every envelope that arrives until `done()` (asked at least every
/// 10 ms), sending a Heartbeat whenever nothing was sent for 5 s: a client
/// that is connected but idle.
Status IdleUntil(testing::SmaTestClient& client, const std::function<bool()>& done);
Status IdleUntil(testing::SmaTestClient& client, Clock::time_point until);

/// `text` split at white space: a benchmark's --sma-args.
std::vector<std::string> SplitWords(const std::string& text);

/// The 1-, 5- and 15-minute load averages (/proc/loadavg): how busy the
/// machine was besides the run.
std::string LoadAverage();

}  // namespace penumbra::bench
