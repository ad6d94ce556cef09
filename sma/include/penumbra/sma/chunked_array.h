#pragma once
// A growable array kept in fixed-size chunks, for the hierarchy's node and
// vertex tables (hierarchy.h), which splits grow to hundreds of MB on large
// models. Unlike a std::vector:
//  * growth never copies: a std::vector that fills reallocates to twice its
//    capacity and copies every element -- on the 2 M-triangle street the
//    first split grew the hierarchy by 150 MiB at once and copied ~420 MB
//    under the SMA's exclusive state lock (docs/performance.md, "Memory over
//    a long walk");
//  * at most one chunk is allocated ahead of the elements (capacity - size
//    < kChunkSize), so the memory follows the size;
//  * elements never move: a reference stays valid while the array grows.
// Indexing is one indirection through the chunk table (a shift and a mask).
//
// Threads: not synchronised, like a std::vector; the owner's lock guards it.

#include <cstddef>
#include <memory>
#include <vector>

#include "penumbra/common/check.h"

namespace penumbra::sma {

template <class T, unsigned kChunkBits = 14>
class ChunkedArray {
 public:
  static constexpr size_t kChunkSize = size_t(1) << kChunkBits;

  size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  /// Elements allocated (whole chunks).
  size_t capacity() const { return chunks_.size() * kChunkSize; }
  /// Bytes held: the chunks and the chunk table.
  size_t MemoryBytes() const {
    return capacity() * sizeof(T) + chunks_.capacity() * sizeof(std::unique_ptr<T[]>);
  }

  /// Bytes allocated beyond the last element (the last chunk's tail).
  size_t TailBytes() const { return (capacity() - size_) * sizeof(T); }

  T& operator[](size_t i) { return chunks_[i >> kChunkBits][i & (kChunkSize - 1)]; }
  const T& operator[](size_t i) const { return chunks_[i >> kChunkBits][i & (kChunkSize - 1)]; }

  void push_back(const T& value) {
    if (size_ == capacity()) chunks_.push_back(std::make_unique<T[]>(kChunkSize));
    (*this)[size_++] = value;
  }
  /// Grows to `n` elements, the new ones value-initialised. Never shrinks
  /// (nothing here needs it): `n` below size() is a programming error.
  void resize(size_t n) {
    PENUMBRA_CHECK(n >= size_, "ChunkedArray only grows");
    while (capacity() < n) chunks_.push_back(std::make_unique<T[]>(kChunkSize));
    size_ = n;
  }
  /// Makes room in the chunk table (not the chunks) for `n` elements.
  void reserve(size_t n) { chunks_.reserve((n + kChunkSize - 1) >> kChunkBits); }

 private:
  std::vector<std::unique_ptr<T[]>> chunks_;
  size_t size_ = 0;
};

}  // namespace penumbra::sma
