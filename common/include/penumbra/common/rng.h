#pragma once
// PCG32 (O'Neill 2014): small, fast, and splittable into independent streams,
// which is what makes every shading sample deterministic: a sample's stream
// depends only on (seed, sample id), never on the thread that shades it.

#include <cstdint>

#include "penumbra/common/hash.h"

namespace penumbra {

class Pcg32 {
 public:
  /// Stream `stream` of generator `seed`; distinct streams are independent.
  Pcg32(uint64_t seed, uint64_t stream) : inc_((stream << 1u) | 1u) {
    NextU32();
    state_ += seed;
    NextU32();
  }

  /// The stream used for the shading sample `sampleId` under global `seed`.
  static Pcg32 ForSample(uint64_t seed, uint64_t sampleId) {
    return Pcg32(Mix64(seed ^ 0xda3e39cb94b95bdbull), Mix64(sampleId));
  }

  uint32_t NextU32() {
    const uint64_t old = state_;
    state_ = old * 6364136223846793005ull + inc_;
    const auto xorshifted = static_cast<uint32_t>(((old >> 18u) ^ old) >> 27u);
    const auto rot = static_cast<uint32_t>(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((~rot + 1u) & 31));
  }

  /// Uniform in [0, 1), never 1.
  float NextFloat() { return float(NextU32() >> 8) * 0x1p-24f; }

  /// Uniform integer in [0, bound); bound > 0. Lemire's multiply-shift.
  uint32_t NextBelow(uint32_t bound) {
    return static_cast<uint32_t>((uint64_t(NextU32()) * bound) >> 32);
  }

 private:
  uint64_t state_ = 0;
  uint64_t inc_;
};

}  // namespace penumbra
