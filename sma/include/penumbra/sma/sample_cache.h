#pragma once
// The object-space sample cache: one shading sample per hierarchy vertex,
// shared by every client (paper §2). A sample is either shaded, with its
// radiance and irradiance, or not yet. A shaded sample can be improved in
// place: a further, independent estimate (an improvement round, with a random
// stream of its own) is averaged in, weighted by the paths of each, so that
// the noise of what clients see falls as a view rests; who asked for it and
// whether it is on its way is the renderer pool's business, not the cache's.
//
// Threads: every function may be called from any thread, with no outside
// lock: samples are stored and improved (I/O threads) while views read them
// (job threads). The state lock guards the hierarchy, not the cache.
//  * Storage never moves: slots live in fixed-size chunks found through a
//    directory allocated once, so a reader's slot stays where it is while
//    the hierarchy's growth grows the cache (only growth takes a mutex, and
//    readers never take it).
//  * Storage is lazy (issue 15: memory follows what has been seen, not the
//    model's size): Reserve() only extends the id range; a chunk is
//    allocated by the first write into it (Store, Restore, Invalidate), and
//    a read of a vertex whose chunk does not exist reads an unshaded slot
//    of generation 0 -- what the chunk's slots hold when it is made.
//  * Each slot is a sequence lock: a writer makes its sequence odd, writes,
//    and makes it even again (release); Read() retries until it saw one even
//    sequence before and after, so it returns a whole sample, never half of
//    an improvement. IsShaded() is one acquire load.
//  * Replacement and removal (moving objects invalidate samples, issue 14;
//    eviction will bound memory, issue 15) are writes like any other:
//    Evict() and Invalidate() clear a slot under its sequence and bump its
//    generation. A reader holds values it copied, never a reference into a
//    slot, so it is never left with a torn or freed sample; one that must
//    know whether what it copied is still current compares
//    CachedSample::generation with Generation().
//  * Dropping chunks (issue 15: samples no one holds are dropped). The ids
//    of base vertices are never freed, so their samples are let go a chunk
//    at a time: DropChunk() evicts every sample of a chunk and gives its
//    pages back to the system (madvise), and the chunk record goes to a
//    free list that the next chunk made reuses. Chunk memory is never
//    unmapped while the cache lives (type-stable, like the kernel's
//    SLAB_TYPESAFE_BY_RCU): a reader that found a chunk just before it was
//    dropped still reads mapped memory (zeros), so readers need no
//    reclamation scheme and take no lock and no read-modify-write. Each
//    chunk carries an incarnation, a sequence lock one level up from the
//    slots': odd while it is being dropped, dropped or being reused; a
//    reader checks it is even and names the chunk index it looked up,
//    before and after its read, and looks the chunk up again otherwise.
//    Writers count themselves into the chunk (one atomic increment per
//    write, which readers do not pay); a drop makes the incarnation odd,
//    waits for the writers inside to leave (a few stores each) and holds
//    the growth mutex throughout, so a writer that meets a drop waits on
//    that mutex for it to end. What a dropped chunk's slots must pass on --
//    their highest ValidFrom (epochs only rise) and generation (a copy a
//    reader holds must never look current again) -- is kept per chunk
//    index and given to the next chunk made there. Chunks have ages like
//    the hierarchy's nodes (Touch, on the collector's clock, SetTick); the
//    collector decides which to drop (collector.h).
//  * Scene epochs (issue 14). Each slot keeps the epoch its sample was
//    shaded at and the epoch it is valid from (`validFrom`): Invalidate(v, e)
//    raises validFrom to e, and every write -- Store, Improve, Restore --
//    compares the sample's epoch with validFrom inside the slot's sequence,
//    so a sample shaded at a pose older than the vertex's last invalidation
//    is refused whatever order the reply and the move reach the slot in
//    (the check and the invalidation are both writes of the one slot, so
//    they are ordered). A vertex whose sample was invalidated (not merely
//    never shaded) reads `AwaitingReshade` until a valid sample is stored:
//    visibility still descends through splits whose midpoints await a
//    reshade, so a client keeps the triangles it holds (and their old
//    radiance, its own copy) until the RESHADED update replaces it.
//    A move also changes what every vertex with no sample should be shaded
//    at, and most of a refined hierarchy's vertices have none (287 k of
//    299 k in the breakfast room seen once): InvalidateUnshaded(e) raises
//    one cache-wide floor instead of each one's ValidFrom (which touched,
//    and allocated a chunk for, every one of them on every move). A first
//    estimate stored into a slot with no sample must be shaded at the
//    floor or later. The floor's write and a Put's read of it are ordered
//    against the slot's sequence by a seq_cst fence on each side (Dekker's
//    pattern): a planner that raised the floor and then reads a slot as
//    unshaded knows that any store into it that it did not see will see
//    the floor.

