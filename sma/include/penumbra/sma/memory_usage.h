#pragma once
// What the SMA's own data occupies (issue 15, the memory budget): the sample
// cache, the hierarchy and every client's mirror, as one figure beside the
// process's resident set. The parts are estimates from sizes and capacities
// (a hash map: its bucket array plus one heap node per entry), not malloc
// counts -- close enough to compare against a budget of megabytes, and cheap
// enough to compute for every stats reply. What they leave out (the renderer
// pool's queues, visibility buffers, textures, code, the scene itself) is
// what the process's RSS shows beyond their sum.

#include <cstddef>
#include <cstdint>

namespace penumbra::sma {

/// Heap bytes of one entry of a node-based container (std::unordered_map,
/// std::unordered_set): the value and the next pointer, plus the cached hash
/// when the container keeps one, rounded up to glibc malloc's 16-byte
/// granule with its 8-byte header.
inline size_t HashNodeBytes(size_t valueBytes, bool cachedHash) {
  const size_t payload = sizeof(void*) + valueBytes + (cachedHash ? sizeof(size_t) : 0);
  return (payload + 8 + 15) / 16 * 16;
}

/// Estimated heap bytes of an unordered container: bucket array + entries.
/// Assumes the hash is not cached in the nodes (true in libstdc++ for the
/// integer keys the SMA uses: std::hash of an integer is "fast").
template <class Container>
size_t UnorderedMapBytes(const Container& c) {
  return c.bucket_count() * sizeof(void*) + c.size() * HashNodeBytes(sizeof(typename Container::value_type), false);
}

/// The SMA's data, in bytes (SmaServer's stats: memory_*).
struct MemoryUsage {
  size_t cache = 0;      // SampleCache::MemoryBytes
  size_t hierarchy = 0;  // Hierarchy::MemoryBytes
  size_t clients = 0;    // every session's ClientMirror::MemoryBytes
  size_t Total() const { return cache + hierarchy + clients; }
};

}  // namespace penumbra::sma
