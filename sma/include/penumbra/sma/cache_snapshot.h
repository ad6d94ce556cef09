#pragma once
// The sample cache on disk (`--cache-dir`): a snapshot of every shaded
// sample and of the splits their vertices hang on, written periodically and
// at shutdown, read back at start so that a restarted SMA (even after
// kill -9) does not shade again what it had.
//
// Ids. A sample belongs to a vertex id, and midpoint vertex ids are assigned
// by splits in the order they happen (hierarchy.h, "Ids"). So a snapshot
// stores the splits, in that order -- read off the nodes: children are
// appended per split, so walking node ids from RootCount() visits the splits
// in the order they were made -- and the reload repeats them
// (Hierarchy::ApplySplit) on a fresh hierarchy of the same scene, which gives
// back every node and vertex id bit for bit. Nothing else of the hierarchy is
// stored: positions, normals and edge maps follow from the splits.
//
// Format (little-endian; why not protobuf: docs in sma/README.md, "Cache on
// disk"):
//   header, 64 bytes:
//     0  magic "PNBRSMAC"            8  u32 format version (kFormatVersion)
//     12 u32 header bytes (64)       16 u64 scene identity
//     24 u32 root count              28 u32 base vertex count
//     32 u32 node count              36 u32 vertex count    (after the splits)
//     40 u32 split count             44 u32 sample count
//     48 u64 payload checksum        56 u64 header checksum (of bytes 0..55)
//   payload: split count x 5 bytes   (u32 node, u8 shape: 0-2 = 1 -> 2 across
//                                     that edge, 3 = 1 -> 4), in order made;
//            sample count x 38 bytes (u32 vertex, 3 f32 radiance, 3 f32
//                                     irradiance, f32 standard error, u32
//                                     paths, u16 rounds), vertices increasing.
// Checksums are penumbra::Hasher digests (hash.h): they catch torn and
// flipped bytes, not tampering. A file is written to a temporary name in the
// same directory, fsynced, renamed over the old one, and the directory
// fsynced: a crash at any moment leaves the previous snapshot or the new one.
//
// A snapshot is untrusted input: every count is checked against the file's
// size and the hierarchy's limits before anything is allocated, every split
// must apply to a leaf and the result must conform, every sample must name a
// vertex that exists and be physically possible (RadianceBounds). A file that
// fails any check is ignored with one warning naming the problem.

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/sample_cache.h"

namespace spdlog {
class logger;
}

namespace penumbra::sma {

inline constexpr uint32_t kCacheSnapshotFormatVersion = 1;
inline constexpr size_t kCacheSnapshotHeaderBytes = 64;
inline constexpr size_t kCacheSnapshotSplitBytes = 5;
inline constexpr size_t kCacheSnapshotSampleBytes = 38;
/// The snapshot's name in --cache-dir.
inline constexpr const char* kCacheSnapshotFileName = "sma-cache.snapshot";

/// One split as Refine() made it.
struct SplitRecord {
  NodeId node = kNoNode;
  uint8_t childCount = 0;  // 2 or 4
  uint8_t splitEdge = 0;   // the edge of a 1 -> 2 split

