#pragma once
// OperatorEndpoint: the `--http HOST:PORT` endpoint of the renderer and the
// SMA (docs/deploy.md, "HTTP endpoints"; metric names in docs/metrics.md):
//   /healthz  200 while the process serves HTTP at all (liveness);
//   /readyz   200 once the tier is attached and says it is ready, else 503
//             with the reason (readiness);
//   /metrics  the Prometheus text exposition: the process's own gauges
//             (<prefix>_build_info, _uptime_seconds, _resident_memory_bytes,
//             _ready) and whatever the attached tier writes.
// It starts before the scene loads, so a liveness probe sees the process
// alive while /readyz says "loading the scene".
//
// Threads: the handlers run on the HTTP server's own thread (http_server.h).
// Attach and Detach may be called from any thread; Detach returns only once
// no handler is inside the probe, so the tier may then be destroyed.

#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "penumbra/common/http_server.h"
#include "penumbra/common/metrics.h"

namespace penumbra {

/// What a tier tells its operator endpoint. Both are called on the HTTP
/// thread and must not block for long (read atomics or a brief snapshot).
struct OperatorProbe {
  /// Writes the tier's metric families.
  std::function<void(metrics::ExpositionWriter&)> writeMetrics;
  /// Empty when ready; otherwise why not, for a human ("no renderer connected").
  std::function<std::string()> notReadyReason;
};

class OperatorEndpoint {
 public:
  /// `prefix`: the tier's metric prefix, "penumbra_sma" or "penumbra_renderer".
  static Expected<std::unique_ptr<OperatorEndpoint>> Start(const HostPort& where, std::string prefix,
                                                           net::HttpServerOptions options = {});
  /// For a tier's main: nullptr when `httpFlag` is empty; otherwise parses
  /// it (HOST:PORT, port 0: any free port), starts, and writes the bound
  /// port to `portFile` when it is not empty. Errors name the flag.
  static Expected<std::unique_ptr<OperatorEndpoint>> FromFlags(const std::string& httpFlag,
                                                               const std::string& portFile, std::string prefix);
  ~OperatorEndpoint();

  void Attach(OperatorProbe probe);
  void Detach();
  /// Stops serving (graceful; joins the HTTP thread). Idempotent.
  void Stop();
  tcp::endpoint Endpoint() const { return http_->Endpoint(); }

 private:
  OperatorEndpoint(std::string prefix) : prefix_(std::move(prefix)) {}
  net::HttpResponse Metrics();
  net::HttpResponse Ready();
  std::string NotReadyReason();  // caller holds probeMutex_

  std::string prefix_;
  std::chrono::steady_clock::time_point started_ = std::chrono::steady_clock::now();
  std::mutex probeMutex_;  // held while a handler calls into the probe
  std::optional<OperatorProbe> probe_;
  std::unique_ptr<net::HttpServer> http_;
};

}  // namespace penumbra
