#pragma once
// The renderer's Prometheus families (docs/metrics.md): the server counters
// its StatsReply carries (RendererServer::Impl::AddServerCounters, the one
// source of truth) under penumbra_renderer_* names.

#include "penumbra/common/metrics.h"
#include "penumbra/wire.pb.h"

namespace penumbra {

void WriteRendererMetrics(metrics::ExpositionWriter& out, const wire::StatsReply& serverCounters);

}  // namespace penumbra
