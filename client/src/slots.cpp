#include "penumbra/client/slots.h"

#include <algorithm>

#include "penumbra/common/check.h"

namespace penumbra::client {

uint32_t SlotAllocator::Allocate() {
  if (!free_.empty()) {
    const uint32_t slot = free_.back();
    free_.pop_back();
    return slot;
  }
  return highWater_++;
}

void SlotAllocator::Release(uint32_t slot) {
  PENUMBRA_CHECK(slot < highWater_, "released slot was never allocated");
  free_.push_back(slot);
}

void SlotAllocator::Clear() {
  free_.clear();
  highWater_ = 0;
}

std::vector<SlotRange> DirtyRanges::Take(uint32_t mergeGap) {
  std::vector<SlotRange> ranges;
  std::sort(marks_.begin(), marks_.end());
  for (uint32_t slot : marks_) {
    if (!ranges.empty()) {
      SlotRange& last = ranges.back();
      const uint32_t end = last.first + last.count;
      if (slot < end) continue;  // marked twice
      if (slot - end <= mergeGap) {
        last.count = slot + 1 - last.first;
        continue;
      }
    }
    ranges.push_back(SlotRange{slot, 1});
  }
  marks_.clear();
  return ranges;
}

}  // namespace penumbra::client
