#include "penumbra/sma/sample_cache.h"

#include <algorithm>
#include <cmath>
#include <thread>

#include <fmt/format.h>

#include "penumbra/common/check.h"

namespace penumbra::sma {

RadianceBounds RadianceBounds::ForScene(const Scene& scene) {
  const float brightest = scene.MaxEmittedRadiance();
  RadianceBounds bounds;
  bounds.maxRadiance = kMonteCarloMargin * brightest;
  bounds.maxIrradiance = kMonteCarloMargin * kPi * brightest;
  return bounds;
}

Status RadianceBounds::Check(const ShadedSample& sample) const {
  const auto inRange = [](const Rgb& c, float limit) {
    for (int i = 0; i < 3; ++i)
      if (!(c[i] >= 0.0f && c[i] <= limit)) return false;  // also false for NaN
    return true;
  };
  if (!inRange(sample.radiance, maxRadiance))
    return Fail(fmt::format("radiance ({:g}, {:g}, {:g}) is outside [0, {:g}]", sample.radiance.r, sample.radiance.g,
                            sample.radiance.b, maxRadiance));
  if (!inRange(sample.irradiance, maxIrradiance))
    return Fail(fmt::format("irradiance ({:g}, {:g}, {:g}) is outside [0, {:g}]", sample.irradiance.r,
                            sample.irradiance.g, sample.irradiance.b, maxIrradiance));
  if (!(sample.irradianceStdErr >= 0.0f && sample.irradianceStdErr <= maxIrradiance))
    return Fail(fmt::format("standard error {:g} is outside [0, {:g}]", sample.irradianceStdErr, maxIrradiance));
  return Status::Ok();
}

namespace {
constexpr auto kRelaxed = std::memory_order_relaxed;
Rgb LoadRgb(const std::atomic<float> (&c)[3]) { return Rgb(c[0].load(kRelaxed), c[1].load(kRelaxed), c[2].load(kRelaxed)); }
void StoreRgb(std::atomic<float> (&c)[3], const Rgb& value) {
  for (int i = 0; i < 3; ++i) c[i].store(value[i], kRelaxed);
}
}  // namespace

SampleCache::SampleCache() : directory_(new std::atomic<std::atomic<Slot*>*>[kTopEntries]()) {}
SampleCache::~SampleCache() = default;

void SampleCache::Reserve(size_t vertexCount) {
  if (vertexCount <= Size()) return;
  std::lock_guard lock(growthMutex_);
  if (vertexCount <= size_.load(kRelaxed)) return;
  PENUMBRA_CHECK(vertexCount - 1 <= std::numeric_limits<VertexId>::max(),
                 fmt::format("sample cache of {} vertices", vertexCount));
  size_.store(vertexCount, std::memory_order_release);
}

size_t SampleCache::MemoryBytes() const {
  return kTopEntries * sizeof(std::atomic<std::atomic<Slot*>*>) +
         pagesAllocated_.load(kRelaxed) * kPageEntries * sizeof(std::atomic<Slot*>) +
         chunksAllocated_.load(kRelaxed) * kChunkSlots * sizeof(Slot);
}

SampleCache::Slot& SampleCache::SlotFor(VertexId v) {
  if (v >= Size()) Reserve(size_t(v) + 1);
  if (const Slot* found = Find(v)) return const_cast<Slot&>(*found);
  // The first write into this chunk (and maybe this page): made under the
  // growth mutex, published with release so that a reader that finds a
  // pointer sees what it points to initialised.
  std::lock_guard lock(growthMutex_);
  std::atomic<std::atomic<Slot*>*>& top = directory_[v >> kTopShift];
  std::atomic<Slot*>* page = top.load(kRelaxed);
  if (!page) {
    pages_.push_back(std::make_unique<std::atomic<Slot*>[]>(kPageEntries));
    page = pages_.back().get();
    top.store(page, std::memory_order_release);
    pagesAllocated_.fetch_add(1, kRelaxed);
  }
  std::atomic<Slot*>& entry = page[(v >> kChunkBits) & (kPageEntries - 1)];
  Slot* chunk = entry.load(kRelaxed);
  if (!chunk) {
    chunks_.push_back(std::make_unique<Slot[]>(kChunkSlots));
    chunk = chunks_.back().get();
    entry.store(chunk, std::memory_order_release);
    chunksAllocated_.fetch_add(1, kRelaxed);
  }
  return chunk[v & (kChunkSlots - 1)];
}

uint32_t SampleCache::BeginWrite(Slot& s) {
  uint32_t sequence = s.sequence.load(kRelaxed);
  for (;;) {
    if (sequence & 1u) {  // another writer of this very slot: brief (a few stores)
      std::this_thread::yield();
      sequence = s.sequence.load(kRelaxed);
      continue;
    }
    if (s.sequence.compare_exchange_weak(sequence, sequence + 1, std::memory_order_acquire, kRelaxed)) break;
  }
  // The odd sequence must be visible before any value changes.
  std::atomic_thread_fence(std::memory_order_release);
  return sequence;
}

void SampleCache::WriteValues(Slot& s, const ShadedSample& sample, uint16_t rounds) {
  StoreRgb(s.radiance, sample.radiance);
  StoreRgb(s.irradiance, sample.irradiance);
  s.irradianceStdErr.store(sample.irradianceStdErr, kRelaxed);
  s.paths.store(sample.paths, kRelaxed);
  s.rounds.store(rounds, kRelaxed);
  s.epoch.store(sample.epoch, kRelaxed);
}

template <typename F>
auto SampleCache::ReadConsistent(VertexId v, F&& read) const -> decltype(read(std::declval<const Slot&>())) {
  const Slot* s = Find(v);
  if (!s) return read(Slot{});  // an all-zero, unshaded slot
  for (;;) {
    const uint32_t before = s->sequence.load(std::memory_order_acquire);
    if (before & 1u) {
      std::this_thread::yield();
      continue;
    }
    auto value = read(*s);
    std::atomic_thread_fence(std::memory_order_acquire);
    if (s->sequence.load(kRelaxed) == before) return value;
  }
}

std::optional<CachedSample> SampleCache::Read(VertexId v) const {
  return ReadConsistent(v, [](const Slot& s) -> std::optional<CachedSample> {
    if (!s.shaded.load(kRelaxed)) return std::nullopt;
    return CachedSample{LoadRgb(s.radiance), LoadRgb(s.irradiance), s.irradianceStdErr.load(kRelaxed),
                        s.paths.load(kRelaxed), s.rounds.load(kRelaxed), s.generation.load(kRelaxed),
                        s.epoch.load(kRelaxed)};
  });
}

std::optional<CachedSample> SampleCache::ReadSuspect(VertexId v) const {
  return ReadConsistent(v, [](const Slot& s) -> std::optional<CachedSample> {
    if (!s.suspect.load(kRelaxed)) return std::nullopt;
    return CachedSample{LoadRgb(s.radiance), LoadRgb(s.irradiance), s.irradianceStdErr.load(kRelaxed),
                        s.paths.load(kRelaxed), s.rounds.load(kRelaxed), s.generation.load(kRelaxed),
                        s.epoch.load(kRelaxed)};
  });
}

Rgb SampleCache::Radiance(VertexId v) const {
  // A suspect slot keeps its values but reads unshaded: zero.
  return ReadConsistent(v, [](const Slot& s) { return s.shaded.load(kRelaxed) ? LoadRgb(s.radiance) : Rgb(0.0f); });
}
Rgb SampleCache::Irradiance(VertexId v) const {
  return ReadConsistent(v, [](const Slot& s) { return s.shaded.load(kRelaxed) ? LoadRgb(s.irradiance) : Rgb(0.0f); });
}
float SampleCache::IrradianceStdErr(VertexId v) const {
  const Slot* s = Find(v);
  return s && s->shaded.load(std::memory_order_acquire) ? s->irradianceStdErr.load(kRelaxed) : 0.0f;
}
uint32_t SampleCache::Paths(VertexId v) const {
  const Slot* s = Find(v);
  return s && s->shaded.load(std::memory_order_acquire) ? s->paths.load(kRelaxed) : 0;
}
uint16_t SampleCache::Rounds(VertexId v) const {
  const Slot* s = Find(v);
  return s && s->shaded.load(std::memory_order_acquire) ? s->rounds.load(kRelaxed) : 0;
}
uint32_t SampleCache::Generation(VertexId v) const {
  const Slot* s = Find(v);
  return s ? s->generation.load(std::memory_order_acquire) : 0;
}
uint64_t SampleCache::ValidFrom(VertexId v) const {
  const Slot* s = Find(v);
  return s ? s->validFrom.load(std::memory_order_acquire) : 0;
}

float SampleCache::RelativeError(VertexId v) const {
  const auto sample = Read(v);
  if (!sample) return 0.0f;
  const float e = penumbra::Luminance(sample->irradiance);
  const float err = sample->irradianceStdErr;
  // Black with no spread is every path finding nothing, which from 16 paths
  // does not show that there is nothing to find: a dim surface lit by a few
  // narrow ways (sunlight bounced off a patch of floor) reads 0 in many sets
  // of 16 paths (docs/refinement.md, third round). Its error is unknown
  // until kBlackPaths paths have found nothing -- then fewer than 3 in
  // kBlackPaths of its paths carry light (the rule of three, 95 %), and it is
  // taken as black: hidden and buried vertices are not improved to the cap.
  if (!(e > 0.0f)) return sample->paths < kBlackPaths ? std::numeric_limits<float>::infinity() : 0.0f;
  return err > 0.0f ? err / e : 0.0f;
}

std::vector<VertexId> SampleCache::Improve(std::span<const ShadedSample> samples, std::vector<VertexId>* stale) {
  std::vector<VertexId> changed;
  changed.reserve(samples.size());
  for (const ShadedSample& sample : samples) {
    if (sample.paths == 0) continue;
    // A vertex whose chunk was never written is unshaded, never invalidated:
    // an improvement has nothing to do there.
    Slot* found = const_cast<Slot*>(Find(sample.vertex));
    if (!found) continue;
    Slot& s = *found;
    const uint32_t sequence = BeginWrite(s);
    const uint16_t rounds = s.rounds.load(kRelaxed);
    if (sample.epoch < s.validFrom.load(kRelaxed) || s.awaitingReshade.load(kRelaxed)) {
      // Shaded at a pose a move has since changed, or of a vertex whose
      // sample was invalidated: it needs a first estimate again.
      if (stale) stale->push_back(sample.vertex);
    } else if (s.shaded.load(kRelaxed) && sample.round == rounds + 1) {
      const uint32_t paths = s.paths.load(kRelaxed);
      const double n1 = std::max<uint32_t>(1, paths), n2 = std::max<uint32_t>(1, sample.paths), n = n1 + n2;
      const float w1 = float(n1 / n), w2 = float(n2 / n);
      const float err = s.irradianceStdErr.load(kRelaxed);
      ShadedSample mixed = sample;
      mixed.radiance = w1 * LoadRgb(s.radiance) + w2 * sample.radiance;
      mixed.irradiance = w1 * LoadRgb(s.irradiance) + w2 * sample.irradiance;
      // Var(w1 X1 + w2 X2) = w1^2 Var1 + w2^2 Var2 for independent estimates.
      mixed.irradianceStdErr =
          std::sqrt(w1 * w1 * err * err + w2 * w2 * sample.irradianceStdErr * sample.irradianceStdErr);
      mixed.paths = uint32_t(std::min<double>(n, std::numeric_limits<uint32_t>::max()));
      mixed.epoch = std::min(sample.epoch, s.epoch.load(kRelaxed));  // the older pose it still mixes
      WriteValues(s, mixed, sample.round);
      changed.push_back(sample.vertex);
    }
    EndWrite(s, sequence);
  }
  changes_ += changed.size();
  return changed;
}

size_t SampleCache::Put(std::span<const ShadedSample> samples, bool keepRounds, std::vector<VertexId>* stale) {
  size_t added = 0;
  for (const ShadedSample& sample : samples) {
    if (sample.vertex == kNoVertex) continue;
    Slot& s = SlotFor(sample.vertex);
    const uint32_t sequence = BeginWrite(s);
    // The epoch check is inside the slot's sequence, like Invalidate's
    // write of validFrom: whichever comes second sees the other.
    if (sample.epoch < s.validFrom.load(kRelaxed)) {
      if (stale) stale->push_back(sample.vertex);
    } else if (!s.shaded.load(kRelaxed)) {
      WriteValues(s, sample, keepRounds ? sample.round : 0);
      if (s.awaitingReshade.exchange(0, kRelaxed)) ++reshaded_;
      // A reshade replaces a sample held back for a test: the test's
      // answer, when it comes, finds the slot no longer suspect.
      s.suspect.store(0, kRelaxed);
      // Release: IsShaded()'s acquire load then sees the values (and
      // EndWrite publishes them to Read()).
      s.shaded.store(1, std::memory_order_release);
      ++added;
    }
    EndWrite(s, sequence);
  }
  shadedCount_ += added;
  changes_ += added;
  return added;
}

size_t SampleCache::Store(std::span<const ShadedSample> samples, std::vector<VertexId>* stale) {
  return Put(samples, false, stale);
}
size_t SampleCache::Restore(std::span<const ShadedSample> samples) { return Put(samples, true, nullptr); }

bool SampleCache::Evict(VertexId v) {
  Slot* found = const_cast<Slot*>(Find(v));
  if (!found) return false;  // never written: nothing to evict, and no chunk made for it
  Slot& s = *found;
  const uint32_t sequence = BeginWrite(s);
  const bool wasShaded = s.shaded.load(kRelaxed) != 0;
  const bool wasSuspect = s.suspect.load(kRelaxed) != 0;  // it then stays AwaitingReshade
  if (wasShaded || wasSuspect) {
    s.shaded.store(0, std::memory_order_release);
    s.suspect.store(0, std::memory_order_release);
    WriteValues(s, ShadedSample{v, Rgb(0.0f), Rgb(0.0f), 0.0f, 0, 0}, 0);
    s.generation.fetch_add(1, std::memory_order_release);
  }
  EndWrite(s, sequence);
  if (wasShaded) --shadedCount_;
  if (wasShaded || wasSuspect) ++changes_;
  return wasShaded || wasSuspect;
}

size_t SampleCache::SlotBytes() { return sizeof(Slot); }

bool SampleCache::Forget(VertexId v) {
  Slot* found = const_cast<Slot*>(Find(v));
  if (!found) return false;  // never written: it reads unshaded already
  Slot& s = *found;
  const uint32_t sequence = BeginWrite(s);
  const bool wasShaded = s.shaded.load(kRelaxed) != 0;
  s.shaded.store(0, std::memory_order_release);
  s.awaitingReshade.store(0, std::memory_order_release);
  s.suspect.store(0, std::memory_order_release);
  WriteValues(s, ShadedSample{v, Rgb(0.0f), Rgb(0.0f), 0.0f, 0, 0}, 0);
  s.generation.fetch_add(1, std::memory_order_release);
  EndWrite(s, sequence);
  if (wasShaded) --shadedCount_;
  ++changes_;
  return wasShaded;
}

bool SampleCache::Invalidate(VertexId v, uint64_t epoch) {
  Slot& s = SlotFor(v);
  const uint32_t sequence = BeginWrite(s);
  if (s.validFrom.load(kRelaxed) < epoch) s.validFrom.store(epoch, std::memory_order_release);
  // A sample already shaded at this pose (dispatched after the move was
  // published, stored before it was applied here) is kept.
  const bool wasShaded = s.shaded.load(kRelaxed) != 0;
  const bool evict = (wasShaded || s.suspect.load(kRelaxed) != 0) && s.epoch.load(kRelaxed) < epoch;
  if (evict) {
    s.shaded.store(0, std::memory_order_release);
    s.suspect.store(0, std::memory_order_release);
    s.awaitingReshade.store(1, std::memory_order_release);
    WriteValues(s, ShadedSample{v, Rgb(0.0f), Rgb(0.0f), 0.0f, 0, 0, 0}, 0);
    s.generation.fetch_add(1, std::memory_order_release);
  }
  EndWrite(s, sequence);
  if (evict) {
    if (wasShaded) --shadedCount_;
    ++changes_;
  }
  return evict;
}

std::optional<uint32_t> SampleCache::Suspect(VertexId v, uint64_t epoch) {
  Slot* found = const_cast<Slot*>(Find(v));
  if (!found) return std::nullopt;  // never written: nothing to test
  Slot& s = *found;
  const uint32_t sequence = BeginWrite(s);
  if (s.validFrom.load(kRelaxed) < epoch) s.validFrom.store(epoch, std::memory_order_release);
  const bool wasShaded = s.shaded.load(kRelaxed) != 0;
  std::optional<uint32_t> generation;
  if ((wasShaded || s.suspect.load(kRelaxed) != 0) && s.epoch.load(kRelaxed) < epoch) {
    // The values stay: only the flags say the sample may not be shown.
    s.shaded.store(0, std::memory_order_release);
    s.suspect.store(1, std::memory_order_release);
    s.awaitingReshade.store(1, std::memory_order_release);
    generation = s.generation.fetch_add(1, std::memory_order_release) + 1;
  }
  EndWrite(s, sequence);
  if (generation) {
    if (wasShaded) --shadedCount_;
    ++changes_;
  }
  return generation;
}

bool SampleCache::Confirm(VertexId v, uint32_t generation) { return ResolveSuspect(v, generation, /*keep=*/true); }
bool SampleCache::FailSuspect(VertexId v, uint32_t generation) { return ResolveSuspect(v, generation, false); }

bool SampleCache::ResolveSuspect(VertexId v, uint32_t generation, bool keep) {
  Slot* found = const_cast<Slot*>(Find(v));
  if (!found) return false;
  Slot& s = *found;
  const uint32_t sequence = BeginWrite(s);
  // Only the suspect sample of that very generation: anything written since
  // owns the vertex now.
  const bool ok = s.suspect.load(kRelaxed) != 0 && s.generation.load(kRelaxed) == generation;
  if (ok) {
    s.suspect.store(0, std::memory_order_release);
    if (keep) {
      s.awaitingReshade.store(0, std::memory_order_release);
      s.shaded.store(1, std::memory_order_release);
    } else {  // stays AwaitingReshade, its values gone
      WriteValues(s, ShadedSample{v, Rgb(0.0f), Rgb(0.0f), 0.0f, 0, 0, 0}, 0);
      s.generation.fetch_add(1, std::memory_order_release);
    }
  }
  EndWrite(s, sequence);
  if (ok) {
    ++changes_;
    if (keep) {
      ++shadedCount_;
      ++confirmed_;
    } else {
      ++failedTests_;
    }
  }
  return ok;
}

}  // namespace penumbra::sma
