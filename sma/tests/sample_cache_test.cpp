// The sample cache written while it is read: whole samples, never torn,
// never lost to growth, eviction seen through generations. The concurrent
// cases are meant for ThreadSanitizer too (scripts/test.sh --tsan).

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cmath>
#include <functional>
#include <optional>
#include <thread>
#include <vector>

#include "penumbra/sma/sample_cache.h"

namespace penumbra::sma {
namespace {

// A sample whose three channels are equal and whose irradiance is twice its
// radiance: any mix of two such samples keeps both properties, a torn read
// of two different versions does not.
ShadedSample Sample(VertexId v, float value, uint16_t round = 0, uint32_t paths = 16) {
  return ShadedSample{v, Rgb(value), Rgb(2.0f * value), 0.1f * value, paths, round};
}

::testing::AssertionResult Whole(const CachedSample& s) {
  const Rgb& r = s.radiance;
  const Rgb& e = s.irradiance;
  if (r.r != r.g || r.g != r.b || e.r != e.g || e.g != e.b)
    return ::testing::AssertionFailure() << "channels differ: radiance (" << r.r << ", " << r.g << ", " << r.b
                                         << "), irradiance (" << e.r << ", " << e.g << ", " << e.b << ")";
  if (std::abs(e.r - 2.0f * r.r) > 1e-4f * std::max(1.0f, r.r))
    return ::testing::AssertionFailure() << "irradiance " << e.r << " is not twice radiance " << r.r;
  return ::testing::AssertionSuccess();
}

TEST(SampleCache, StoresOnceImprovesInOrderAndEvicts) {
  SampleCache cache;
  cache.Reserve(4);
  EXPECT_FALSE(cache.IsShaded(2));
  EXPECT_FALSE(cache.Read(2).has_value());
  EXPECT_EQ(cache.Store(std::vector{Sample(2, 1.0f)}), 1u);
  EXPECT_EQ(cache.Store(std::vector{Sample(2, 5.0f)}), 0u);  // a duplicate keeps the first
  ASSERT_TRUE(cache.Read(2).has_value());
  EXPECT_EQ(cache.Radiance(2).r, 1.0f);

  // Round 2 before round 1 is ignored; round 1 averages by paths (16 + 48).
  EXPECT_TRUE(cache.Improve(std::vector{Sample(2, 3.0f, 2)}).empty());
  EXPECT_EQ(cache.Improve(std::vector{Sample(2, 3.0f, 1, 48)}), std::vector<VertexId>{2});
  const CachedSample improved = *cache.Read(2);
  EXPECT_FLOAT_EQ(improved.radiance.r, 0.25f * 1.0f + 0.75f * 3.0f);
  EXPECT_EQ(improved.paths, 64u);
  EXPECT_EQ(improved.rounds, 1u);
  EXPECT_TRUE(Whole(improved));

  const uint32_t generation = cache.Generation(2);
  EXPECT_EQ(cache.ShadedCount(), 1u);
  EXPECT_TRUE(cache.Evict(2));
  EXPECT_FALSE(cache.Evict(2));
  EXPECT_FALSE(cache.IsShaded(2));
  EXPECT_EQ(cache.ShadedCount(), 0u);
  EXPECT_EQ(cache.Generation(2), generation + 1);
  EXPECT_EQ(cache.Radiance(2).r, 0.0f);
  // Shaded again after eviction, as a fresh first estimate.
  EXPECT_EQ(cache.Store(std::vector{Sample(2, 7.0f)}), 1u);
  EXPECT_EQ(cache.Read(2)->rounds, 0u);
  EXPECT_EQ(cache.Read(2)->generation, generation + 1);
}

TEST(SampleCache, GrowsPastChunksWithoutLosingSamples) {
  SampleCache cache;
  // Far beyond one chunk, grown by Store itself, out of order.
  constexpr VertexId kCount = 100000;
  for (VertexId v = kCount; v-- > 0;)
    if (v % 3 == 0) cache.Store(std::vector{Sample(v, float(v))});
  EXPECT_EQ(cache.Size(), size_t(kCount));
  EXPECT_EQ(cache.ShadedCount(), size_t((kCount + 2) / 3));
  for (VertexId v = 0; v < kCount; ++v) {
    ASSERT_EQ(cache.IsShaded(v), v % 3 == 0) << v;
    if (v % 3 == 0) {
      ASSERT_EQ(cache.Radiance(v).r, float(v));
    }
  }
  EXPECT_FALSE(cache.IsShaded(kCount + 5));  // beyond the end: unshaded, no growth
  EXPECT_EQ(cache.Size(), size_t(kCount));
}

// Issue 15: memory follows what has been written, not the id range.
TEST(SampleCache, ChunksAreAllocatedByTheFirstWriteOnly) {
  SampleCache cache;
  const size_t empty = cache.MemoryBytes();
  cache.Reserve(10'000'000);
  EXPECT_EQ(cache.Size(), 10'000'000u);
  EXPECT_EQ(cache.MemoryBytes(), empty);  // the range, no slots
  // Reads, improvements and evictions of unwritten vertices allocate nothing.
  EXPECT_FALSE(cache.IsShaded(9'000'000));
  EXPECT_FALSE(cache.Read(9'000'000));
  EXPECT_EQ(cache.Generation(9'000'000), 0u);
  EXPECT_FALSE(cache.AwaitingReshade(9'000'000));
  EXPECT_EQ(cache.ValidFrom(9'000'000), 0u);
  EXPECT_TRUE(cache.Improve(std::vector{Sample(9'000'000, 1.0f, 1)}).empty());
  EXPECT_FALSE(cache.Evict(9'000'000));
  EXPECT_EQ(cache.MemoryBytes(), empty);
  // One store: one chunk, whatever the id.
  EXPECT_EQ(cache.Store(std::vector{Sample(9'000'000, 3.0f)}), 1u);
  const size_t oneChunk = cache.MemoryBytes() - empty;
  EXPECT_GT(oneChunk, 0u);
  EXPECT_EQ(cache.Radiance(9'000'000).r, 3.0f);
  EXPECT_FALSE(cache.IsShaded(9'000'001));  // a neighbour in the chunk: unshaded
  EXPECT_EQ(cache.Store(std::vector{Sample(9'000'001, 4.0f)}), 1u);
  EXPECT_EQ(cache.MemoryBytes(), empty + oneChunk);
  // An invalidation is a write (it keeps the vertex's ValidFrom): it makes
  // the chunk of a vertex never shaded, and a stale sample is then refused.
  cache.Invalidate(5, 2);
  EXPECT_EQ(cache.MemoryBytes(), empty + 2 * oneChunk);
  std::vector<VertexId> stale;
  ShadedSample old = Sample(5, 1.0f);
  old.epoch = 1;
  EXPECT_EQ(cache.Store(std::vector{old}, &stale), 0u);
  EXPECT_EQ(stale, std::vector<VertexId>{5});
}

// Two writers store and improve, while the cache grows under them, and
// readers check that every sample they see is whole and that what was
// shaded stays shaded with its rounds and paths only rising.
TEST(SampleCache, ReadersSeeWholeSamplesWhileWritersStoreImproveAndGrow) {
  SampleCache cache;
  constexpr VertexId kVertices = 3 * 16384 + 100;  // three chunk boundaries crossed while read
  constexpr uint16_t kRounds = 6;
  std::atomic<bool> writersDone{false};
  std::atomic<uint64_t> samplesRead{0};

  auto writer = [&](VertexId first) {
    for (VertexId v = first; v < kVertices; v += 2) cache.Store(std::vector{Sample(v, float(v % 97) + 1.0f)});
    for (uint16_t round = 1; round <= kRounds; ++round)
      for (VertexId v = first; v < kVertices; v += 2)
        cache.Improve(std::vector{Sample(v, float(round * 1000 + v % 89), round, 16u << (round % 3))});
  };
  auto reader = [&](unsigned seed) {
    std::vector<uint16_t> lastRounds(kVertices, 0);
    std::vector<uint8_t> seenShaded(kVertices, 0);
    uint64_t read = 0;
    VertexId v = seed;
    while (!writersDone.load(std::memory_order_acquire) || read < 200000) {
      v = (v * 1103515245u + 12345u) % kVertices;
      const auto sample = cache.Read(v);
      if (!sample) {
        ASSERT_FALSE(seenShaded[v]) << "vertex " << v << " was shaded and is not any more";
        continue;
      }
      ++read;
      seenShaded[v] = 1;
      ASSERT_TRUE(Whole(*sample)) << "vertex " << v;
      ASSERT_GE(sample->rounds, lastRounds[v]) << "vertex " << v;
      ASSERT_LE(sample->rounds, kRounds);
      ASSERT_GE(sample->paths, 16u);
      lastRounds[v] = sample->rounds;
    }
    samplesRead += read;
  };

  std::vector<std::thread> threads;
  threads.emplace_back(reader, 1u);
  threads.emplace_back(reader, 7u);
  std::thread w0(writer, 0), w1(writer, 1);
  w0.join();
  w1.join();
  writersDone.store(true, std::memory_order_release);
  for (auto& t : threads) t.join();

  EXPECT_GT(samplesRead.load(), 0u);
  EXPECT_EQ(cache.ShadedCount(), size_t(kVertices));
  for (VertexId v = 0; v < kVertices; ++v) {
    const auto sample = cache.Read(v);
    ASSERT_TRUE(sample.has_value()) << v;
    EXPECT_EQ(sample->rounds, kRounds) << v;
    EXPECT_TRUE(Whole(*sample)) << v;
  }
}

// Replacement as moving objects will do it: evict, store anew. A reader
// that copied a sample can tell it is stale by its generation, and never
// sees a torn one.
TEST(SampleCache, EvictionWhileReadingBumpsGenerations) {
  SampleCache cache;
  constexpr VertexId kVertices = 512;
  constexpr int kReplacements = 200;
  cache.Reserve(kVertices);
  for (VertexId v = 0; v < kVertices; ++v) cache.Store(std::vector{Sample(v, 1.0f)});
  std::atomic<bool> done{false};
  std::thread writer([&] {
    for (int k = 0; k < kReplacements; ++k)
      for (VertexId v = 0; v < kVertices; ++v) {
        EXPECT_TRUE(cache.Evict(v));
        cache.Store(std::vector{Sample(v, float(k + 2))});
      }
    done.store(true, std::memory_order_release);
  });
  std::thread reader([&] {
    std::vector<uint32_t> generations(kVertices, 0);
    VertexId v = 0;
    while (!done.load(std::memory_order_acquire)) {
      v = (v + 37) % kVertices;
      const auto sample = cache.Read(v);
      if (!sample) continue;
      ASSERT_TRUE(Whole(*sample));
      ASSERT_GE(sample->generation, generations[v]);
      generations[v] = sample->generation;
      // Value k + 2 was stored in generation k + 1 (the first store, 1.0, in 0).
      ASSERT_EQ(sample->radiance.r, sample->generation == 0 ? 1.0f : float(sample->generation + 1));
    }
  });
  writer.join();
  reader.join();
  for (VertexId v = 0; v < kVertices; ++v) EXPECT_EQ(cache.Generation(v), uint32_t(kReplacements));
  EXPECT_EQ(cache.ShadedCount(), size_t(kVertices));
}


// Moving objects (issue 14): a sample shaded at a pose older than its
// vertex's last invalidation never reaches the cache, whichever of the
// reply and the move comes first.
ShadedSample At(VertexId v, float value, uint64_t epoch, uint16_t round = 0) {
  ShadedSample s = Sample(v, value, round);
  s.epoch = epoch;
  return s;
}

TEST(SampleCache, InvalidateEvictsOlderSamplesAndRefusesStaleOnes) {
  SampleCache cache;
  cache.Reserve(4);
  ASSERT_EQ(cache.Store(std::vector{At(0, 1.0f, 0), At(1, 1.0f, 0), At(2, 1.0f, 3)}), 3u);
  const uint32_t generation = cache.Generation(0);

  // A move at epoch 3: the samples shaded before it go; one already shaded
  // at epoch 3 (dispatched after the move was published) stays.
  EXPECT_TRUE(cache.Invalidate(0, 3));
  EXPECT_FALSE(cache.Invalidate(2, 3));
  EXPECT_FALSE(cache.Invalidate(3, 3));  // never shaded: only its ValidFrom moves
  EXPECT_FALSE(cache.IsShaded(0));
  EXPECT_TRUE(cache.AwaitingReshade(0));
  EXPECT_FALSE(cache.AwaitingReshade(3));
  EXPECT_EQ(cache.Generation(0), generation + 1);
  EXPECT_TRUE(cache.IsShaded(1));  // not invalidated
  EXPECT_TRUE(cache.IsShaded(2));
  EXPECT_EQ(cache.ValidFrom(0), 3u);
  EXPECT_EQ(cache.ShadedCount(), 2u);

  // A reply shaded at epoch 2 arriving after the move: refused, reported.
  std::vector<VertexId> stale;
  EXPECT_EQ(cache.Store(std::vector{At(0, 5.0f, 2), At(3, 5.0f, 1)}, &stale), 0u);
  EXPECT_EQ(stale, (std::vector<VertexId>{0, 3}));
  EXPECT_FALSE(cache.IsShaded(0));
  EXPECT_TRUE(cache.AwaitingReshade(0));
  // An improvement of a vertex awaiting its reshade, or shaded before the
  // move, is refused too: the vertex needs a first estimate.
  stale.clear();
  EXPECT_TRUE(cache.Improve(std::vector{At(0, 5.0f, 3, 1)}, &stale).empty());
  EXPECT_EQ(stale, std::vector<VertexId>{0});

  // The reshade, shaded at epoch 3 or later, is stored and counted.
  stale.clear();
  EXPECT_EQ(cache.Store(std::vector{At(0, 7.0f, 4)}, &stale), 1u);
  EXPECT_TRUE(stale.empty());
  EXPECT_FALSE(cache.AwaitingReshade(0));
  EXPECT_EQ(cache.Radiance(0).r, 7.0f);
  EXPECT_EQ(cache.Read(0)->epoch, 4u);
  EXPECT_EQ(cache.Reshaded(), 1u);

  // Invalidations only raise ValidFrom.
  EXPECT_FALSE(cache.Invalidate(0, 2));
  EXPECT_EQ(cache.ValidFrom(0), 3u);
  EXPECT_TRUE(cache.IsShaded(0));
}

TEST(SampleCache, ImprovedSampleKeepsTheOldestEpochItMixes) {
  SampleCache cache;
  ASSERT_EQ(cache.Store(std::vector{At(0, 1.0f, 1)}), 1u);
  ASSERT_EQ(cache.Improve(std::vector{At(0, 1.0f, 5, 1)}).size(), 1u);
  EXPECT_EQ(cache.Read(0)->epoch, 1u);
  // So a move at epoch 2 evicts it: part of it was shaded at epoch 1.
  EXPECT_TRUE(cache.Invalidate(0, 2));
}

// A test instead of an invalidation (issue 14, docs/moving-objects.md "A
// test instead of a bound"): a suspect sample is held back -- unshaded to
// every reader, awaiting its reshade -- with its values kept, and comes back
// as it was when its test passes.
TEST(SampleCache, ASuspectSampleReadsUnshadedAndAPassedTestRestoresItAsItWas) {
  SampleCache cache;
  ASSERT_EQ(cache.Store(std::vector{At(0, 1.0f, 1), At(1, 2.0f, 1)}), 2u);
  ASSERT_EQ(cache.Improve(std::vector{At(0, 3.0f, 2, 1)}).size(), 1u);  // 16 + 16 paths, one round
  const CachedSample before = *cache.Read(0);
  ASSERT_EQ(before.paths, 32u);
  ASSERT_EQ(before.rounds, 1u);
  ASSERT_EQ(before.epoch, 1u);
  const uint64_t changes = cache.Changes();

  const std::optional<uint32_t> generation = cache.Suspect(0, 3);
  ASSERT_TRUE(generation.has_value());
  EXPECT_EQ(*generation, before.generation + 1);
  EXPECT_EQ(cache.Generation(0), *generation);
  EXPECT_GT(cache.Changes(), changes);
  // Nobody is shown it...
  EXPECT_FALSE(cache.IsShaded(0));
  EXPECT_FALSE(cache.Read(0).has_value());
  EXPECT_EQ(cache.Radiance(0), Rgb(0.0f));
  EXPECT_EQ(cache.Irradiance(0), Rgb(0.0f));
  EXPECT_EQ(cache.Paths(0), 0u);
  EXPECT_EQ(cache.Luminance(0), 0.0f);
  EXPECT_TRUE(cache.AwaitingReshade(0));
  EXPECT_TRUE(cache.IsSuspect(0));
  EXPECT_EQ(cache.ValidFrom(0), 3u);
  EXPECT_EQ(cache.ShadedCount(), 1u);
  // ...but it is kept, whole, for the test.
  const std::optional<CachedSample> kept = cache.ReadSuspect(0);
  ASSERT_TRUE(kept.has_value());
  EXPECT_EQ(kept->radiance, before.radiance);
  EXPECT_EQ(kept->irradiance, before.irradiance);
  EXPECT_EQ(kept->irradianceStdErr, before.irradianceStdErr);
  EXPECT_EQ(kept->paths, before.paths);
  EXPECT_EQ(kept->rounds, before.rounds);
  EXPECT_EQ(kept->epoch, 1u);
  EXPECT_EQ(kept->generation, *generation);
  EXPECT_FALSE(cache.ReadSuspect(1).has_value()) << "not suspect";
  EXPECT_TRUE(cache.IsShaded(1));

  // The test passed: the same sample, shaded again, at its own pose.
  EXPECT_TRUE(cache.Confirm(0, *generation));
  EXPECT_EQ(cache.Confirmed(), 1u);
  EXPECT_EQ(cache.FailedTests(), 0u);
  EXPECT_TRUE(cache.IsShaded(0));
  EXPECT_FALSE(cache.IsSuspect(0));
  EXPECT_FALSE(cache.AwaitingReshade(0));
  EXPECT_FALSE(cache.ReadSuspect(0).has_value());
  EXPECT_EQ(cache.ShadedCount(), 2u);
  EXPECT_EQ(cache.Reshaded(), 0u) << "kept, not shaded again";
  const std::optional<CachedSample> after = cache.Read(0);
  ASSERT_TRUE(after.has_value());
  EXPECT_EQ(after->radiance, before.radiance);
  EXPECT_EQ(after->irradiance, before.irradiance);
  EXPECT_EQ(after->irradianceStdErr, before.irradianceStdErr);
  EXPECT_EQ(after->paths, before.paths);
  EXPECT_EQ(after->rounds, before.rounds);
  EXPECT_EQ(after->epoch, 1u) << "the pose it was shaded at, not the move's";
  EXPECT_EQ(after->generation, *generation);
  EXPECT_TRUE(Whole(*after));
  // Confirmed once only.
  EXPECT_FALSE(cache.Confirm(0, *generation));
  EXPECT_FALSE(cache.FailSuspect(0, *generation));
  EXPECT_EQ(cache.Confirmed(), 1u);
  EXPECT_EQ(cache.ShadedCount(), 2u);
  // A reply shaded before the move is still refused, and the next
  // improvement round is taken.
  std::vector<VertexId> stale;
  EXPECT_EQ(cache.Store(std::vector{At(0, 9.0f, 2)}, &stale), 0u);
  EXPECT_EQ(cache.Radiance(0), before.radiance);
  EXPECT_EQ(cache.Improve(std::vector{At(0, 3.0f, 3, 2)}).size(), 1u);
  EXPECT_EQ(cache.Read(0)->epoch, 1u);

  // The next move is judged from the pose it was shaded at: epoch 1.
  const std::optional<uint32_t> again = cache.Suspect(0, 4);
  ASSERT_TRUE(again.has_value());
  EXPECT_EQ(cache.ReadSuspect(0)->epoch, 1u);
  EXPECT_EQ(cache.ShadedCount(), 1u);
}

// Whatever wrote the slot since Suspect -- a newer move's test or
// invalidation, the reshade, eviction, the id freed -- owns it: the late
// answer of the old test confirms nothing and drops nothing.
TEST(SampleCache, AnAnswerForAnOlderGenerationConfirmsAndFailsNothing) {
  struct Case {
    const char* name;
    std::function<void(SampleCache&)> writeSince;
    bool shadedAfter;     // vertex 0, once written since
    bool awaitingAfter;
    bool suspectAfter;
    size_t shadedCountAfter;  // vertex 1 stays shaded throughout
  };
  const std::vector<Case> cases{
      {"a newer move's test", [](SampleCache& c) { ASSERT_TRUE(c.Suspect(0, 4).has_value()); }, false, true, true, 1},
      {"a newer move's invalidation", [](SampleCache& c) { EXPECT_TRUE(c.Invalidate(0, 4)); }, false, true, false, 1},
      {"the same move's invalidation", [](SampleCache& c) { EXPECT_TRUE(c.Invalidate(0, 3)); }, false, true, false, 1},
      {"the reshade at the new pose",
       [](SampleCache& c) { EXPECT_EQ(c.Store(std::vector{At(0, 7.0f, 3)}), 1u); }, true, false, false, 2},
      {"eviction", [](SampleCache& c) { EXPECT_TRUE(c.Evict(0)); }, false, true, false, 1},
      {"the id freed", [](SampleCache& c) { EXPECT_FALSE(c.Forget(0)) << "it read unshaded"; }, false, false, false, 1},
  };
  for (const Case& k : cases) {
    SCOPED_TRACE(k.name);
    SampleCache cache;
    ASSERT_EQ(cache.Store(std::vector{At(0, 1.0f, 1), At(1, 2.0f, 1)}), 2u);
    const std::optional<uint32_t> generation = cache.Suspect(0, 3);
    ASSERT_TRUE(generation.has_value());
    k.writeSince(cache);
    const std::optional<CachedSample> read = cache.Read(0);
    const uint32_t slotGeneration = cache.Generation(0);

    EXPECT_FALSE(cache.Confirm(0, *generation));
    EXPECT_FALSE(cache.FailSuspect(0, *generation));
    // Nothing changed.
    EXPECT_EQ(cache.Confirmed(), 0u);
    EXPECT_EQ(cache.FailedTests(), 0u);
    EXPECT_EQ(cache.Generation(0), slotGeneration);
    EXPECT_EQ(cache.IsShaded(0), k.shadedAfter);
    EXPECT_EQ(cache.AwaitingReshade(0), k.awaitingAfter);
    EXPECT_EQ(cache.IsSuspect(0), k.suspectAfter);
    EXPECT_EQ(cache.ReadSuspect(0).has_value(), k.suspectAfter);
    EXPECT_EQ(cache.ShadedCount(), k.shadedCountAfter);
    EXPECT_EQ(cache.Read(0).has_value(), read.has_value());
    if (k.shadedAfter) {
      EXPECT_EQ(cache.Radiance(0), Rgb(7.0f)) << "the reshade stays";
      EXPECT_EQ(cache.Reshaded(), 1u);
    }
    if (k.suspectAfter) {
      EXPECT_NE(slotGeneration, *generation);
      EXPECT_EQ(cache.ReadSuspect(0)->epoch, 1u) << "still the sample shaded at epoch 1";
      EXPECT_EQ(cache.ValidFrom(0), 4u);
    }
    if (!k.shadedAfter && !k.suspectAfter) {
      EXPECT_EQ(cache.Radiance(0), Rgb(0.0f));
      EXPECT_FALSE(cache.ReadSuspect(0).has_value());
    }
  }
}

// The test failed: the sample is dropped, the vertex waits for its reshade,
// and only a sample shaded at the move's pose or later is stored.
TEST(SampleCache, AFailedTestDropsTheSampleAndOnlyTheReshadeAtTheNewPoseIsStored) {
  SampleCache cache;
  ASSERT_EQ(cache.Store(std::vector{At(0, 1.0f, 1), At(1, 2.0f, 1)}), 2u);
  const std::optional<uint32_t> generation = cache.Suspect(0, 3);
  ASSERT_TRUE(generation.has_value());

  // A reply shaded before the move, arriving during the test: stale.
  std::vector<VertexId> stale;
  EXPECT_EQ(cache.Store(std::vector{At(0, 5.0f, 2)}, &stale), 0u);
  EXPECT_EQ(stale, std::vector<VertexId>{0});
  EXPECT_TRUE(cache.IsSuspect(0)) << "a stale reply does not end the test";
  EXPECT_EQ(cache.ReadSuspect(0)->radiance, Rgb(1.0f));
  // An improvement of a suspect sample is refused too.
  stale.clear();
  EXPECT_TRUE(cache.Improve(std::vector{At(0, 5.0f, 3, 1)}, &stale).empty());
  EXPECT_EQ(stale, std::vector<VertexId>{0});
  EXPECT_TRUE(cache.IsSuspect(0));

  EXPECT_TRUE(cache.FailSuspect(0, *generation));
  EXPECT_EQ(cache.FailedTests(), 1u);
  EXPECT_EQ(cache.Confirmed(), 0u);
  EXPECT_FALSE(cache.IsSuspect(0));
  EXPECT_FALSE(cache.ReadSuspect(0).has_value());
  EXPECT_FALSE(cache.IsShaded(0));
  EXPECT_FALSE(cache.Read(0).has_value());
  EXPECT_TRUE(cache.AwaitingReshade(0));
  EXPECT_EQ(cache.Generation(0), *generation + 1) << "a reader's copy of the suspect sample can tell";
  EXPECT_EQ(cache.ShadedCount(), 1u);
  // Failed once only; a confirmation arriving after it keeps nothing.
  EXPECT_FALSE(cache.FailSuspect(0, *generation));
  EXPECT_FALSE(cache.Confirm(0, *generation));
  EXPECT_FALSE(cache.Confirm(0, *generation + 1)) << "not suspect";
  EXPECT_FALSE(cache.IsShaded(0));
  EXPECT_EQ(cache.FailedTests(), 1u);

  stale.clear();
  EXPECT_EQ(cache.Store(std::vector{At(0, 5.0f, 2)}, &stale), 0u);
  EXPECT_EQ(stale, std::vector<VertexId>{0});
  EXPECT_EQ(cache.Store(std::vector{At(0, 7.0f, 3)}, &stale), 1u);
  EXPECT_EQ(stale.size(), 1u);
  EXPECT_TRUE(cache.IsShaded(0));
  EXPECT_FALSE(cache.AwaitingReshade(0));
  EXPECT_EQ(cache.Reshaded(), 1u);
  EXPECT_EQ(cache.ShadedCount(), 2u);
  const CachedSample reshaded = *cache.Read(0);
  EXPECT_EQ(reshaded.radiance, Rgb(7.0f));
  EXPECT_EQ(reshaded.epoch, 3u);
  EXPECT_EQ(reshaded.rounds, 0u);
  EXPECT_EQ(reshaded.paths, 16u);
}

// Only a sample shaded before the move's epoch is suspected: a vertex with
// no sample has nothing to test, and one shaded at the move's pose is valid.
TEST(SampleCache, OnlyASampleShadedBeforeTheEpochIsSuspected) {
  SampleCache cache;
  cache.Reserve(8);
  const size_t memory = cache.MemoryBytes();
  EXPECT_FALSE(cache.Suspect(5, 3).has_value()) << "its chunk was never written";
  EXPECT_FALSE(cache.Suspect(100, 3).has_value()) << "beyond the cache";
  EXPECT_EQ(cache.MemoryBytes(), memory) << "nothing allocated for nothing to test";
  EXPECT_FALSE(cache.IsSuspect(5));
  EXPECT_FALSE(cache.AwaitingReshade(5));

  ASSERT_EQ(cache.Store(std::vector{At(0, 1.0f, 3), At(1, 1.0f, 4)}), 2u);
  EXPECT_FALSE(cache.Suspect(2, 3).has_value()) << "its chunk exists, it was never shaded";
  EXPECT_FALSE(cache.IsSuspect(2));
  EXPECT_FALSE(cache.AwaitingReshade(2));
  const uint32_t generation = cache.Generation(0);
  EXPECT_FALSE(cache.Suspect(0, 3).has_value()) << "shaded at the move's pose";
  EXPECT_FALSE(cache.Suspect(1, 3).has_value()) << "shaded after it";
  for (VertexId v : {0u, 1u}) {
    EXPECT_TRUE(cache.IsShaded(v)) << v;
    EXPECT_FALSE(cache.IsSuspect(v)) << v;
    EXPECT_FALSE(cache.AwaitingReshade(v)) << v;
  }
  EXPECT_EQ(cache.Generation(0), generation);
  EXPECT_EQ(cache.ShadedCount(), 2u);
  EXPECT_FALSE(cache.Confirm(0, generation)) << "nothing suspect to confirm";
  EXPECT_FALSE(cache.FailSuspect(0, generation));
  EXPECT_TRUE(cache.IsShaded(0));
}

// A suspect sample counts as stored: a move that invalidates it drops it,
// and the vertex awaits its reshade.
TEST(SampleCache, InvalidatingASuspectSampleDropsIt) {
  SampleCache cache;
  ASSERT_EQ(cache.Store(std::vector{At(0, 1.0f, 1), At(1, 2.0f, 1)}), 2u);
  ASSERT_TRUE(cache.Suspect(0, 3).has_value());
  const uint32_t generation = cache.Generation(0);
  EXPECT_TRUE(cache.Invalidate(0, 5));
  EXPECT_FALSE(cache.IsSuspect(0));
  EXPECT_FALSE(cache.ReadSuspect(0).has_value());
  EXPECT_FALSE(cache.IsShaded(0));
  EXPECT_TRUE(cache.AwaitingReshade(0));
  EXPECT_EQ(cache.Generation(0), generation + 1);
  EXPECT_EQ(cache.ValidFrom(0), 5u);
  EXPECT_EQ(cache.ShadedCount(), 1u) << "counted out once, by Suspect";
  EXPECT_FALSE(cache.Invalidate(0, 6)) << "nothing left to drop";
  EXPECT_FALSE(cache.Suspect(0, 6).has_value()) << "nothing left to test";
  EXPECT_EQ(cache.Store(std::vector{At(0, 3.0f, 6)}), 1u);
  EXPECT_EQ(cache.Reshaded(), 1u);
  EXPECT_EQ(cache.ShadedCount(), 2u);
}

// Replies and moves race on one slot: whatever the interleaving, no sample
// older than the last invalidation is left in the cache.
TEST(SampleCache, ConcurrentStoresAndInvalidationsLeaveNothingStale) {
  constexpr VertexId kVertices = 256;
  constexpr uint64_t kEpochs = 200;
  SampleCache cache;
  cache.Reserve(kVertices);
  std::atomic<uint64_t> published{0};
  std::atomic<bool> done{false};
  std::thread mover([&] {
    for (uint64_t e = 1; e <= kEpochs; ++e) {
      published.store(e);
      for (VertexId v = 0; v < kVertices; ++v) cache.Invalidate(v, e);
    }
    done = true;
  });
  std::thread replies([&] {
    uint64_t round = 0;
    while (!done) {
      // Shaded at a pose read some time ago: often stale.
      const uint64_t epoch = published.load() - std::min<uint64_t>(published.load(), round++ % 3);
      for (VertexId v = 0; v < kVertices; ++v) cache.Store(std::vector{At(v, float(epoch), epoch)});
    }
  });
  mover.join();
  replies.join();
  for (VertexId v = 0; v < kVertices; ++v) {
    const auto s = cache.Read(v);
    if (s) {
      EXPECT_GE(s->epoch, kEpochs) << v;
    }
    EXPECT_EQ(cache.ValidFrom(v), kEpochs);
  }
}

// InvalidateUnshaded: one floor for every vertex with no sample -- what
// Invalidate(v, e) on each of them did -- touching none.
TEST(SampleCache, TheUnshadedFloorRefusesOldFirstEstimatesOfVerticesWithNoSampleOnly) {
  SampleCache cache;
  cache.Reserve(3 * SampleCache::kChunkVertices);
  ASSERT_EQ(cache.Store(std::vector{At(0, 1.0f, 1)}), 1u);
  const size_t bytes = cache.MemoryBytes();
  cache.InvalidateUnshaded(3);
  EXPECT_EQ(cache.MemoryBytes(), bytes) << "no chunk made for the vertices with no sample";
  EXPECT_EQ(cache.UnshadedValidFrom(), 3u);
  cache.InvalidateUnshaded(2);
  EXPECT_EQ(cache.UnshadedValidFrom(), 3u) << "the floor only rises";
  // A vertex with a sample is judged by its own ValidFrom: still 0.
  EXPECT_EQ(cache.ValidFrom(0), 0u);
  EXPECT_EQ(cache.Improve(std::vector{At(0, 3.0f, 1, 1)}).size(), 1u);
  // Vertices with none, in a chunk that exists and in one that does not:
  // a first estimate shaded before the floor is refused and reported.
  const VertexId far = VertexId(2 * SampleCache::kChunkVertices + 5);
  EXPECT_EQ(cache.ValidFrom(1), 3u);
  EXPECT_EQ(cache.ValidFrom(far), 3u);
  std::vector<VertexId> stale;
  EXPECT_EQ(cache.Store(std::vector{At(1, 5.0f, 2), At(far, 5.0f, 2)}, &stale), 0u);
  EXPECT_EQ(stale, (std::vector<VertexId>{1, far}));
  EXPECT_EQ(cache.Store(std::vector{At(1, 5.0f, 3), At(far, 5.0f, 4)}), 2u);
  // Once it has a sample, a vertex's improvements are judged by its own
  // ValidFrom; evicted, it has none again and the floor applies.
  EXPECT_EQ(cache.ValidFrom(1), 0u);
  EXPECT_TRUE(cache.Evict(0));
  EXPECT_EQ(cache.Store(std::vector{At(0, 5.0f, 2)}), 0u);
  EXPECT_EQ(cache.Store(std::vector{At(0, 5.0f, 3)}), 1u);
}

// The race InvalidateUnshaded's fences close: a planner raises the floor,
// then reads which vertices have samples, while replies shaded at the old
// pose are stored. Every vertex the planner read as having none must stay
// without an old sample: the planner did not judge it, so only the floor
// can keep an old sample out.
TEST(SampleCache, AVertexThePlannerReadWithNoSampleNeverGetsAnOldOne) {
  constexpr VertexId kVertices = 4 * VertexId(SampleCache::kChunkVertices);
  for (int trial = 0; trial < 20; ++trial) {
    SampleCache cache;
    cache.Reserve(kVertices);
    std::atomic<bool> go{false};
    std::thread replies([&] {
      while (!go.load()) std::this_thread::yield();
      for (VertexId v = 0; v < kVertices; ++v) cache.Store(std::vector{At(v, 1.0f, 1)});
    });
    std::vector<VertexId> readWithNone;
    go = true;
    // A later start each trial: the floor meets the replies at another place.
    std::this_thread::sleep_for(std::chrono::microseconds(50 * trial));
    cache.InvalidateUnshaded(2);
    for (VertexId v = 0; v < kVertices; ++v)
      if (!cache.Read(v)) readWithNone.push_back(v);
    replies.join();
    for (VertexId v : readWithNone) {
      const auto s = cache.Read(v);
      ASSERT_FALSE(s.has_value() && s->epoch < 2) << "trial " << trial << ": vertex " << v;
    }
  }
}


// Dropping chunks (issue 15: samples no one holds are dropped).
constexpr VertexId kChunk = VertexId(SampleCache::kChunkVertices);

TEST(SampleCache, ADroppedChunkReadsUnshadedGivesItsMemoryBackAndIsReused) {
  SampleCache cache;
  cache.Reserve(3 * kChunk);
  for (VertexId v = 0; v < 2 * kChunk; v += 7) cache.Store(std::vector{Sample(v, float(v))});
  ASSERT_EQ(cache.ChunksInUse(), 2u);
  const size_t bytes = cache.MemoryBytes();
  const size_t shaded = cache.ShadedCount();
  const size_t inFirst = (kChunk + 6) / 7;

  const std::optional<size_t> dropped = cache.DropChunk(0);
  ASSERT_TRUE(dropped);
  EXPECT_EQ(*dropped, inFirst);
  EXPECT_EQ(cache.ShadedCount(), shaded - inFirst);
  EXPECT_EQ(cache.ChunksInUse(), 1u);
  EXPECT_EQ(cache.ChunksDropped(), 1u);
  // The chunk's slots are no longer counted (its record and what it passes
  // on are, a few hundred bytes).
  EXPECT_LE(cache.MemoryBytes(), bytes - SampleCache::ChunkBytes() + 512);
  for (VertexId v = 0; v < kChunk; v += 7) {
    ASSERT_FALSE(cache.IsShaded(v)) << v;
    ASSERT_FALSE(cache.Read(v)) << v;
  }
  for (VertexId v = (kChunk + 6) / 7 * 7; v < 2 * kChunk; v += 7) {  // the other chunk is untouched
    const auto sample = cache.Read(v);
    ASSERT_TRUE(sample) << v;
    ASSERT_EQ(sample->radiance.r, float(v));
  }
  EXPECT_FALSE(cache.DropChunk(0)) << "not in use";
  EXPECT_FALSE(cache.DropChunk(2)) << "never made";

  // A sample stored there again makes the chunk again from the dropped
  // record: no new memory, and counted as a re-shade only for the vertices
  // that had a sample.
  cache.Store(std::vector{Sample(7, 70.0f), Sample(8, 80.0f)});
  EXPECT_EQ(cache.ReshadedAfterDrop(), 1u);
  EXPECT_EQ(cache.Read(7)->radiance.r, 70.0f);
  EXPECT_EQ(cache.ChunksInUse(), 2u);
  EXPECT_EQ(cache.MemoryBytes(), bytes);
  // Improvements of dropped samples have nothing to improve.
  EXPECT_TRUE(cache.Improve(std::vector{Sample(14, 1.0f, 1)}).empty());
  EXPECT_FALSE(cache.IsShaded(14));
}

TEST(SampleCache, ADroppedChunkPassesOnValidFromAndGenerations) {
  SampleCache cache;
  cache.Reserve(kChunk);
  cache.Store(std::vector{At(3, 1.0f, 1)});
  EXPECT_TRUE(cache.Invalidate(3, 5));  // a move at epoch 5
  cache.Store(std::vector{At(3, 5.0f, 5)});  // its reshade
  const auto before = cache.Read(3);
  ASSERT_TRUE(before);
  ASSERT_TRUE(cache.DropChunk(0));
  // A late reply shaded at the old pose is still refused after the drop.
  std::vector<VertexId> stale;
  EXPECT_EQ(cache.Store(std::vector{At(3, 1.0f, 4)}, &stale), 0u);
  EXPECT_EQ(stale, std::vector<VertexId>{3});
  EXPECT_EQ(cache.ValidFrom(3), 5u);
  // A copy read before the drop never looks current again.
  EXPECT_NE(cache.Generation(3), before->generation);
  EXPECT_GT(cache.Generation(3), before->generation);
  cache.Store(std::vector{At(3, 6.0f, 6)});
  EXPECT_NE(cache.Read(3)->generation, before->generation);
}

TEST(SampleCache, AChunkHoldingAMovesStateIsNotDropped) {
  SampleCache cache;
  cache.Reserve(2 * kChunk);
  cache.Store(std::vector{At(1, 1.0f, 1), At(kChunk + 1, 1.0f, 1)});
  ASSERT_TRUE(cache.Invalidate(1, 2));  // awaiting its reshade
  ASSERT_TRUE(cache.Suspect(kChunk + 1, 2));
  EXPECT_FALSE(cache.DropChunk(0));
  EXPECT_FALSE(cache.DropChunk(1));
  EXPECT_TRUE(cache.AwaitingReshade(1));
  EXPECT_TRUE(cache.IsSuspect(kChunk + 1));
  EXPECT_EQ(cache.ChunksInUse(), 2u);
  EXPECT_EQ(cache.ChunksDropped(), 0u);
  // Once the move's work is done, the chunk may go.
  cache.Store(std::vector{At(1, 2.0f, 2)});
  EXPECT_TRUE(cache.DropChunk(0));
}

TEST(SampleCache, ChunksAgeFromTheirLastTouch) {
  SampleCache cache;
  cache.Reserve(4 * kChunk);
  cache.SetTick(10);
  for (VertexId c = 0; c < 3; ++c) cache.Store(std::vector{Sample(c * kChunk + 5, 1.0f)});
  cache.SetTick(40);
  cache.Touch(kChunk + 900);  // any vertex of chunk 1
  cache.Touch(3 * kChunk + 1);  // no chunk: nothing
  cache.SetTick(60);
  using Old = std::vector<std::pair<uint32_t, uint32_t>>;
  EXPECT_EQ(cache.OldChunks(0, 4 * kChunk, 30), (Old{{10, 0}, {10, 2}}));
  EXPECT_EQ(cache.OldChunks(0, 4 * kChunk, 10), (Old{{10, 0}, {40, 1}, {10, 2}}));
  // Only chunks wholly inside the range.
  EXPECT_EQ(cache.OldChunks(1, 3 * kChunk - 1, 10), (Old{{40, 1}}));
  EXPECT_EQ(cache.ChunkLastUse(1), 40u);
  EXPECT_EQ(cache.ChunkLastUse(3), std::nullopt);
  // A chunk made again is young.
  ASSERT_TRUE(cache.DropChunk(0));
  cache.Store(std::vector{Sample(5, 1.0f)});
  EXPECT_EQ(cache.ChunkLastUse(0), 60u);
}

// Readers, writers and drops at once (meant for ThreadSanitizer and
// AddressSanitizer too): a reader only ever sees vertex v's own sample, whole,
// or none -- never a slot of a chunk reused for other vertices -- and the
// counts add up at the end.
TEST(SampleCache, ReadersAndWritersMeetDropsAndReusedChunksSafely) {
  constexpr VertexId kChunks = 4;
  constexpr VertexId kVertices = kChunks * kChunk;
  SampleCache cache;
  cache.Reserve(kVertices);
  const auto valueOf = [](VertexId v) { return float(v) + 1.0f; };
  std::atomic<bool> done{false};
  std::atomic<uint64_t> drops{0}, wholeReads{0};
  std::vector<std::thread> threads;
  threads.emplace_back([&] {  // the renderers' replies
    for (int round = 0; round < 600; ++round)
      for (VertexId v = VertexId(round % 3); v < kVertices; v += 3) cache.Store(std::vector{Sample(v, valueOf(v))});
    done = true;
  });
  threads.emplace_back([&] {  // improvements of whatever is there
    while (!done)
      for (VertexId v = 1; v < kVertices; v += 97) {
        const uint16_t next = uint16_t(cache.Rounds(v) + 1);
        cache.Improve(std::vector{Sample(v, valueOf(v), next)});
      }
  });
  threads.emplace_back([&] {  // the collector
    uint32_t c = 0;
    while (!done) {
      if (cache.DropChunk(c++ % kChunks)) ++drops;
      std::this_thread::yield();
    }
  });
  for (int r = 0; r < 2; ++r)
    threads.emplace_back([&] {  // views
      while (!done)
        for (VertexId v = 0; v < kVertices; v += 5) {
          cache.Touch(v);
          if (const auto s = cache.Read(v)) {
            ASSERT_TRUE(Whole(*s)) << v;
            // Improvements mix equal values: the same up to rounding, while
            // a neighbouring vertex's differs by 1 in at most 4097.
            ASSERT_NEAR(s->radiance.r, valueOf(v), 1e-5f * valueOf(v))
                << "vertex " << v << " read another vertex's sample";
            ++wholeReads;
          }
          (void)cache.IsShaded(v);
          (void)cache.Generation(v);
        }
    });
  for (auto& t : threads) t.join();
  EXPECT_GT(drops.load(), 0u);
  EXPECT_GT(wholeReads.load(), 0u);
  std::printf("%llu drops, %llu whole reads\n", (unsigned long long)drops.load(), (unsigned long long)wholeReads.load());
  size_t shaded = 0;
  for (VertexId v = 0; v < kVertices; ++v) shaded += cache.IsShaded(v) ? 1 : 0;
  EXPECT_EQ(cache.ShadedCount(), shaded);
  EXPECT_LE(cache.ChunksInUse(), size_t(kChunks));
  EXPECT_EQ(cache.ChunksDropped(), drops.load());
}

}  // namespace
}  // namespace penumbra::sma
