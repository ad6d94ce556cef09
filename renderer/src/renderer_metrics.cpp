#include "renderer_metrics.h"

#include "penumbra/common/messages.h"

namespace penumbra {

void WriteRendererMetrics(metrics::ExpositionWriter& out, const wire::StatsReply& serverCounters) {
  // One line per counter of AddServerCounters (docs/protocol.md, "Renderer
  // counters"); one added there without a line here is exported as a gauge.
  static const std::vector<metrics::CounterSpec> specs = {
      {"samples_shaded", "penumbra_renderer_samples_shaded_total", "counter", "Samples shaded, all connections"},
      {"samples_cancelled", "penumbra_renderer_samples_cancelled_total", "counter",
       "Samples dropped because their connection closed"},
      {"samples_queued", "penumbra_renderer_samples_queued", "gauge", "Samples waiting or being shaded now"},
      {"paths_traced", "penumbra_renderer_paths_traced_total", "counter", "Paths traced"},
      {"rays_traced", "penumbra_renderer_rays_traced_total", "counter", "Rays traced"},
      {"samples_buried", "penumbra_renderer_samples_buried_total", "counter",
       "Samples shaded where their surface emerges from burying geometry"},
      {"worker_threads", "penumbra_renderer_worker_threads", "gauge", "Shading threads"},
      {"connections", "penumbra_renderer_connections", "gauge", "Open SMA connections"},
      {"uptime_seconds", "penumbra_renderer_server_uptime_seconds", "gauge", "Seconds since the server started"},
  };
  metrics::WriteCounters(out, "penumbra_renderer", CounterPairs(serverCounters), specs);
}

}  // namespace penumbra
