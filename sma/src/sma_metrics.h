#pragma once
// The SMA's Prometheus families (docs/metrics.md): the counters its
// StatsReply carries (SmaServer::Impl::AddGlobalCounters, the one source of
// truth) under penumbra_sma_* names, plus the view latency histograms.
// Called on the HTTP endpoint's thread.

#include "penumbra/common/metrics.h"
#include "penumbra/wire.pb.h"

namespace penumbra::sma {

struct ViewLatencyHistograms {
  metrics::Histogram toFirstDelta{metrics::LatencyBucketsSeconds()};  // view received -> first delta sent
  metrics::Histogram toShaded{metrics::LatencyBucketsSeconds()};      // -> stage 1 done (every visible triangle shaded)
  metrics::Histogram toConverged{metrics::LatencyBucketsSeconds()};   // -> converged
};

void WriteSmaMetrics(metrics::ExpositionWriter& out, const wire::StatsReply& globalCounters,
                     const ViewLatencyHistograms& latencies);

}  // namespace penumbra::sma
