#pragma once
// Invariant checks. A failed CHECK is a bug in Penumbra, not bad input: it
// logs one critical line with the place and the condition, then aborts.
// Bad input never reaches a CHECK; it is reported as an Error.

#include <cstdlib>
#include <string_view>

namespace penumbra::detail {
[[noreturn]] void CheckFailed(const char* file, int line, const char* condition, std::string_view message);
}  // namespace penumbra::detail

#define PENUMBRA_CHECK(condition, message)                                             \
  do {                                                                                 \
    if (!(condition)) ::penumbra::detail::CheckFailed(__FILE__, __LINE__, #condition, (message)); \
  } while (false)
