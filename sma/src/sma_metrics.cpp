#include "sma_metrics.h"

#include "penumbra/common/messages.h"

namespace penumbra::sma {

namespace {

// One line per counter of AddGlobalCounters (docs/protocol.md, "SMA
// counters"). A counter added there without a line here is still exported,
// as a gauge named after it (metrics::WriteCounters).
const std::vector<metrics::CounterSpec>& Specs() {
  static const std::vector<metrics::CounterSpec> specs = {
      {"clients", "penumbra_sma_clients", "gauge", "Client sessions connected"},
      {"hierarchy_nodes", "penumbra_sma_hierarchy_nodes", "gauge", "Nodes of the subdivision hierarchy"},
      {"hierarchy_vertices", "penumbra_sma_hierarchy_vertices", "gauge", "Vertices of the subdivision hierarchy"},
      {"cache_shaded", "penumbra_sma_cache_shaded_vertices", "gauge", "Vertices with a shaded sample in the cache"},
      {"samples_improved", "penumbra_sma_samples_improved_total", "counter",
       "Improvement rounds that changed a cached sample"},
      {"cache_hits", "penumbra_sma_cache_hits_total", "counter", "Cache lookups (visible triangle corners) found shaded"},
      {"cache_misses", "penumbra_sma_cache_misses_total", "counter", "Cache lookups not yet shaded"},
      {"cache_hit_rate", "penumbra_sma_cache_hit_ratio", "gauge", "Hits / lookups since start"},
      {"memory_bytes", "penumbra_sma_memory_bytes", "gauge",
       "The SMA's data: sample cache + hierarchy + clients' mirrors (estimated from sizes and capacities)"},
      {"memory_cache_bytes", "penumbra_sma_memory_part_bytes", "gauge", "The SMA's data by part", "part", "cache"},
      {"memory_hierarchy_bytes", "penumbra_sma_memory_part_bytes", "gauge", "The SMA's data by part", "part",
       "hierarchy"},
      {"memory_clients_bytes", "penumbra_sma_memory_part_bytes", "gauge", "The SMA's data by part", "part", "clients"},
      {"memory_budget_bytes", "penumbra_sma_memory_budget_bytes", "gauge", "--memory-budget in bytes; 0: unbounded"},
      {"memory_in_use_bytes", "penumbra_sma_memory_in_use_bytes", "gauge",
       "The SMA's data less freed slots awaiting reuse: what the collector keeps within the budget"},
      {"memory_collections", "penumbra_sma_memory_collections_total", "counter",
       "Collections started (data in use over --memory-collect-start of the budget)"},
      {"memory_collections_stuck", "penumbra_sma_memory_collections_stuck_total", "counter",
       "Collection passes that ended over the stop level: what was left was held, young or entangled with it"},
      {"collected_nodes", "penumbra_sma_collected_nodes_total", "counter", "Hierarchy nodes freed by the collector"},
      {"samples_evicted", "penumbra_sma_samples_evicted_total", "counter",
       "Cached samples dropped with the vertices the collector freed"},
      {"samples_reshaded_after_eviction", "penumbra_sma_samples_reshaded_after_eviction_total", "counter",
       "Vertices made (and shaded) again by splits of nodes the collector had collapsed"},
      {"memory_trims", "penumbra_sma_memory_trims_total", "counter",
       "malloc_trim calls at the end of collections that freed memory"},
      {"memory_trimmed_bytes", "penumbra_sma_memory_trimmed_bytes_total", "counter",
       "Resident bytes those malloc_trim calls handed back (resident before less after)"},
      {"process_resident_bytes", "penumbra_sma_process_resident_bytes", "gauge",
       "Resident set of the SMA process (/proc/self/statm)"},
      {"samples_requested", "penumbra_sma_samples_requested_total", "counter",
       "Distinct samples queued for the renderers"},
      {"samples_shaded", "penumbra_sma_samples_shaded_total", "counter", "Samples answered by renderers (first estimates and improvement rounds)"},
      {"samples_requeued", "penumbra_sma_samples_requeued_total", "counter", "Samples re-sent after a renderer failed"},
      {"samples_failed", "penumbra_sma_samples_failed_total", "counter", "Samples refused as invalid (stored black)"},
      {"samples_rejected", "penumbra_sma_samples_rejected_total", "counter",
       "Samples answered with impossible radiance (their renderer quarantined)"},
      {"samples_queued_visible", "penumbra_sma_samples_queued", "gauge",
       "Samples waiting for a renderer, by priority (the autoscaling signal)", "priority", "visible"},
      {"samples_queued_background", "penumbra_sma_samples_queued", "gauge",
       "Samples waiting for a renderer, by priority (the autoscaling signal)", "priority", "background"},
      {"samples_queued_improve", "penumbra_sma_samples_queued", "gauge",
       "Samples waiting for a renderer, by priority (the autoscaling signal)", "priority", "improve"},
      {"samples_queued_predicted", "penumbra_sma_samples_queued", "gauge",
       "Samples waiting for a renderer, by priority (the autoscaling signal)", "priority", "predicted"},
      {"samples_in_flight", "penumbra_sma_samples_in_flight", "gauge", "Samples sent to renderers, not yet answered"},
      {"predicted_views", "penumbra_sma_predicted_views_total", "counter",
       "Predicted camera views traced (movement prediction)"},
      {"samples_requested_predicted", "penumbra_sma_samples_requested_predicted_total", "counter",
       "Distinct samples queued because a predicted view needed them"},
      {"view_triangles_new", "penumbra_sma_view_triangles_new_total", "counter",
       "Triangles new views newly displayed (visible, not held by their client)"},
      {"view_triangles_new_shaded", "penumbra_sma_view_triangles_new_shaded_total", "counter",
       "Of view_triangles_new: those whose corners were already shaded when the view's visibility was applied"},
      {"prediction_hit_rate", "penumbra_sma_prediction_hit_ratio", "gauge",
       "view_triangles_new_shaded / view_triangles_new since start (counted with prediction on or off)"},
      {"renderer.*.connected", "penumbra_sma_renderer_connected", "gauge", "1 while the renderer is connected",
       "renderer"},
      {"renderer.*.samples_in_flight", "penumbra_sma_renderer_samples_in_flight", "gauge",
       "Samples sent to the renderer, not yet answered", "renderer"},
      {"renderer.*.samples_shaded", "penumbra_sma_renderer_samples_shaded_total", "counter",
       "Samples the renderer answered", "renderer"},
      {"renderer.*.samples_per_second", "penumbra_sma_renderer_samples_per_second", "gauge",
       "The renderer's recent throughput as the pool measures it", "renderer"},
      {"renderer.*.failures", "penumbra_sma_renderer_failures_total", "counter",
       "Connection failures and timeouts of the renderer", "renderer"},
      {"renderer.*.bad_replies", "penumbra_sma_renderer_bad_replies_total", "counter",
       "Malformed or impossible replies (each quarantines the renderer)", "renderer"},
      {"scene_epoch", "penumbra_sma_scene_epoch", "gauge", "Moves of movable objects applied so far (the scene's pose number)"},
      {"moves", "penumbra_sma_moves_total", "counter", "Moves applied (client MoveObjects and animation steps, after coalescing)"},
      {"moves_refused", "penumbra_sma_moves_refused_total", "counter",
       "MoveObject requests refused (unknown or animated object, transform not finite and rigid)"},
      {"moves_coalesced", "penumbra_sma_moves_coalesced_total", "counter",
       "Moves replaced by a later move of the same object before they were applied"},
      {"samples_invalidated", "penumbra_sma_samples_invalidated_total", "counter",
       "Cached samples evicted because a move may have changed them"},
      {"samples_reshaded_after_move", "penumbra_sma_samples_reshaded_after_move_total", "counter",
       "First estimates stored for vertices whose sample a move had invalidated"},
      {"samples_stale_refused", "penumbra_sma_samples_stale_refused_total", "counter",
       "Samples refused because they were shaded at a pose a move had since changed (asked again)"},
      {"last_move_invalidated", "penumbra_sma_last_move_invalidated_samples", "gauge",
       "Cached samples the last move evicted"},
      {"samples_invalidated_urgent", "penumbra_sma_samples_invalidated_urgent_total", "counter",
       "Of samples_invalidated: the moved objects' own and those whose direct light changed (re-shaded first)"},
      {"last_move_invalidated_urgent", "penumbra_sma_last_move_invalidated_urgent_samples", "gauge",
       "Of the last move's evicted samples: the moved objects' own and those whose direct light changed"},
      {"last_move_cached", "penumbra_sma_last_move_cached_samples", "gauge",
       "Samples cached just before the last move (what a full recomputation would re-shade)"},
      {"last_move_reshaded", "penumbra_sma_last_move_reshaded_samples", "gauge",
       "Invalidated samples re-shaded since the last move"},
      {"last_move_apply_ms", "penumbra_sma_last_move_apply_milliseconds", "gauge",
       "Time the last move took to apply (pose, invalidation), before sessions were told"},
      {"renderers", "penumbra_sma_renderers", "gauge", "Renderer endpoints known (resolved)"},
      {"renderers_connected", "penumbra_sma_renderers_up", "gauge", "Renderer endpoints connected and ready"},
  };
  return specs;
}

}  // namespace

void WriteSmaMetrics(metrics::ExpositionWriter& out, const wire::StatsReply& globalCounters,
                     const ViewLatencyHistograms& latencies) {
  metrics::WriteCounters(out, "penumbra_sma", CounterPairs(globalCounters), Specs());
  out.WriteHistogram("penumbra_sma_view_first_delta_seconds",
                     "New view received -> its first delta sent (visibility traced, mapped, planned)",
                     latencies.toFirstDelta.Read());
  out.WriteHistogram("penumbra_sma_view_shaded_seconds",
                     "New view received -> every initially visible triangle shaded (stage 1)",
                     latencies.toShaded.Read());
  out.WriteHistogram("penumbra_sma_view_converged_seconds",
                     "New view received -> converged (refinement and improvement done)",
                     latencies.toConverged.Read());
}

}  // namespace penumbra::sma
