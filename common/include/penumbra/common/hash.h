#pragma once
// 64-bit hashing for identities (scene hash) and seeding random streams.
// Not cryptographic: it detects accidental mismatch, not tampering.

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <string_view>

namespace penumbra {

/// SplitMix64 finaliser: a bijective mix with good avalanche.
constexpr uint64_t Mix64(uint64_t x) {
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ull;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebull;
  x ^= x >> 31;
  return x;
}

/// Combines a value into a running hash (order-sensitive).
constexpr uint64_t HashCombine(uint64_t seed, uint64_t value) {
  return Mix64(seed ^ (value + 0x9e3779b97f4a7c15ull + (seed << 6) + (seed >> 2)));
}

/// Incremental hash of a byte stream; 8 bytes per step, so a scene of tens of
/// megabytes hashes in milliseconds.
class Hasher {
 public:
  explicit Hasher(uint64_t seed = 0x50656e756d627261ull) : state_(seed) {}

  void Update(const void* data, size_t size) {
    const auto* bytes = static_cast<const unsigned char*>(data);
    size_t i = 0;
    for (; i + 8 <= size; i += 8) {
      uint64_t word;
      std::memcpy(&word, bytes + i, 8);
      state_ = HashCombine(state_, word);
    }
    uint64_t tail = 0;
    std::memcpy(&tail, bytes + i, size - i);
    state_ = HashCombine(state_, tail ^ (uint64_t(size - i) << 56));
    length_ += size;
  }
  template <class T>
  void UpdateSpan(std::span<const T> values) {
    Update(values.data(), values.size_bytes());
  }
  void Update(std::string_view s) {
    Update(uint64_t(s.size()));
    Update(s.data(), s.size());
  }
  void Update(uint64_t v) { Update(&v, sizeof v); }

  uint64_t Digest() const { return Mix64(state_ ^ length_); }

 private:
  uint64_t state_;
  uint64_t length_ = 0;
};

}  // namespace penumbra