#include <atomic>
#include <bitset>
#include <cstdint>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <unordered_map>
#include <thread>
#include <utility>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/sma/hierarchy.h"
namespace penumbra::sma {

struct ShadedSample {
  VertexId vertex = kNoVertex;
  Rgb radiance{0.0f};
  Rgb irradiance{0.0f};
  float irradianceStdErr = 0.0f;  // standard error of Luminance(irradiance), from the renderer
  uint32_t paths = 1;             // paths the estimate averages
  uint16_t round = 0;             // 0: the first estimate; k > 0: the k-th improvement
  uint64_t epoch = 0;             // the scene epoch (pose) it was shaded at
};

/// What a renderer's sample can physically be in one scene, so that a bad or
/// hostile renderer cannot poison the cache that every client is served from.
/// Reflected radiance is non-negative and, for albedo <= 1, at most the
/// brightest emitter's radiance L; irradiance at most pi L. One Monte Carlo
/// estimate may overshoot the physical value (a path that lands close to a
/// light), so the bounds are `kMonteCarloMargin` times wider: absurd values
/// (1e30, 3e38) fail, noisy honest ones pass.
struct RadianceBounds {
  static constexpr float kMonteCarloMargin = 1.0e4f;
  float maxRadiance = std::numeric_limits<float>::max();
  float maxIrradiance = std::numeric_limits<float>::max();

  static RadianceBounds ForScene(const Scene& scene);
  /// OK, or what is wrong with the sample (non-finite, negative, too bright).
  Status Check(const ShadedSample& sample) const;
};

/// One shaded sample as a reader copied it (SampleCache::Read).
struct CachedSample {
  Rgb radiance{0.0f};
  Rgb irradiance{0.0f};
  float irradianceStdErr = 0.0f;
  uint32_t paths = 0;
  uint16_t rounds = 0;
  uint32_t generation = 0;  // the slot's generation when read (Evict bumps it)
  uint64_t epoch = 0;       // the scene epoch it was shaded at
};

class SampleCache {
 public:
  SampleCache();
  ~SampleCache();
  SampleCache(const SampleCache&) = delete;
  SampleCache& operator=(const SampleCache&) = delete;

  /// Grows to cover `vertexCount` vertices (new ones unshaded). Allocates
  /// nothing: chunks come with their first write. Takes the growth mutex.
  void Reserve(size_t vertexCount);
  size_t Size() const { return size_.load(std::memory_order_acquire); }

  bool IsShaded(VertexId v) const {
    return ReadSlot(v, [](const Slot& s) { return s.shaded.load(std::memory_order_acquire) != 0; });
  }
  /// The whole sample of a shaded vertex, as one consistent copy; nothing
  /// for an unshaded one.
  std::optional<CachedSample> Read(VertexId v) const;
  /// Single fields (each a consistent read of its own; use Read() for
  /// several fields of one version). Zero for an unshaded vertex.
  Rgb Radiance(VertexId v) const;
  Rgb Irradiance(VertexId v) const;
  float IrradianceStdErr(VertexId v) const;
  /// Paths averaged into a shaded sample, and the improvement rounds so far.
  uint32_t Paths(VertexId v) const;
  uint16_t Rounds(VertexId v) const;
  /// Generation of a vertex's slot: bumped by every Evict() and Invalidate().
  uint32_t Generation(VertexId v) const;
  /// Whether the vertex's sample was invalidated by a move and no valid one
  /// has been stored since (it is then unshaded, too).
  bool AwaitingReshade(VertexId v) const {
    return ReadSlot(v, [](const Slot& s) { return s.awaitingReshade.load(std::memory_order_acquire) != 0; });
  }
  /// Whether the vertex's sample is held back awaiting a move's test
  /// (Suspect): then it is also unshaded and AwaitingReshade.
  bool IsSuspect(VertexId v) const {
    return ReadSlot(v, [](const Slot& s) { return s.suspect.load(std::memory_order_acquire) != 0; });
  }
  /// Whether the chunk of vertex ids holding `v` exists. Every vertex of a
  /// chunk that does not exists reads as never shaded -- no sample, none
  /// suspect, none awaiting a reshade -- so a scan for those can skip its
  /// kChunkVertices ids (PlanInvalidation does, after InvalidateUnshaded).
  bool HasChunk(VertexId v) const { return FindChunk(v) != nullptr; }
  /// The whole sample of a suspect vertex (as Read of a shaded one), for a
  /// later move to judge again; nothing when the vertex is not suspect.
  std::optional<CachedSample> ReadSuspect(VertexId v) const;
  /// The earliest scene epoch a sample of this vertex may have been shaded
  /// at to be stored (0 for a vertex never invalidated): its own, and for a
  /// vertex with no sample at least the floor (InvalidateUnshaded).
  uint64_t ValidFrom(VertexId v) const;
  /// Relative standard error of a shaded sample's irradiance luminance: 0
  /// for an unshaded vertex and for a lit sample with no spread (every path
  /// agreed, e.g. an open uniform sky); infinite for a sample that reads
  /// black from fewer than kBlackPaths paths (paths that found nothing do
  /// not show there is nothing to find), 0 once that many have found nothing.
  float RelativeError(VertexId v) const;
  /// The first estimate's paths (`--first-paths`, 8) and one improvement
  /// round of 64: on the grey-white room's sofa nearly all of what
  /// improving black samples gains (docs/refinement.md, third round, measured
  /// with 16 first paths and 80), without improving every hidden vertex to
  /// the path cap.
  static constexpr uint32_t kBlackPaths = 72;
  /// Luminance of the shaded radiance (0 when unshaded).
  float Luminance(VertexId v) const { return penumbra::Luminance(Radiance(v)); }

