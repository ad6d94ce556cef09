#pragma once
// Reading and writing RGB images, with alpha where asked (screenshots, reference renders, textures).
// OpenImageIO does the file formats; its headers stay inside image_io.cpp so
// that including this header costs nothing. Every function is thread-safe and
// reports bad input as an Error that names the file; none throws.

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "penumbra/common/expected.h"

namespace penumbra {

/// An RGB image in memory, three floats per pixel, row 0 at the top.
struct Image {
  int width = 0;
  int height = 0;
  std::vector<float> rgb;  // width * height * 3, row-major
  /// True when the file stored floating-point values (EXR, HDR, float TIFF),
  /// which are linear by convention; false for 8- and 16-bit integer data,
  /// which is sRGB-encoded by convention.
  bool storedAsFloat = false;
  /// The file's alpha channel, width * height values (a screenshot's
  /// coverage: 0 where nothing was drawn). Filled by ReadImageWithAlpha when
  /// the file has one; empty otherwise.
  std::vector<float> alpha;
};

/// Largest image ReadImage accepts, so that a corrupt header cannot make it
/// allocate gigabytes: 32768 pixels per side and 2^26 pixels in all.
inline constexpr int kMaxImageSide = 32768;
inline constexpr int64_t kMaxImagePixels = int64_t(1) << 26;
/// ... and at most this many bytes once decoded (width * height * 3 floats,
/// 12 bytes a pixel: 256 MiB is 22.3 million pixels, e.g. 4096 x 4096 with
/// room to spare). Checked before anything is allocated: a 200 kB PNG just
/// under the pixel limit used to cost 1.6 GiB (the decoded floats, then the
/// texture made of them).
inline constexpr int64_t kMaxImageBytes = int64_t(256) << 20;

/// OK when an image of `width` x `height` pixels, decoded to `channels`
/// floats a pixel, is within the limits above; otherwise an Error that starts
/// with `nameForMessages`.
Status CheckImageSize(int64_t width, int64_t height, const std::string& nameForMessages, int channels = 3);

/// Writes linear RGB (width * height * 3 floats, row 0 at the top) to `path`,
/// choosing the format by extension (case-insensitive):
///   .exr, .hdr        float, values unchanged (linear);
///   .png, .jpg, .jpeg 8-bit, each value clamped to [0,1] and sRGB-encoded.
/// Tone mapping, if wanted, is the caller's job. Any other extension, a size
/// mismatch or an I/O failure is an Error.
Status WriteImage(const std::filesystem::path& path, int width, int height,
                  std::span<const float> linearRgb);
/// The same with an alpha channel (width * height values, stored unchanged
/// beside unassociated RGB): .exr only, since it is meant for coverage that
/// tools read back exactly; any other extension is an Error.
Status WriteImage(const std::filesystem::path& path, int width, int height, std::span<const float> linearRgb,
                  std::span<const float> alpha);

/// Reads an image file as stored: integer formats are scaled to [0,1] without
/// any colour-space conversion, float formats are returned unchanged. A grey
/// image is replicated to RGB; channels beyond the third (alpha) are dropped.
Expected<Image> ReadImage(const std::filesystem::path& path);
/// Like ReadImage, and keeps the file's alpha channel in Image::alpha when it
/// has one (counted in the decoded-size limit: 16 bytes a pixel then).
Expected<Image> ReadImageWithAlpha(const std::filesystem::path& path);

/// Like ReadImage, for an encoded file held in memory (a PNG or JPEG embedded
/// in a glTF/GLB). `formatExtension` ("png", "jpg", ...) tells the decoder
/// what the bytes are; `nameForMessages` prefixes every error.
Expected<Image> ReadImageFromMemory(std::span<const std::byte> encoded, std::string_view formatExtension,
                                    const std::string& nameForMessages);

}  // namespace penumbra
