#include "penumbra/sma/sample_cache.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <new>
#include <thread>

#include <sys/mman.h>

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

namespace {
// A chunk's slots: anonymous pages of their own, so that a drop can give
// them back (MADV_DONTNEED) while they stay mapped and read as zeros.
void* MapChunk(size_t bytes) {
  void* memory = mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (memory == MAP_FAILED) throw std::bad_alloc();
  return memory;
}
}  // namespace

SampleCache::SampleCache() : directory_(new std::atomic<Page*>[kTopEntries]()) {}

SampleCache::~SampleCache() {
  for (const auto& chunk : chunks_) munmap(chunk->slots, ChunkBytes());
}

void SampleCache::Reserve(size_t vertexCount) {
  if (vertexCount <= Size()) return;
  std::lock_guard lock(growthMutex_);
  if (vertexCount <= size_.load(kRelaxed)) return;
  PENUMBRA_CHECK(vertexCount - 1 <= std::numeric_limits<VertexId>::max(),
                 fmt::format("sample cache of {} vertices", vertexCount));
  size_.store(vertexCount, std::memory_order_release);
}

size_t SampleCache::ChunkBytes() {
  static_assert(kChunkSlots * sizeof(Slot) % 4096 == 0, "a chunk's slots are whole pages");
  return kChunkSlots * sizeof(Slot);
}

size_t SampleCache::MemoryBytes() const {
  // A dropped chunk's record: its size and a hash node's pointers and hash.
  constexpr size_t kDroppedRecordBytes = sizeof(DroppedChunk) + sizeof(uint32_t) + 3 * sizeof(void*);
  return kTopEntries * sizeof(std::atomic<Page*>) + pagesAllocated_.load(kRelaxed) * sizeof(Page) +
         chunksMade_.load(kRelaxed) * sizeof(Chunk) + chunksInUse_.load(kRelaxed) * ChunkBytes() +
         droppedRecords_.load(kRelaxed) * kDroppedRecordBytes;
}

SampleCache::Chunk* SampleCache::MakeChunk(VertexId v) {
  std::lock_guard lock(growthMutex_);
  std::atomic<Page*>& top = directory_[v >> kTopShift];
  Page* page = top.load(kRelaxed);
  if (!page) {
    pages_.push_back(std::make_unique<Page>());
    page = pages_.back().get();
    top.store(page, std::memory_order_release);
    pagesAllocated_.fetch_add(1, kRelaxed);
  }
  const size_t entryIndex = (v >> kChunkBits) & (kPageEntries - 1);
  std::atomic<Chunk*>& entry = page->chunks[entryIndex];
  if (Chunk* inUse = entry.load(kRelaxed)) return inUse;  // made meanwhile
  Chunk* chunk = nullptr;
  if (!freeChunks_.empty()) {
    chunk = freeChunks_.back();  // its slots read zero: given back when it was dropped
    freeChunks_.pop_back();
  } else {
    chunks_.push_back(std::make_unique<Chunk>());
    chunk = chunks_.back().get();
    chunk->slots = static_cast<Slot*>(MapChunk(ChunkBytes()));
    std::uninitialized_value_construct_n(chunk->slots, kChunkSlots);
    chunksMade_.fetch_add(1, kRelaxed);
  }
  // Odd until published: a reader that still holds this record from its
  // previous index looks up again.
  PENUMBRA_CHECK(chunk->incarnation.load(kRelaxed) & 1u, "a chunk being made is not in use");
  const uint32_t chunkIndex = uint32_t(v >> kChunkBits);
  if (auto dropped = dropped_.find(chunkIndex); dropped != dropped_.end()) {
    for (size_t i = 0; i < kChunkSlots; ++i) {
      Slot& s = chunk->slots[i];
      s.validFrom.store(dropped->second.validFrom, kRelaxed);
      s.generation.store(dropped->second.generation + 1, kRelaxed);
      s.dropped.store(dropped->second.shaded[i] ? 1 : 0, kRelaxed);
    }
    dropped_.erase(dropped);
    droppedRecords_.store(dropped_.size(), kRelaxed);
  }
  chunk->index.store(chunkIndex, kRelaxed);
  chunk->lastUse.store(Tick(), kRelaxed);
  chunk->incarnation.store(chunk->incarnation.load(kRelaxed) + 1, std::memory_order_release);
  // Release: a reader that finds the pointer sees the chunk as made.
  entry.store(chunk, std::memory_order_release);
  chunksInUse_.fetch_add(1, kRelaxed);
  return chunk;
}