  /// Stores first estimates (round 0); a vertex beyond Size() grows the
  /// cache. Storing a vertex twice keeps the first value (samples are
  /// deterministic, so a second one can only be a duplicate). A sample
  /// shaded at an epoch before the vertex's ValidFrom is refused and, when
  /// `stale` is given, its vertex appended there (to be asked again).
  /// Returns how many were new.
  size_t Store(std::span<const ShadedSample> samples, std::vector<VertexId>* stale = nullptr);
  /// Averages improvements (round k > 0) into shaded samples, weighted by
  /// paths; the standard errors combine accordingly. An improvement of an
  /// unshaded vertex, or whose round is not the vertex's next, is ignored;
  /// one shaded before the vertex's ValidFrom, or of a vertex awaiting its
  /// reshade, is refused and appended to `stale` (when given): the vertex
  /// needs a first estimate again. Returns the vertices that changed.
  std::vector<VertexId> Improve(std::span<const ShadedSample> samples, std::vector<VertexId>* stale = nullptr);
  /// Puts back samples as a snapshot saved them (CacheSnapshot), with their
  /// paths and improvement rounds, into vertices not yet shaded; a vertex
  /// beyond Size() grows the cache. Returns how many were put back.
  size_t Restore(std::span<const ShadedSample> samples);
  /// Forgets a vertex's sample (it becomes unshaded) and bumps its slot's
  /// generation, so that a reader holding an older copy can tell. For
  /// invalidation and eviction; whoever calls it keeps the pool's rule (a
  /// vertex is in the cache or alive in the pool) by requesting it again if
  /// it is still needed. Returns whether it was shaded.
  bool Evict(VertexId v);
  /// The vertex's id was freed (the collector collapsed the subtree that
  /// made it; hierarchy.h "Collection") and may name another vertex next:
  /// the slot reads as never shaded -- no sample, not awaiting a reshade,
  /// no paths or rounds -- and its generation is bumped. Its ValidFrom is
  /// kept (epochs only rise). The caller makes sure no request for the
  /// vertex is alive in the pool. Returns whether it was shaded.
  bool Forget(VertexId v);
  /// A move at scene epoch `epoch` changed what this vertex's sample should
  /// be: from now on only samples shaded at `epoch` or later are stored
  /// (ValidFrom), and a stored sample shaded earlier is evicted (as Evict,
  /// and the vertex then reads AwaitingReshade). A sample already shaded at
  /// `epoch` or later is kept. Returns whether a sample was evicted.
  /// A suspect sample counts as stored: Invalidate drops it too (and
  /// returns true).
  bool Invalidate(VertexId v, uint64_t epoch);
  /// A move at scene epoch `epoch`, for every vertex that has no sample
  /// (never shaded, evicted, forgotten, dropped, awaiting a reshade): from
  /// now on a first estimate is stored into a slot with no sample only if
  /// shaded at `epoch` or later -- Invalidate(v, epoch) on each of them,
  /// touching none. Call it before reading which vertices have samples
  /// (see the file comment). The floor only rises.
  void InvalidateUnshaded(uint64_t epoch);
  uint64_t UnshadedValidFrom() const { return unshadedValidFrom_.load(std::memory_order_acquire); }
  /// As Invalidate, but the sample shaded before `epoch` is kept in the slot
  /// for a test (see the file comment): the vertex reads unshaded,
  /// AwaitingReshade and IsSuspect. A suspect sample is suspected again for
  /// the later epoch. Returns the slot's new generation, for Confirm or
  /// FailSuspect; nothing when there was no sample shaded before `epoch`
  /// (none at all: nothing to test; one shaded at `epoch` or later: valid).
  std::optional<uint32_t> Suspect(VertexId v, uint64_t epoch);
  /// The test passed: the suspect sample of generation `generation` is valid
  /// again, as it was (shaded, not awaiting a reshade). False -- nothing
  /// done -- when the slot was written since (not suspect, or another
  /// generation).
  bool Confirm(VertexId v, uint32_t generation);
  /// The test failed: the suspect sample of generation `generation` is
  /// dropped; the vertex stays AwaitingReshade (the caller asks for it).
  /// False -- nothing done -- when the slot was written since.
  bool FailSuspect(VertexId v, uint32_t generation);
  /// Samples a test kept (Confirm) and dropped (FailSuspect) so far.
  uint64_t Confirmed() const { return confirmed_.load(std::memory_order_relaxed); }
  uint64_t FailedTests() const { return failedTests_.load(std::memory_order_relaxed); }