  bool operator==(const SplitRecord&) const = default;
};

/// What a snapshot holds, copied out of a live hierarchy and cache.
struct CacheSnapshotData {
  uint64_t sceneIdentity = 0;
  uint32_t rootCount = 0;
  uint32_t baseVertexCount = 0;
  uint32_t nodeCount = 0;    // after the splits
  uint32_t vertexCount = 0;  // after the splits
  std::vector<SplitRecord> splits;     // in the order they were made
  std::vector<ShadedSample> samples;   // shaded vertices, increasing
  uint64_t cacheChanges = 0;           // SampleCache::Changes() when the copy began
};

/// A snapshot read back: a hierarchy with the same ids as the one saved, and
/// the samples to put in a cache for it (SampleCache::Restore).
struct RestoredCache {
  Hierarchy hierarchy;
  std::vector<ShadedSample> samples;
  size_t splits = 0;
};

/// Copies what a snapshot needs, taking `stateMutex` shared for at most
/// `chunk` nodes or vertices at a time. Only samples shaded at scene epoch 0
/// (every movable object where the scene file puts it) are copied: a
/// restarted SMA starts at that pose, so they are right for it (a sample of
/// epoch 0 still cached after moves was judged unchanged by them), while
/// one shaded after a move may not be. Splits are pose-free (object space).
///
/// `chunk` nodes or vertices at a time, so that writers (samples arriving,
/// refinement) wait briefly at most. Consistent because the hierarchy only
/// grows: the splits below the node count read first are final, and a sample
/// once shaded stays shaded (an improvement copied half-way is one estimate
/// or the other, never a mix: each vertex is copied under one lock).
/// Any thread; `hierarchy` and `cache` must be those `stateMutex` guards.
CacheSnapshotData CaptureCacheSnapshot(std::shared_mutex& stateMutex, const Hierarchy& hierarchy,
                                       const SampleCache& cache, size_t chunk = 16384);

/// The file's bytes for `data` (header and payload).
std::string EncodeCacheSnapshot(const CacheSnapshotData& data);

/// Checks `bytes` as a snapshot for `scene` and replays it on a fresh
/// hierarchy; an Error names what is wrong (foreign, truncated, corrupt,
/// another version, another scene, impossible content). Allocates at most in
/// proportion to bytes.size().
Expected<RestoredCache> DecodeCacheSnapshot(std::span<const char> bytes, const Scene& scene,
                                            const RadianceBounds& bounds);

/// The midpoints of `hierarchy`'s splits that `cache` has no sample for. After
/// a restore these are the samples that were on their way when the snapshot
/// was taken: no view asks for them again (visibility shows a split's parent
/// until they arrive, and refinement never splits a node twice), so the SMA
/// asks for them itself. Caller holds the state lock.
std::vector<VertexId> UnshadedMidpoints(const Hierarchy& hierarchy, const SampleCache& cache);

/// Writes `bytes` to `path` so that a crash at any moment leaves either the
/// old file or the new one whole: a temporary file beside it, fsync, rename,
/// fsync of the directory.
Status WriteFileAtomically(const std::filesystem::path& path, std::string_view bytes);

/// Reads a whole file (at most `maxBytes`).
Expected<std::string> ReadWholeFile(const std::filesystem::path& path, uint64_t maxBytes);

struct CacheSnapshotStats {
  uint64_t written = 0;          // snapshots written since start
  uint64_t failed = 0;           // snapshots that could not be written
  uint64_t lastBytes = 0;        // size of the last one written
  uint64_t lastSamples = 0;      // shaded samples in it
  uint64_t lastSplits = 0;
  double lastCaptureMs = 0.0;    // copying under the state lock (in chunks)
  double lastWriteMs = 0.0;      // encoding, writing, fsync, rename
  uint64_t restoredSamples = 0;  // put back at start
  uint64_t restoredSplits = 0;
  double restoreMs = 0.0;
};

/// Owns --cache-dir: the lock that keeps a second SMA out of it, the reload
/// at start, and the snapshot thread.
///
/// Threads: Restore() before Start(); Start() and Stop() from one thread (the
/// SMA's Run()); Stats() from any. The snapshot thread takes the state lock
/// shared only, in chunks (CaptureCacheSnapshot), and encodes and writes
/// without it, so I/O threads and views are never held up by the disk.
class CacheSnapshotter {
 public:
  /// Creates `dir` if needed and locks it (flock on DIR/sma-cache.lock);
  /// fails with a message if it cannot, or if another process holds it.
  static Expected<std::unique_ptr<CacheSnapshotter>> Open(const std::filesystem::path& dir,
                                                          std::chrono::milliseconds interval);
  ~CacheSnapshotter();
  CacheSnapshotter(const CacheSnapshotter&) = delete;
  CacheSnapshotter& operator=(const CacheSnapshotter&) = delete;

  /// The saved hierarchy and samples when DIR holds a snapshot of `scene`;
  /// nullopt when it holds none, or one that does not fit (a warning says
  /// why; the next snapshot replaces it).
  std::optional<RestoredCache> Restore(const Scene& scene, const RadianceBounds& bounds);

  /// Starts snapshotting every interval, when anything changed since the
  /// last snapshot (or since the restore).
  void Start(std::shared_mutex& stateMutex, const Hierarchy& hierarchy, const SampleCache& cache);
  /// Stops the thread and writes a final snapshot if anything changed.
  /// Call once nothing changes any more (I/O stopped). Idempotent.
  void Stop();
  /// Writes a snapshot now if anything changed; returns whether one was written.
  bool SnapshotIfChanged();

  CacheSnapshotStats Stats() const;
  const std::filesystem::path& File() const { return file_; }

 private:
  CacheSnapshotter(std::filesystem::path dir, std::chrono::milliseconds interval, int lockFd);
  void Loop();

  const std::filesystem::path dir_;
  const std::filesystem::path file_;
  const std::chrono::milliseconds interval_;
  const int lockFd_;
  std::shared_ptr<spdlog::logger> log_;

  std::shared_mutex* stateMutex_ = nullptr;
  const Hierarchy* hierarchy_ = nullptr;
  const SampleCache* cache_ = nullptr;

  std::mutex snapshotMutex_;  // one snapshot at a time (thread and Stop)
  std::pair<size_t, uint64_t> lastSaved_{0, 0};  // (node count, cache changes) on disk

  mutable std::mutex mutex_;  // guards stopping_, stats_
  std::condition_variable wake_;
  bool stopping_ = false;
  CacheSnapshotStats stats_;
  std::thread thread_;
};

}  // namespace penumbra::sma
