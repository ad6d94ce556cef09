#pragma once
// ShadingPool: the renderer's worker threads. Batches (ShadeJobs) are split
// into chunks; workers take chunks round-robin across sources (one source per
// connection), so one connection's huge batch cannot starve another's.
// Within a source chunks go in order, except that an urgent job's chunks
// overtake the queued chunks of jobs that are not urgent, and a soon job's
// those of jobs that are neither urgent nor soon.
// Results leave in parts, as chunks finish, through the job's callback.
//
// Threads: Submit/Cancel/AddSource are thread-safe. Callbacks run on worker
// threads; the pool serialises the callbacks of one job, in the order their
// `remaining` counts decrease, so the part with remaining == 0 is the last.

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "penumbra/renderer/shading.h"

namespace penumbra {

struct ShadeJob {
  /// outputs[begin, end) are ready; `remaining` samples of the job are still
  /// to come (0: this is the last part).
  using PartCallback = std::function<void(const ShadeJob& job, size_t begin, size_t end,
                                          const ShadeCounters& counters, size_t remaining)>;

  uint64_t batchId = 0;
  int paths = 0;  // 0: the shader's default
  /// A client waits for it (ShadeRequest::urgent): its chunks go ahead of
  /// its source's queued chunks of jobs that are not urgent (behind those
  /// of earlier urgent jobs). Chunks being shaded are not interrupted.
  bool urgent = false;
  /// A client is expected to want it soon (ShadeRequest::soon): its chunks
  /// go behind its source's queued urgent and soon chunks, ahead of the rest.
  bool soon = false;
  /// 2 urgent, 1 soon, 0 neither: a source's queue is in non-increasing rank.
  int Rank() const { return urgent ? 2 : soon ? 1 : 0; }
  /// The pose every sample is shaded at (from the shader's RayScene); null:
  /// the scene's initial pose. Held by the job, so a newer pose built
  /// meanwhile never changes what an older batch is shaded against.
  std::shared_ptr<const PosedRayScene> pose;
  std::vector<ShadeInput> inputs;
  std::vector<ShadeOutput> outputs;  // filled by the pool; sized like inputs
  /// A verification batch (ShadeRequest::verify_change) when set: each input
  /// is not shaded but its change from `baseline` to `pose` through
  /// `region` is estimated (Shader::EstimateChangeThrough) into `changes`
  /// (sized like inputs by the pool; `outputs` then stays empty).
  std::shared_ptr<const PosedRayScene> baseline;
  std::vector<Bounds3> region;
  std::vector<ChangeEstimate> changes;
  PartCallback onPart;

 private:
  friend class ShadingPool;
  std::mutex partMutex_;
  size_t remaining_ = 0;
};

class ShadingPool {
 public:
  class Source;

  /// Starts `threads` workers (each sets flush-to-zero). `shader` must
  /// outlive the pool.
  ShadingPool(const Shader& shader, int threads);
  /// Stops the workers; queued chunks are dropped, running ones finish.
  ~ShadingPool();
  ShadingPool(const ShadingPool&) = delete;
  ShadingPool& operator=(const ShadingPool&) = delete;

  std::shared_ptr<Source> AddSource();
  /// Queues a job from `source`. The job's outputs are sized here.
  void Submit(const std::shared_ptr<Source>& source, std::shared_ptr<ShadeJob> job);
  /// Drops every queued chunk of `source` (its connection closed) and stops
  /// delivering its parts; a worker on one of its samples stops within a few
  /// dozen paths. Returns the number of queued samples dropped.
  size_t Cancel(const std::shared_ptr<Source>& source);

  int Threads() const { return int(workers_.size()); }

  struct Totals {
    uint64_t samplesShaded = 0;
    uint64_t samplesCancelled = 0;
    uint64_t paths = 0;
    uint64_t rays = 0;
    uint64_t buriedSamples = 0;  // shaded where their surface emerges (shading.h: "Buried samples")
    uint64_t samplesQueued = 0;  // waiting or being shaded now
  };
  Totals GetTotals() const;

 private:
  // Paths per chunk at most (~10 ms of a worker on a real interior): how
  // long an urgent job may wait for a worker to be free.
  static constexpr size_t kChunkPaths = 2048;
  struct Chunk {
    std::shared_ptr<ShadeJob> job;
    size_t begin = 0;
    size_t end = 0;
  };
  void WorkerLoop();
  void RunChunk(Source& source, const Chunk& chunk);

  const Shader& shader_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<std::shared_ptr<Source>> ready_;  // sources with queued chunks, in turn order
  bool stopping_ = false;
  std::vector<std::thread> workers_;

  std::atomic<uint64_t> samplesShaded_{0};
  std::atomic<uint64_t> samplesCancelled_{0};
  std::atomic<uint64_t> paths_{0};
  std::atomic<uint64_t> rays_{0};
  std::atomic<uint64_t> buriedSamples_{0};
  std::atomic<uint64_t> samplesQueued_{0};
};

}  // namespace penumbra
