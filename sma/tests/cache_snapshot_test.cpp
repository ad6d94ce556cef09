#include "penumbra/sma/cache_snapshot.h"

#include <bit>
#include <cstring>
#include <fstream>
#include <random>
#include <shared_mutex>

#include <gtest/gtest.h>

#include "hierarchy_test_scenes.h"
#include "penumbra/common/hash.h"

namespace penumbra::sma {
namespace {

// A room: a floor grid, two walls at right angles (creases: vertices split
// per side), a light on the ceiling; both sides shaded.
Scene RoomScene(bool twoSided = true, float floorShift = 0.0f) {
  SceneBuilder b;
  Material grey;
  const uint32_t mat = b.AddMaterial(grey);
  Material light;
  light.emission = Rgb(10.0f);
  const uint32_t lamp = b.AddMaterial(light);
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) b.AddQuad(Vec3(float(i) + floorShift, 0, float(j)), Vec3(0, 0, 1), Vec3(1, 0, 0), mat);
  b.AddQuad(Vec3(0, 0, 0), Vec3(4, 0, 0), Vec3(0, 3, 0), mat);
  b.AddQuad(Vec3(0, 0, 0), Vec3(0, 3, 0), Vec3(0, 0, 4), mat);
  b.AddQuad(Vec3(1, 2.9f, 1), Vec3(1, 0, 0), Vec3(0, 0, 1), lamp);
  Scene s;
  s.twoSided = twoSided;
  EXPECT_TRUE(b.BuildInto(s).ok());
  return s;
}

// Refines `rounds` random leaves with varied options (so that both 1 -> 4 and
// 1 -> 2 splits happen, and the split budget runs out now and then).
void RefineRandomly(Hierarchy& h, int rounds, uint32_t seed) {
  std::mt19937 rng(seed);
  for (int i = 0; i < rounds; ++i) {
    const auto leaves = Leaves(h);
    RefineOptions o;
    o.aspectThreshold = std::uniform_real_distribution<float>(0.3f, 2.0f)(rng);
    o.maxSplits4 = std::uniform_int_distribution<uint32_t>(1, 8)(rng);
    o.maxDepth = uint8_t(std::uniform_int_distribution<int>(3, 8)(rng));
    h.Refine(leaves[std::uniform_int_distribution<size_t>(0, leaves.size() - 1)(rng)], o);
  }
}

// Shades most vertices, improves some of them once or twice.
void ShadeRandomly(const Hierarchy& h, SampleCache& cache, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  cache.Reserve(h.VertexCount());
  std::vector<ShadedSample> first;
  for (VertexId v = 0; v < h.VertexCount(); ++v) {
    if (u(rng) < 0.2f) continue;  // not shaded yet
    first.push_back(ShadedSample{.vertex = v,
                                 .radiance = Rgb(u(rng), u(rng), u(rng)),
                                 .irradiance = Rgb(u(rng), u(rng), u(rng)) * 3.0f,
                                 .irradianceStdErr = 0.1f * u(rng),
                                 .paths = 16});
  }
  cache.Store(first);
  for (uint16_t round = 1; round <= 2; ++round) {
    std::vector<ShadedSample> more;
    for (const ShadedSample& s : first)
      if (u(rng) < 0.3f && cache.Rounds(s.vertex) == round - 1)
        more.push_back(ShadedSample{.vertex = s.vertex,
                                    .radiance = Rgb(u(rng)),
                                    .irradiance = Rgb(u(rng)),
                                    .irradianceStdErr = 0.05f,
                                    .paths = 64,
                                    .round = round});
    cache.Improve(more);
  }
}

struct Live {
  explicit Live(const Scene& scene) : hierarchy(scene) {}
  std::shared_mutex mutex;
  Hierarchy hierarchy;
  SampleCache cache;
};

std::unique_ptr<Live> MakeLive(const Scene& scene, int rounds = 60) {
  auto live = std::make_unique<Live>(scene);
  RefineRandomly(live->hierarchy, rounds, 7);
  ShadeRandomly(live->hierarchy, live->cache, 11);
  return live;
}

std::string Encode(Live& live, size_t chunk = 65536) {
  return EncodeCacheSnapshot(CaptureCacheSnapshot(live.mutex, live.hierarchy, live.cache, chunk));
}

uint32_t Bits(float f) { return std::bit_cast<uint32_t>(f); }

void ExpectSameHierarchy(const Hierarchy& a, const Hierarchy& b) {
  ASSERT_EQ(a.NodeCount(), b.NodeCount());
  ASSERT_EQ(a.VertexCount(), b.VertexCount());
  for (NodeId id = 0; id < a.NodeCount(); ++id) {
    const Node& x = a.GetNode(id);
    const Node& y = b.GetNode(id);
    ASSERT_EQ(x.v, y.v) << "node " << id;
    ASSERT_EQ(x.mid, y.mid) << "node " << id;
    ASSERT_EQ(x.parent, y.parent) << "node " << id;
    ASSERT_EQ(x.firstChild, y.firstChild) << "node " << id;
    ASSERT_EQ(x.childCount, y.childCount) << "node " << id;
    ASSERT_EQ(x.depth, y.depth) << "node " << id;
    ASSERT_EQ(x.back, y.back) << "node " << id;
    if (x.childCount == 2) {
      ASSERT_EQ(x.splitEdge, y.splitEdge) << "node " << id;
    }
  }
  for (VertexId v = 0; v < a.VertexCount(); ++v) {
    const SampleVertex& x = a.GetVertex(v);
    const SampleVertex& y = b.GetVertex(v);
    for (int c = 0; c < 3; ++c) {
      ASSERT_EQ(Bits(x.position[c]), Bits(y.position[c])) << "vertex " << v;
      ASSERT_EQ(Bits(x.normal[c]), Bits(y.normal[c])) << "vertex " << v;
    }
    ASSERT_EQ(x.point, y.point) << "vertex " << v;
    ASSERT_EQ(x.baseTriangle, y.baseTriangle) << "vertex " << v;
  }
}

// Decoding must fail, and say `expected` (a fragment of the message).
void ExpectRejected(std::span<const char> bytes, const Scene& scene, const std::string& expected) {
  auto r = DecodeCacheSnapshot(bytes, scene, RadianceBounds::ForScene(scene));
  ASSERT_FALSE(r.ok()) << "accepted; expected: " << expected;
  EXPECT_NE(r.error().message.find(expected), std::string::npos) << r.error().message;
}

// Rewrites the header checksum after a deliberate change to the header, so
// that the check after it is the one tested.
void ResealHeader(std::string& bytes) {
  Hasher h;
  h.Update(bytes.data(), 56);
  const uint64_t sum = h.Digest();
  std::memcpy(bytes.data() + 56, &sum, 8);
}
void ResealPayload(std::string& bytes) {
  Hasher h;
  h.Update(bytes.data() + kCacheSnapshotHeaderBytes, bytes.size() - kCacheSnapshotHeaderBytes);
  const uint64_t sum = h.Digest();
  std::memcpy(bytes.data() + 48, &sum, 8);
  ResealHeader(bytes);
}

TEST(CacheSnapshotTest, RoundTripGivesBackEveryIdAndSample) {
  for (bool twoSided : {true, false}) {
    SCOPED_TRACE(twoSided ? "two-sided" : "one-sided");
    const Scene scene = RoomScene(twoSided);
    auto live = MakeLive(scene);
    ASSERT_GT(live->hierarchy.NodeCount(), live->hierarchy.RootCount() + 100);
    ASSERT_TRUE(live->hierarchy.Conforming());
    // Small chunks: the copy takes and releases the lock many times.
    const std::string bytes = Encode(*live, 7);
    auto restored = DecodeCacheSnapshot(bytes, scene, RadianceBounds::ForScene(scene));
    ASSERT_TRUE(restored.ok()) << restored.error().message;
    ExpectSameHierarchy(live->hierarchy, restored->hierarchy);
    EXPECT_TRUE(restored->hierarchy.Conforming());

    SampleCache cache;
    cache.Reserve(restored->hierarchy.VertexCount());
    EXPECT_EQ(cache.Restore(restored->samples), live->cache.ShadedCount());
    EXPECT_EQ(cache.ShadedCount(), live->cache.ShadedCount());
    size_t improved = 0;
    for (VertexId v = 0; v < live->hierarchy.VertexCount(); ++v) {
      ASSERT_EQ(cache.IsShaded(v), live->cache.IsShaded(v)) << "vertex " << v;
      if (!cache.IsShaded(v)) continue;
      for (int c = 0; c < 3; ++c) {
        ASSERT_EQ(Bits(cache.Radiance(v)[c]), Bits(live->cache.Radiance(v)[c])) << "vertex " << v;
        ASSERT_EQ(Bits(cache.Irradiance(v)[c]), Bits(live->cache.Irradiance(v)[c])) << "vertex " << v;
      }
      ASSERT_EQ(Bits(cache.IrradianceStdErr(v)), Bits(live->cache.IrradianceStdErr(v)));
      ASSERT_EQ(cache.Paths(v), live->cache.Paths(v));
      ASSERT_EQ(cache.Rounds(v), live->cache.Rounds(v));
      improved += cache.Rounds(v) > 0;
    }
    EXPECT_GT(improved, 0u);
    // What was on its way when the snapshot was taken is what the SMA asks
    // for again: every midpoint without a sample, and nothing else.
    const std::vector<VertexId> unshaded = UnshadedMidpoints(restored->hierarchy, cache);
    ASSERT_FALSE(unshaded.empty());
    size_t expected = 0;
    for (VertexId v = VertexId(live->hierarchy.BaseVertexCount()); v < live->hierarchy.VertexCount(); ++v)
      expected += !live->cache.IsShaded(v);
    EXPECT_EQ(unshaded.size(), expected);
    for (VertexId v : unshaded) {
      EXPECT_GE(v, restored->hierarchy.BaseVertexCount());
      EXPECT_FALSE(cache.IsShaded(v));
    }

    // The restored hierarchy refines on exactly like the original: its edge
    // maps came back too.
    RefineRandomly(live->hierarchy, 20, 99);
    RefineRandomly(restored->hierarchy, 20, 99);
    ExpectSameHierarchy(live->hierarchy, restored->hierarchy);
  }
}

TEST(CacheSnapshotTest, AnUnrefinedEmptyCacheRoundTrips) {
  const Scene scene = RoomScene();
  Live live(scene);
  const std::string bytes = Encode(live);
  EXPECT_EQ(bytes.size(), kCacheSnapshotHeaderBytes);
  auto restored = DecodeCacheSnapshot(bytes, scene, RadianceBounds::ForScene(scene));
  ASSERT_TRUE(restored.ok()) << restored.error().message;
  EXPECT_EQ(restored->hierarchy.NodeCount(), live.hierarchy.NodeCount());
  EXPECT_TRUE(restored->samples.empty());
}

// Moving objects: a restart begins at the initial pose (epoch 0), so only
// samples shaded there are kept; those shaded after a move are left out.
TEST(CacheSnapshotTest, OnlySamplesShadedAtTheInitialPoseAreKept) {
  const Scene scene = RoomScene();
  Live live(scene);
  std::vector<ShadedSample> samples;
  for (VertexId v = 0; v < 6; ++v)
    samples.push_back(ShadedSample{.vertex = v, .radiance = Rgb(0.5f), .irradiance = Rgb(1.0f), .paths = 16,
                                   .epoch = v % 2 == 0 ? 0u : 3u});
  live.cache.Store(samples);
  const CacheSnapshotData data = CaptureCacheSnapshot(live.mutex, live.hierarchy, live.cache);
  std::vector<VertexId> kept;
  for (const ShadedSample& s : data.samples) kept.push_back(s.vertex);
  EXPECT_EQ(kept, (std::vector<VertexId>{0, 2, 4}));
}

TEST(CacheSnapshotTest, ATruncatedFileIsRejected) {
  const Scene scene = RoomScene();
  auto live = MakeLive(scene, 20);
  const std::string bytes = Encode(*live);
  for (size_t length : {size_t(0), size_t(1), size_t(40), kCacheSnapshotHeaderBytes - 1})
    ExpectRejected(std::span(bytes).first(length), scene, "too short");
  for (size_t length : {kCacheSnapshotHeaderBytes, kCacheSnapshotHeaderBytes + 3, bytes.size() / 2, bytes.size() - 1})
    ExpectRejected(std::span(bytes).first(length), scene, "truncated");
  std::string longer = bytes + "x";
  ExpectRejected(longer, scene, "too long");
}

TEST(CacheSnapshotTest, AnyFlippedByteIsRejected) {
  const Scene scene = RoomScene();
  auto live = MakeLive(scene, 10);
  const std::string bytes = Encode(*live);
  ASSERT_LT(bytes.size(), 200000u);
  for (size_t i = 0; i < bytes.size(); ++i) {
    std::string flipped = bytes;
    flipped[i] = char(flipped[i] ^ (1 << (i % 8)));
    auto r = DecodeCacheSnapshot(flipped, scene, RadianceBounds::ForScene(scene));
    ASSERT_FALSE(r.ok()) << "byte " << i << " flipped, still accepted";
  }
  // A flip in the content is caught by its checksum.
  std::string flipped = bytes;
  flipped[bytes.size() - 3] ^= 0x10;
  ExpectRejected(flipped, scene, "content is corrupt");
  flipped = bytes;
  flipped[20] ^= 0x01;  // in the scene identity
  ExpectRejected(flipped, scene, "header is corrupt");
}

TEST(CacheSnapshotTest, AnotherScenesSnapshotIsRejected) {
  const Scene scene = RoomScene();
  const Scene other = RoomScene(true, 0.5f);  // the same shape, moved: another identity
  ASSERT_NE(scene.identity, other.identity);
  auto live = MakeLive(scene, 10);
  const std::string bytes = Encode(*live);
  ExpectRejected(bytes, other, "scene identity");
}

TEST(CacheSnapshotTest, AnotherVersionOrAForeignFileIsRejected) {
  const Scene scene = RoomScene();
  auto live = MakeLive(scene, 10);
  std::string bytes = Encode(*live);
  std::string newer = bytes;
  const uint32_t version = kCacheSnapshotFormatVersion + 1;
  std::memcpy(newer.data() + 8, &version, 4);
  ExpectRejected(newer, scene, "format version 2");
  ResealHeader(newer);
  ExpectRejected(newer, scene, "format version 2");

  std::string text = "{\"scene\": \"cornell-box\"}\n" + std::string(100, ' ');
  ExpectRejected(text, scene, "not a Penumbra SMA cache snapshot");
  std::mt19937 rng(3);
  std::string noise(4096, '\0');
  for (char& c : noise) c = char(rng());
  ExpectRejected(noise, scene, "not a Penumbra SMA cache snapshot");
}

// A file whose checksums hold but whose counts or content are impossible (a
// hostile file, or a bug in a writer): each is caught before it allocates or
// corrupts anything.
TEST(CacheSnapshotTest, ImpossibleContentWithGoodChecksumsIsRejected) {
  const Scene scene = RoomScene();
  auto live = MakeLive(scene, 10);
  const std::string good = Encode(*live);

  // Counts far beyond the file: 2^32 - 1 splits in a few kilobytes.
  std::string huge = good;
  const uint32_t many = ~uint32_t(0);
  std::memcpy(huge.data() + 40, &many, 4);
  ResealHeader(huge);
  ExpectRejected(huge, scene, "truncated");
  // More nodes than the splits can make.
  std::string nodes = good;
  std::memcpy(nodes.data() + 32, &many, 4);
  ResealHeader(nodes);
  ExpectRejected(nodes, scene, "cannot come from");

  CacheSnapshotData data = CaptureCacheSnapshot(live->mutex, live->hierarchy, live->cache);
  ASSERT_GE(data.splits.size(), 2u);
  ASSERT_GE(data.samples.size(), 2u);
  const auto reject = [&](CacheSnapshotData d, const std::string& expected) {
    ExpectRejected(EncodeCacheSnapshot(d), scene, expected);
  };
  {
    CacheSnapshotData d = data;
    d.splits[1] = d.splits[0];  // the same node split twice
    reject(d, "split already");
  }
  {
    CacheSnapshotData d = data;
    d.splits[0].node = 1u << 30;
    reject(d, "does not exist");
  }
  {
    CacheSnapshotData d = data;
    d.splits[0].childCount = 2;
    d.splits[0].splitEdge = 7;
    std::string bytes = EncodeCacheSnapshot(d);  // shape byte 7
    ExpectRejected(bytes, scene, "unknown shape");
  }
  {
    // One 1 -> 4 split with none of the propagation Refine does: T-vertices.
    Hierarchy fresh(scene);
    CacheSnapshotData d;
    d.sceneIdentity = scene.identity;
    d.rootCount = uint32_t(fresh.RootCount());
    d.baseVertexCount = uint32_t(fresh.BaseVertexCount());
    d.nodeCount = d.rootCount + 4;
    d.vertexCount = d.baseVertexCount + 3;
    d.splits = {SplitRecord{0, 4, 0}};
    reject(d, "T-vertices");
  }
  {
    CacheSnapshotData d = data;
    d.samples[0].radiance = Rgb(3e38f, 0.0f, 0.0f);  // poison
    reject(d, "radiance");
  }
  {
    CacheSnapshotData d = data;
    d.samples[1].vertex = d.samples[0].vertex;
    reject(d, "out of order");
  }
  {
    CacheSnapshotData d = data;
    d.samples.back().vertex = d.vertexCount;
    reject(d, "does not exist");
  }
  {
    CacheSnapshotData d = data;
    d.vertexCount += 1;
    reject(d, "declares");
  }
}

// Random changes past the checksums (the checksums resealed): whatever the
// content, decoding returns an error or a hierarchy that conforms, never
// crashes, never hangs, never allocates beyond the file's size (ASan/UBSan
// builds run this too).
TEST(CacheSnapshotTest, RandomContentWithGoodChecksumsIsRejectedOrSound) {
  const Scene scene = RoomScene();
  auto live = MakeLive(scene, 15);
  const std::string good = Encode(*live);
  std::mt19937 rng(12);
  size_t accepted = 0;
  for (int trial = 0; trial < 1500; ++trial) {
    std::string bytes = good;
    const int changes = 1 + int(rng() % 4);
    for (int k = 0; k < changes; ++k) {
      // Header counts (24..47) or anywhere in the payload.
      const bool header = rng() % 4 == 0;
      const size_t at = header ? 24 + rng() % 24 : kCacheSnapshotHeaderBytes + rng() % (bytes.size() - kCacheSnapshotHeaderBytes);
      bytes[at] = char(rng());
    }
    ResealPayload(bytes);
    auto r = DecodeCacheSnapshot(bytes, scene, RadianceBounds::ForScene(scene));
    if (!r.ok()) continue;
    ++accepted;  // e.g. a changed radiance that is still possible
    ASSERT_TRUE(r->hierarchy.Conforming()) << "trial " << trial;
    for (const ShadedSample& sample : r->samples) ASSERT_LT(sample.vertex, r->hierarchy.VertexCount());
  }
  EXPECT_GT(accepted, 0u);  // some changes stay possible: the checks past the checksums ran
  EXPECT_LT(accepted, 1500u);
}

// --- On disk --------------------------------------------------------------------

std::filesystem::path TempDir(const std::string& name) {
  const auto dir = std::filesystem::temp_directory_path() /
                   ("penumbra-cache-test-" + name + "-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  return dir;
}

TEST(CacheSnapshotterTest, SnapshotsOnlyWhenChangedAndRestoresInAnotherInstance) {
  const Scene scene = RoomScene();
  const auto dir = TempDir("restore");
  auto live = MakeLive(scene, 30);
  {
    auto snapshotter = CacheSnapshotter::Open(dir, std::chrono::hours(1));
    ASSERT_TRUE(snapshotter.ok()) << snapshotter.error().message;
    EXPECT_FALSE((*snapshotter)->Restore(scene, RadianceBounds::ForScene(scene)).has_value());  // nothing there
    // A second SMA on the same directory is refused.
    auto second = CacheSnapshotter::Open(dir, std::chrono::hours(1));
    ASSERT_FALSE(second.ok());
    EXPECT_NE(second.error().message.find("another SMA"), std::string::npos) << second.error().message;

    // Start() takes the current state as saved (it is what a restore gave).
    (*snapshotter)->Start(live->mutex, live->hierarchy, live->cache);
    EXPECT_FALSE((*snapshotter)->SnapshotIfChanged());
    const auto unshaded = [&] {
      VertexId v = 0;
      while (live->cache.IsShaded(v)) ++v;
      return v;
    };
    live->cache.Store(std::vector<ShadedSample>{ShadedSample{.vertex = unshaded(), .radiance = Rgb(0.5f), .paths = 4}});
    EXPECT_TRUE((*snapshotter)->SnapshotIfChanged());
    EXPECT_FALSE((*snapshotter)->SnapshotIfChanged());
    RefineRandomly(live->hierarchy, 5, 5);  // splits alone are a change too
    live->cache.Reserve(live->hierarchy.VertexCount());
    EXPECT_TRUE((*snapshotter)->SnapshotIfChanged());
    EXPECT_FALSE((*snapshotter)->SnapshotIfChanged());
    const CacheSnapshotStats stats = (*snapshotter)->Stats();
    EXPECT_EQ(stats.written, 2u);
    EXPECT_EQ(stats.lastSamples, live->cache.ShadedCount());
    EXPECT_EQ(stats.lastBytes, std::filesystem::file_size(dir / kCacheSnapshotFileName));
    // Stop() writes a final snapshot of what changed since.
    live->cache.Store(std::vector<ShadedSample>{ShadedSample{.vertex = unshaded(), .radiance = Rgb(0.25f), .paths = 4}});
    (*snapshotter)->Stop();
    EXPECT_EQ((*snapshotter)->Stats().written, 3u);
  }
  EXPECT_FALSE(std::filesystem::exists(dir / (std::string(kCacheSnapshotFileName) + ".tmp")));
  auto again = CacheSnapshotter::Open(dir, std::chrono::hours(1));  // the lock went with the first
  ASSERT_TRUE(again.ok()) << again.error().message;
  auto restored = (*again)->Restore(scene, RadianceBounds::ForScene(scene));
  ASSERT_TRUE(restored.has_value());
  ExpectSameHierarchy(live->hierarchy, restored->hierarchy);
  EXPECT_EQ(restored->samples.size(), live->cache.ShadedCount());
  EXPECT_EQ((*again)->Stats().restoredSamples, live->cache.ShadedCount());
  std::filesystem::remove_all(dir);
}

TEST(CacheSnapshotterTest, ACorruptFileOnDiskIsIgnoredWithAWarningAndReplaced) {
  const Scene scene = RoomScene();
  const auto dir = TempDir("corrupt");
  std::filesystem::create_directories(dir);
  auto live = MakeLive(scene, 10);
  std::string bytes = Encode(*live);
  bytes[bytes.size() / 2] ^= 0x40;
  {
    std::ofstream(dir / kCacheSnapshotFileName, std::ios::binary) << bytes;
  }
  auto snapshotter = CacheSnapshotter::Open(dir, std::chrono::hours(1));
  ASSERT_TRUE(snapshotter.ok()) << snapshotter.error().message;
  EXPECT_FALSE((*snapshotter)->Restore(scene, RadianceBounds::ForScene(scene)).has_value());
  // A snapshot of a fresh state replaces the corrupt file.
  Live empty(scene);
  (*snapshotter)->Start(empty.mutex, empty.hierarchy, empty.cache);
  empty.cache.Store(std::vector<ShadedSample>{ShadedSample{.vertex = 0, .radiance = Rgb(0.1f), .paths = 1}});
  EXPECT_TRUE((*snapshotter)->SnapshotIfChanged());
  (*snapshotter)->Stop();
  auto read = ReadWholeFile(dir / kCacheSnapshotFileName, 1 << 20);
  ASSERT_TRUE(read.ok());
  auto restored = DecodeCacheSnapshot(*read, scene, RadianceBounds::ForScene(scene));
  ASSERT_TRUE(restored.ok()) << restored.error().message;
  EXPECT_EQ(restored->samples.size(), 1u);
  std::filesystem::remove_all(dir);
}

TEST(CacheSnapshotterTest, AnUnusableDirectoryFailsAtOpenWithAMessage) {
  const auto dir = TempDir("file");
  { std::ofstream(dir) << "a file, not a directory"; }
  auto opened = CacheSnapshotter::Open(dir / "sub", std::chrono::seconds(1));
  ASSERT_FALSE(opened.ok());
  EXPECT_NE(opened.error().message.find("--cache-dir"), std::string::npos) << opened.error().message;
  std::filesystem::remove(dir);
}

TEST(CacheSnapshotterTest, AnAtomicWriteReplacesTheWholeFile) {
  const auto dir = TempDir("atomic");
  std::filesystem::create_directories(dir);
  const auto file = dir / "f";
  ASSERT_TRUE(WriteFileAtomically(file, std::string(10000, 'a')).ok());
  // A torn temporary file left by a crash does not matter.
  { std::ofstream(dir / "f.tmp") << "torn"; }
  ASSERT_TRUE(WriteFileAtomically(file, "bc").ok());
  auto read = ReadWholeFile(file, 100);
  ASSERT_TRUE(read.ok());
  EXPECT_EQ(*read, "bc");
  EXPECT_FALSE(std::filesystem::exists(dir / "f.tmp"));
  EXPECT_FALSE(ReadWholeFile(file, 1).ok());  // over the limit
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace penumbra::sma