SampleCache::SlotWrite SampleCache::EnterSlot(VertexId v, bool make) {
  if (make && v >= Size()) Reserve(size_t(v) + 1);
  const uint32_t index = uint32_t(v >> kChunkBits);
  for (;;) {
    Chunk* chunk = const_cast<Chunk*>(FindChunk(v));
    if (!chunk) {
      if (!make) return SlotWrite(nullptr, nullptr);
      chunk = MakeChunk(v);
    }
    // Dekker-style with DropChunk (which makes the incarnation odd, then
    // reads the writers): sequentially consistent, so that either the drop
    // sees this writer or this writer sees the drop.
    chunk->writers.fetch_add(1, std::memory_order_seq_cst);
    const uint64_t incarnation = chunk->incarnation.load(std::memory_order_seq_cst);
    if (!(incarnation & 1u) && chunk->index.load(kRelaxed) == index)
      return SlotWrite(chunk, &chunk->slots[v & (kChunkSlots - 1)]);
    chunk->writers.fetch_sub(1, std::memory_order_release);
    // A drop in progress holds the growth mutex to its end: wait for it,
    // then look up again.
    std::lock_guard wait(growthMutex_);
  }
}

void SampleCache::Touch(VertexId v) const {
  const Chunk* chunk = FindChunk(v);
  if (!chunk) return;
  // A stale record (dropped meanwhile) takes a harmless store: MakeChunk
  // sets the last use of the chunk it makes.
  const uint32_t now = Tick();
  auto& lastUse = const_cast<std::atomic<uint32_t>&>(chunk->lastUse);
  if (lastUse.load(kRelaxed) != now) lastUse.store(now, kRelaxed);
}

std::vector<std::pair<uint32_t, uint32_t>> SampleCache::OldChunks(VertexId first, VertexId end,
                                                                  uint32_t minAgeTicks) const {
  std::vector<std::pair<uint32_t, uint32_t>> old;
  const size_t last = std::min<size_t>(end, Size());
  const uint32_t now = Tick();
  for (size_t c = (size_t(first) + kChunkSlots - 1) >> kChunkBits; (c + 1) << kChunkBits <= last; ++c) {
    const Page* page = directory_[c >> kPageBits].load(std::memory_order_acquire);
    if (!page) {
      c |= kPageEntries - 1;  // the whole page is unused
      continue;
    }
    const Chunk* chunk = page->chunks[c & (kPageEntries - 1)].load(std::memory_order_acquire);
    if (!chunk) continue;
    const uint32_t lastUse = chunk->lastUse.load(kRelaxed);
    if (now - lastUse >= minAgeTicks) old.emplace_back(lastUse, uint32_t(c));  // unsigned: wraps with the tick
  }
  return old;
}

std::optional<uint32_t> SampleCache::ChunkLastUse(uint32_t chunk) const {
  const Page* page = directory_[chunk >> kPageBits].load(std::memory_order_acquire);
  if (!page) return std::nullopt;
  const Chunk* found = page->chunks[chunk & (kPageEntries - 1)].load(std::memory_order_acquire);
  if (!found) return std::nullopt;
  return found->lastUse.load(kRelaxed);
}

