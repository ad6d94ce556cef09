#pragma once
// The release every executable reports with --version: the CMake project's
// version (CMakeLists.txt), given to penumbra_common's users as PENUMBRA_VERSION.

#include <string_view>

namespace penumbra {

inline constexpr std::string_view kVersion = PENUMBRA_VERSION;

}  // namespace penumbra
