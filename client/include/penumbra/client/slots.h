#pragma once
// Slot bookkeeping for GPU-mirrored arrays. The client keeps vertices and
// triangles in fixed-size slots of CPU arrays that mirror GPU buffers; a
// removed element's slot goes on a free list and is reused by the next
// addition, and every written slot is marked dirty so that the renderer
// uploads only the ranges that changed. Plain data, no GL; single-threaded
// (owned by the render thread).

#include <cstdint>
#include <vector>

namespace penumbra::client {

/// Hands out dense slot indices, reusing released ones first.
class SlotAllocator {
 public:
  /// A free slot: the most recently released one if any, else a new one at
  /// the end (which raises HighWater()).
  uint32_t Allocate();
  /// Returns `slot` (which must be allocated) to the free list.
  void Release(uint32_t slot);
  /// Forgets every slot.
  void Clear();

  /// One past the highest slot ever handed out since the last Clear(): the
  /// length of the array (and GPU buffer) that must hold every live slot.
  uint32_t HighWater() const { return highWater_; }
  /// Slots currently allocated.
  uint32_t Live() const { return highWater_ - uint32_t(free_.size()); }

 private:
  std::vector<uint32_t> free_;
  uint32_t highWater_ = 0;
};

/// A run of consecutive slots [first, first + count).
struct SlotRange {
  uint32_t first = 0;
  uint32_t count = 0;
  bool operator==(const SlotRange&) const = default;
};

/// Slots written since the last upload. Marking is O(1); Take() sorts and
/// merges, so its cost follows the number of marks, not the array size.
class DirtyRanges {
 public:
  void Mark(uint32_t slot) { marks_.push_back(slot); }
  bool Empty() const { return marks_.empty(); }

  /// The marked slots as sorted, disjoint ranges, and forgets them. Ranges
  /// separated by at most `mergeGap` clean slots are merged: re-uploading a
  /// few unchanged slots is cheaper than another glBufferSubData call.
  std::vector<SlotRange> Take(uint32_t mergeGap = 0);
  void Clear() { marks_.clear(); }

 private:
  std::vector<uint32_t> marks_;
};

}  // namespace penumbra::client