std::optional<size_t> SampleCache::DropChunk(uint32_t chunkIndex) {
  std::lock_guard lock(growthMutex_);
  Page* page = directory_[chunkIndex >> kPageBits].load(kRelaxed);
  if (!page) return std::nullopt;
  const size_t entryIndex = chunkIndex & (kPageEntries - 1);
  std::atomic<Chunk*>& entry = page->chunks[entryIndex];
  Chunk* chunk = entry.load(kRelaxed);
  if (!chunk) return std::nullopt;
  // Only holders of the growth mutex change a chunk's incarnation: it is
  // even here. Odd from now: readers wait, writers wait on this mutex.
  const uint64_t incarnation = chunk->incarnation.load(kRelaxed);
  chunk->incarnation.store(incarnation + 1, std::memory_order_seq_cst);
  while (chunk->writers.load(std::memory_order_seq_cst) != 0) std::this_thread::yield();  // a few stores each
  DroppedChunk record;
  size_t shaded = 0;
  for (size_t i = 0; i < kChunkSlots; ++i) {
    const Slot& s = chunk->slots[i];
    if (s.awaitingReshade.load(kRelaxed) || s.suspect.load(kRelaxed)) {
      // A move's state must stay: the chunk is in use again, as it was.
      chunk->incarnation.store(incarnation + 2, std::memory_order_release);
      return std::nullopt;
    }
    // A sample dropped before and not shaded since still counts as dropped.
    const bool had = s.shaded.load(kRelaxed) || s.dropped.load(kRelaxed);
    shaded += s.shaded.load(kRelaxed) ? 1 : 0;
    record.shaded[i] = had;
    record.validFrom = std::max(record.validFrom, s.validFrom.load(kRelaxed));
    record.generation = std::max(record.generation, s.generation.load(kRelaxed));  // the next chunk's start above it
  }
  dropped_[chunkIndex] = record;
  droppedRecords_.store(dropped_.size(), kRelaxed);
  entry.store(nullptr, std::memory_order_release);
  // The pages go back to the system and read as zeros from now on: a
  // never-shaded slot, which MakeChunk starts from.
  PENUMBRA_CHECK(madvise(chunk->slots, ChunkBytes(), MADV_DONTNEED) == 0, "madvise(MADV_DONTNEED) of a cache chunk");
  freeChunks_.push_back(chunk);
  chunksInUse_.fetch_sub(1, kRelaxed);
  chunksDropped_.fetch_add(1, kRelaxed);
  shadedCount_ -= shaded;
  changes_ += shaded;
  return shaded;
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
  return ReadSlot(v, [&read](const Slot& s) {
    for (;;) {
      const uint32_t before = s.sequence.load(std::memory_order_acquire);
      if (before & 1u) {
        std::this_thread::yield();
        continue;
      }
      auto value = read(s);
      std::atomic_thread_fence(std::memory_order_acquire);
      if (s.sequence.load(kRelaxed) == before) return value;
    }
  });
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
  return ReadSlot(v, [](const Slot& s) {
    return s.shaded.load(std::memory_order_acquire) ? s.irradianceStdErr.load(kRelaxed) : 0.0f;
  });
}
uint32_t SampleCache::Paths(VertexId v) const {
  return ReadSlot(v, [](const Slot& s) { return s.shaded.load(std::memory_order_acquire) ? s.paths.load(kRelaxed) : 0u; });
}
uint16_t SampleCache::Rounds(VertexId v) const {
  return ReadSlot(v, [](const Slot& s) {
    return s.shaded.load(std::memory_order_acquire) ? s.rounds.load(kRelaxed) : uint16_t(0);
  });
}
uint32_t SampleCache::Generation(VertexId v) const {
  return ReadSlot(v, [](const Slot& s) { return s.generation.load(std::memory_order_acquire); });
}
uint64_t SampleCache::ValidFrom(VertexId v) const {
  const uint64_t floor = UnshadedValidFrom();
  return ReadSlot(v, [&](const Slot& s) {
    const uint64_t own = s.validFrom.load(std::memory_order_acquire);
    return s.shaded.load(std::memory_order_acquire) != 0 ? own : std::max(own, floor);
  });
}

void SampleCache::InvalidateUnshaded(uint64_t epoch) {
  uint64_t floor = unshadedValidFrom_.load(kRelaxed);
  while (floor < epoch && !unshadedValidFrom_.compare_exchange_weak(floor, epoch, std::memory_order_seq_cst)) {
  }
  // Dekker's pattern with Put (file comment): the caller's reads of slots
  // that follow are ordered after the floor's write.
  std::atomic_thread_fence(std::memory_order_seq_cst);
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
    // A vertex with no chunk (never written, or dropped) is unshaded and
    // awaits no reshade: an improvement has nothing to do there.
    const SlotWrite found = EnterSlot(sample.vertex, /*make=*/false);
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
    const SlotWrite write = EnterSlot(sample.vertex, /*make=*/true);
    Slot& s = *write;
    const uint32_t sequence = BeginWrite(s);
    // The floor of slots with no sample is read after this write made the
    // slot's sequence odd (InvalidateUnshaded: Dekker's pattern): a planner
    // that read the slot unshaded before that is seen here.
    std::atomic_thread_fence(std::memory_order_seq_cst);
    const uint64_t floor = s.shaded.load(kRelaxed) ? 0 : unshadedValidFrom_.load(kRelaxed);
    // The epoch check is inside the slot's sequence, like Invalidate's
    // write of validFrom: whichever comes second sees the other.
    if (sample.epoch < s.validFrom.load(kRelaxed) || sample.epoch < floor) {
      if (stale) stale->push_back(sample.vertex);
    } else if (!s.shaded.load(kRelaxed)) {
      WriteValues(s, sample, keepRounds ? sample.round : 0);
      if (s.awaitingReshade.exchange(0, kRelaxed)) ++reshaded_;
      if (s.dropped.exchange(0, kRelaxed)) ++reshadedAfterDrop_;
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
  const SlotWrite found = EnterSlot(v, /*make=*/false);
  if (!found) return false;  // no chunk: nothing to evict, and none made for it
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
  const SlotWrite found = EnterSlot(v, /*make=*/false);
  if (!found) return false;  // no chunk: it reads unshaded already
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
  const SlotWrite write = EnterSlot(v, /*make=*/true);
  Slot& s = *write;
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
  const SlotWrite found = EnterSlot(v, /*make=*/false);
  if (!found) return std::nullopt;  // no chunk: nothing to test
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
  const SlotWrite found = EnterSlot(v, /*make=*/false);
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