  /// Bytes one vertex's slot takes (a freed vertex's slot is reused by the
  /// next vertex made: the collector counts it free).
  static size_t SlotBytes();
  size_t ShadedCount() const { return shadedCount_.load(std::memory_order_relaxed); }
  /// Bytes the cache occupies: its chunk directory, the chunk records and
  /// the slots of the chunks in use -- not those of dropped chunks, whose
  /// pages went back to the system (issue 15's memory accounting). Any thread.
  size_t MemoryBytes() const;

  // --- Dropping chunks (issue 15; the file comment says how) --------------
  /// Vertices per chunk: what DropChunk lets go of at once. Chunk c holds
  /// vertices [c * kChunkVertices, (c + 1) * kChunkVertices).
  static constexpr size_t kChunkVertices = size_t(1) << 10;
  /// Bytes of one chunk's slots (what a drop gives back).
  static size_t ChunkBytes();
  /// The collector's clock, in its ticks (SMA: Hierarchy::SetTick's). A
  /// chunk made or touched takes the current tick as its last use.
  void SetTick(uint32_t tick) { tick_.store(tick, std::memory_order_relaxed); }
  uint32_t Tick() const { return tick_.load(std::memory_order_relaxed); }
  /// A view displayed, or a prediction asked for, a node with this corner:
  /// its chunk's last use is now. Nothing for a vertex with no chunk. Any
  /// thread, no lock (one relaxed store when the tick moved).
  void Touch(VertexId v) const;
  /// The chunks in use that lie wholly within vertices [first, end) and
  /// were last used `minAgeTicks` or more ago: (last use, chunk index).
  std::vector<std::pair<uint32_t, uint32_t>> OldChunks(VertexId first, VertexId end, uint32_t minAgeTicks) const;
  /// The tick chunk `chunk` was last used at; nothing if it is not in use.
  std::optional<uint32_t> ChunkLastUse(uint32_t chunk) const;
  /// Drops chunk `chunk`: its samples are evicted (unshaded, generations
  /// bumped, ValidFrom kept) and its pages given back. Refused -- nothing
  /// changes -- when it is not in use or a slot is AwaitingReshade or
  /// suspect (a move's state, which must stay). Whoever calls it makes sure
  /// no client holds and no renderer shades its vertices (the collector's
  /// `keep`). Returns the samples dropped, or nothing if refused. Takes the
  /// growth mutex; waits for the writers inside the chunk to leave.
  std::optional<size_t> DropChunk(uint32_t chunk);
  /// First estimates stored into vertices whose sample went with a dropped
  /// chunk: the re-shading dropping cost (issue 15).
  uint64_t ReshadedAfterDrop() const { return reshadedAfterDrop_.load(std::memory_order_relaxed); }
  /// Chunks dropped since the cache was made, and chunks in use now.
  uint64_t ChunksDropped() const { return chunksDropped_.load(std::memory_order_relaxed); }
  size_t ChunksInUse() const { return chunksInUse_.load(std::memory_order_relaxed); }
  /// First estimates stored into vertices awaiting a reshade (a move
  /// invalidated their sample), since the cache was made.
  uint64_t Reshaded() const { return reshaded_.load(std::memory_order_relaxed); }
  /// Counts every sample stored, improved, restored or evicted: a snapshot
  /// is due when it moved since the last one.
  uint64_t Changes() const { return changes_.load(std::memory_order_relaxed); }

