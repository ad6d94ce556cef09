#pragma once
// A small bitmap font for the HUD, drawn for this project: printable ASCII
// (32..126) in 5 x 7 pixel glyphs, in cells two rows taller for the
// descenders of g, p, q and y. Pure data, no GL.

#include <array>
#include <cstdint>

namespace penumbra::client::gl {

inline constexpr int kGlyphWidth = 5;
inline constexpr int kGlyphHeight = 7;
inline constexpr int kCellHeight = 9;

/// The cell of `c`, one byte per row from the top, bit 4 the leftmost
/// column. Characters outside 32..126 draw as '?'.
std::array<uint8_t, kCellHeight> GlyphRows(char c);

}  // namespace penumbra::client::gl
