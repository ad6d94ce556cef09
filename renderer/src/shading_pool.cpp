#include "penumbra/renderer/shading_pool.h"

#include <algorithm>

#include "penumbra/renderer/ray_scene.h"

namespace penumbra {

// Guarded by ShadingPool::mutex_.
class ShadingPool::Source {
 public:
  std::deque<Chunk> chunks;
  bool inReadyList = false;
  std::atomic<bool> cancelled{false};
};

ShadingPool::ShadingPool(const Shader& shader, int threads) : shader_(shader) {
  const int n = std::max(1, threads);
  workers_.reserve(size_t(n));
  for (int i = 0; i < n; ++i) workers_.emplace_back([this] { WorkerLoop(); });
}

ShadingPool::~ShadingPool() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  for (auto& w : workers_) w.join();
}

std::shared_ptr<ShadingPool::Source> ShadingPool::AddSource() { return std::make_shared<Source>(); }

void ShadingPool::Submit(const std::shared_ptr<Source>& source, std::shared_ptr<ShadeJob> job) {
  const size_t n = job->inputs.size();
  if (job->baseline)
    job->changes.assign(n, ChangeEstimate{});
  else
    job->outputs.assign(n, ShadeOutput{});
  job->remaining_ = n;
  if (n == 0) return;
  // Enough chunks to keep every worker busy and answer in several parts, but
  // not so small that per-part overhead shows; and at most kChunkPaths paths,
  // since a chunk being shaded is what an urgent job still waits for.
  const int paths = job->paths > 0 ? job->paths : shader_.Settings().pathsPerSample;
  const size_t mostSamples = std::clamp<size_t>(kChunkPaths / size_t(std::max(1, paths)), 1, 64);
  const size_t chunk = std::clamp<size_t>(n / (4 * workers_.size()), 1, mostSamples);
  samplesQueued_ += n;
  {
    std::lock_guard lock(mutex_);
    // A job's chunks go behind the queued chunks of its rank or higher,
    // ahead of those of lower rank (the queue is urgent chunks first, then
    // soon ones, then the others).
    auto at = source->chunks.end();
    if (const int rank = job->Rank(); rank > 0)
      at = std::find_if(source->chunks.begin(), source->chunks.end(),
                        [rank](const Chunk& c) { return c.job->Rank() < rank; });
    for (size_t begin = 0; begin < n; begin += chunk) {
      at = source->chunks.insert(at, Chunk{job, begin, std::min(n, begin + chunk)});
      ++at;
    }
    if (!source->inReadyList) {
      source->inReadyList = true;
      ready_.push_back(source);
    }
  }
  wake_.notify_all();
}

size_t ShadingPool::Cancel(const std::shared_ptr<Source>& source) {
  size_t dropped = 0;
  {
    std::lock_guard lock(mutex_);
    source->cancelled = true;
    for (const Chunk& c : source->chunks) dropped += c.end - c.begin;
    source->chunks.clear();
  }
  samplesQueued_ -= dropped;
  samplesCancelled_ += dropped;
  return dropped;
}

ShadingPool::Totals ShadingPool::GetTotals() const {
  Totals t;
  t.samplesShaded = samplesShaded_.load();
  t.samplesCancelled = samplesCancelled_.load();
  t.paths = paths_.load();
  t.rays = rays_.load();
  t.buriedSamples = buriedSamples_.load();
  t.samplesQueued = samplesQueued_.load();
  return t;
}

void ShadingPool::WorkerLoop() {
  EnableFlushToZero();
  while (true) {
    std::shared_ptr<Source> source;
    Chunk chunk;
    {
      std::unique_lock lock(mutex_);
      wake_.wait(lock, [&] { return stopping_ || !ready_.empty(); });
      if (stopping_) return;
      source = std::move(ready_.front());
      ready_.pop_front();
      if (source->chunks.empty()) {  // cancelled while waiting its turn
        source->inReadyList = false;
        continue;
      }
      chunk = std::move(source->chunks.front());
      source->chunks.pop_front();
      // Back of the line: the next chunk goes to the next source.
      if (source->chunks.empty())
        source->inReadyList = false;
      else
        ready_.push_back(source);
    }
    RunChunk(*source, chunk);
  }
}

void ShadingPool::RunChunk(Source& source, const Chunk& chunk) {
  ShadeJob& job = *chunk.job;
  ShadeCounters counters;
  size_t done = chunk.begin;
  for (; done < chunk.end; ++done) {
    // A closed connection (or a shutdown) stops its work between samples,
    // and within a sample between paths, not after the chunk.
    if (source.cancelled.load(std::memory_order_relaxed)) break;
    if (job.baseline) {
      const int paths = job.paths > 0 ? job.paths : shader_.Settings().pathsPerSample;
      const PosedRayScene& now = job.pose ? *job.pose : *shader_.GetRays().Initial();
      job.changes[done] = shader_.EstimateChangeThrough(*job.baseline, now, job.inputs[done], job.region, paths,
                                                        &counters, &source.cancelled);
    } else {
      job.outputs[done] = job.pose ? shader_.Shade(*job.pose, job.inputs[done], job.paths, &counters, &source.cancelled)
                                   : shader_.Shade(job.inputs[done], job.paths, &counters, &source.cancelled);
    }
  }
  const size_t shaded = done - chunk.begin;
  samplesShaded_ += shaded;
  samplesQueued_ -= chunk.end - chunk.begin;
  samplesCancelled_ += chunk.end - done;
  paths_ += counters.paths;
  rays_ += counters.rays;
  buriedSamples_ += counters.buriedSamples;
  if (shaded < chunk.end - chunk.begin) return;

  // Decrement and deliver under the job's lock, so parts leave in the order
  // of their `remaining` counts.
  std::lock_guard lock(job.partMutex_);
  job.remaining_ -= shaded;
  if (job.onPart && !source.cancelled) job.onPart(job, chunk.begin, chunk.end, counters, job.remaining_);
}

}  // namespace penumbra