  /// Lookup statistics for the hit rate: a lookup of a vertex a view needed.
  void CountLookups(uint64_t hits, uint64_t misses) const {
    hits_ += hits;
    misses_ += misses;
  }
  uint64_t Hits() const { return hits_; }
  uint64_t Misses() const { return misses_; }

 private:
  // Every field is an atomic so that a reader racing a writer is defined
  // behaviour (and quiet under ThreadSanitizer); the sequence orders them.
  struct Slot {
    std::atomic<uint32_t> sequence{0};  // odd while a writer is in the slot
    std::atomic<uint32_t> generation{0};
    std::atomic<uint8_t> shaded{0};
    std::atomic<uint8_t> dropped{0};  // a sample of this vertex went with a dropped chunk (ReshadedAfterDrop)
    std::atomic<float> radiance[3];
    std::atomic<float> irradiance[3];
    std::atomic<float> irradianceStdErr{0.0f};
    std::atomic<uint32_t> paths{0};
    std::atomic<uint16_t> rounds{0};
    std::atomic<uint8_t> awaitingReshade{0};
    std::atomic<uint8_t> suspect{0};  // values kept for a move's test (Suspect)
    std::atomic<uint64_t> epoch{0};      // of the stored sample
    std::atomic<uint64_t> validFrom{0};  // samples shaded before this epoch are refused
  };
  // Chunks are small (64 KiB) so that lazy storage follows what was seen
  // closely; the directory has two levels so that its own size stays small
  // for any id range: a fixed top level of 1 Ki entries, each a page of
  // 4 Ki chunk pointers (covering 4 Mi vertices) made with its first chunk.
  static constexpr unsigned kChunkBits = 10;  // 1 Ki slots per chunk
  static constexpr size_t kChunkSlots = size_t(1) << kChunkBits;
  static_assert(kChunkSlots == kChunkVertices);
  static constexpr unsigned kPageBits = 12;   // chunk pointers per directory page: 4 Ki
  static constexpr size_t kPageEntries = size_t(1) << kPageBits;
  static constexpr unsigned kTopShift = kChunkBits + kPageBits;
  static constexpr size_t kTopEntries = (size_t(std::numeric_limits<VertexId>::max()) >> kTopShift) + 1;

  // A chunk's slots and what guards their reuse ("Dropping chunks").
  struct Chunk {
    std::atomic<uint64_t> incarnation{1};  // even: serves `index`; odd: being dropped, dropped or being made
    std::atomic<uint32_t> index{0};        // the chunk index (v >> kChunkBits) it serves
    std::atomic<uint32_t> writers{0};      // writers inside its slots now
    std::atomic<uint32_t> lastUse{0};      // tick of its last Touch, or of its making
    Slot* slots = nullptr;                 // kChunkSlots, mapped until the cache goes
  };
  // What a dropped chunk's slots pass on to the next chunk of its index.
  struct DroppedChunk {
    uint64_t validFrom = 0;          // the highest ValidFrom of its slots
    uint32_t generation = 0;         // the highest generation of its slots
    std::bitset<kChunkSlots> shaded;  // the slots that had a sample
  };
  struct Page {
    std::atomic<Chunk*> chunks[kPageEntries];  // null: no chunk in use
  };

