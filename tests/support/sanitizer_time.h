#pragma once
// How much longer a wait may take in a sanitizer build of the tests.
//
// ThreadSanitizer slows the renderer's path tracing and the SMA's visibility
// 5-15x (AddressSanitizer about 2x), and the processes a test starts are
// built the same way. A wait for an outcome (a view converging) scales by
// this; what a test asserts about the outcome does not. Timed performance
// assertions do not belong in tests at all (bench/ measures those).

#include <chrono>

namespace penumbra::testing {

constexpr int SanitizerTimeScale() {
#if defined(__SANITIZE_THREAD__)
  return 6;
#elif defined(__SANITIZE_ADDRESS__)
  return 2;
#else
  return 1;
#endif
}

constexpr bool ThreadSanitizerBuild() { return SanitizerTimeScale() == 6; }
constexpr bool AddressSanitizerBuild() { return SanitizerTimeScale() == 2; }  // with UBSan (cmake/PenumbraOptions.cmake)

/// `timeout` as this build may need it.
constexpr std::chrono::milliseconds ScaledTimeout(std::chrono::milliseconds timeout) {
  return timeout * SanitizerTimeScale();
}

}  // namespace penumbra::testing
