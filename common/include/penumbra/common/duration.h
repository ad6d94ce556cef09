#pragma once
// Durations as the logs and statistics print them.

#include <chrono>

namespace penumbra {

/// `d` in milliseconds, fractions kept.
template <class Rep, class Period>
double Milliseconds(std::chrono::duration<Rep, Period> d) {
  return std::chrono::duration<double, std::milli>(d).count();
}

}  // namespace penumbra