  // The chunk in use for `v`'s index when looked up (it may be being
  // dropped: ReadSlot checks); null for a vertex beyond Size() or whose
  // chunk was never written or was dropped.
  const Chunk* FindChunk(VertexId v) const {
    if (v >= Size()) return nullptr;
    const Page* page = directory_[v >> kTopShift].load(std::memory_order_acquire);
    return page ? page->chunks[(v >> kChunkBits) & (kPageEntries - 1)].load(std::memory_order_acquire) : nullptr;
  }
  // read(slot) on `v`'s slot -- or on an all-zero, unshaded slot when it has
  // no chunk -- retried until the chunk's incarnation was even, named `v`'s
  // chunk index and did not change across the read (the file comment).
  // `read` must only load from the slot and be repeatable.
  template <typename F>
  auto ReadSlot(VertexId v, F&& read) const -> decltype(read(std::declval<const Slot&>())) {
    const uint32_t index = uint32_t(v >> kChunkBits);
    for (;;) {
      const Chunk* chunk = FindChunk(v);
      if (!chunk) return read(Slot{});
      const uint64_t incarnation = chunk->incarnation.load(std::memory_order_acquire);
      if (incarnation & 1u) {  // a drop in progress (the directory entry goes) or a chunk made meanwhile
        std::this_thread::yield();
        continue;
      }
      if (chunk->index.load(std::memory_order_relaxed) != index) continue;  // reused since the look-up
      auto value = read(chunk->slots[v & (kChunkSlots - 1)]);
      std::atomic_thread_fence(std::memory_order_acquire);
      if (chunk->incarnation.load(std::memory_order_relaxed) == incarnation) return value;
    }
  }
  // A writer inside one slot: counted into its chunk, so that no drop
  // begins until it leaves (the destructor).
  class SlotWrite {
   public:
    SlotWrite(Chunk* chunk, Slot* slot) : chunk_(chunk), slot_(slot) {}
    SlotWrite(const SlotWrite&) = delete;
    SlotWrite& operator=(const SlotWrite&) = delete;
    ~SlotWrite() {
      if (chunk_) chunk_->writers.fetch_sub(1, std::memory_order_release);
    }
    explicit operator bool() const { return slot_ != nullptr; }
    Slot& operator*() const { return *slot_; }

   private:
    Chunk* chunk_;
    Slot* slot_;
  };
  // Enters `v`'s slot to write it; with `make`, grows the cache and makes
  // the chunk when needed, else an empty SlotWrite when there is no chunk.
  SlotWrite EnterSlot(VertexId v, bool make);
  Chunk* MakeChunk(VertexId v);  // under growthMutex_; the chunk in use if there is one
  // Writer side of a slot's sequence lock (writers of one slot serialize on it).
  static uint32_t BeginWrite(Slot& s);
  static void EndWrite(Slot& s, uint32_t sequence) { s.sequence.store(sequence + 2, std::memory_order_release); }
  static void WriteValues(Slot& s, const ShadedSample& sample, uint16_t rounds);
  size_t Put(std::span<const ShadedSample> samples, bool keepRounds, std::vector<VertexId>* stale);  // Store, Restore
  bool ResolveSuspect(VertexId v, uint32_t generation, bool keep);  // Confirm, FailSuspect
  template <typename F>
  auto ReadConsistent(VertexId v, F&& read) const -> decltype(read(std::declval<const Slot&>()));

  std::unique_ptr<std::atomic<Page*>[]> directory_;  // kTopEntries pages, null until made
  std::mutex growthMutex_;  // Reserve, making and dropping chunks
  std::vector<std::unique_ptr<Page>> pages_;      // owned; under growthMutex_
  std::vector<std::unique_ptr<Chunk>> chunks_;    // every chunk made (slots unmapped with the cache); under growthMutex_
  std::vector<Chunk*> freeChunks_;                // dropped, to be reused; under growthMutex_
  std::unordered_map<uint32_t, DroppedChunk> dropped_;  // by chunk index, until made again; under growthMutex_
  std::atomic<size_t> droppedRecords_{0};               // dropped_.size() for MemoryBytes
  std::atomic<uint64_t> reshadedAfterDrop_{0};
  std::atomic<size_t> size_{0};
  std::atomic<size_t> chunksMade_{0};  // chunks_.size(), pages_.size() for MemoryBytes (no lock)
  std::atomic<size_t> chunksInUse_{0};
  std::atomic<size_t> pagesAllocated_{0};
  std::atomic<uint64_t> chunksDropped_{0};
  std::atomic<uint32_t> tick_{0};
  std::atomic<size_t> shadedCount_{0};
  std::atomic<uint64_t> changes_{0};
  std::atomic<uint64_t> unshadedValidFrom_{0};  // InvalidateUnshaded's floor
  std::atomic<uint64_t> reshaded_{0};
  std::atomic<uint64_t> confirmed_{0};
  std::atomic<uint64_t> failedTests_{0};
  mutable std::atomic<uint64_t> hits_{0};
  mutable std::atomic<uint64_t> misses_{0};
};

/// Whether the corners of `node` are all shaded.
inline bool CornersShaded(const Node& node, const SampleCache& cache) {
  return cache.IsShaded(node.v[0]) && cache.IsShaded(node.v[1]) && cache.IsShaded(node.v[2]);
}

}  // namespace penumbra::sma
