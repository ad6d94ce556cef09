#pragma once
// How the client filters textures: the anisotropy it asks of the GL.
// Anisotropic filtering keeps the floors and walls of a walkthrough sharp at
// grazing angles on a GPU, where it is nearly free. On a software rasteriser
// it is not: Mesa llvmpipe (Debian 12) drew one frame of the street walk in
// 10-90 s with 16x anisotropy and in 5 ms without, on a view from 24 m
// looking down the street (docs/performance.md, "The client stall"), so a
// headless client on llvmpipe filters isotropically unless told otherwise.
// Pure logic, no GL: the GL layer passes GL_RENDERER and the limit it reads.

#include <optional>
#include <string_view>

namespace penumbra::client {

/// Whether GL_RENDERER names a CPU rasteriser (Mesa llvmpipe, softpipe or
/// swrast; SwiftShader).
bool IsSoftwareRasterizer(std::string_view glRenderer);

/// The GL_TEXTURE_MAX_ANISOTROPY to use: `requested` (--anisotropy) if set,
/// else 16 on a GPU and 1 on a software rasteriser; never above
/// `implementationMax` (1 when the extension is missing) and never below 1.
float ChooseAnisotropy(std::optional<float> requested, std::string_view glRenderer, float implementationMax);

}  // namespace penumbra::client
