// Image files through OpenImageIO. The only file of penumbra_scene_io that
// includes OIIO headers (they are slow to compile and, in a file that also
// includes Protobuf, must come after it).

#include "penumbra/common/image_io.h"

#include <algorithm>
#include <cmath>
#include <memory>

#include <fmt/format.h>
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include "io_util.h"
#include "penumbra/common/math.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;

bool IsFloatFormat(OIIO::TypeDesc format) {
  return format.basetype == OIIO::TypeDesc::FLOAT || format.basetype == OIIO::TypeDesc::HALF ||
         format.basetype == OIIO::TypeDesc::DOUBLE;
}

// Opens `fileName` (through `proxy` when it is not null) and reads the first
// subimage as RGB floats.
Expected<Image> Decode(const std::string& fileName, OIIO::Filesystem::IOProxy* proxy,
                       const std::string& nameForMessages, bool keepAlpha = false) {
  // Colour as stored: without this OIIO premultiplies RGB by alpha.
  OIIO::ImageSpec config;
  config.attribute("oiio:UnassociatedAlpha", 1);
  // OIIO 2.4 ignores open()'s proxy argument when a config is given; the
  // config attribute works.
  if (proxy) config.attribute("oiio:ioproxy", OIIO::TypeDesc::PTR, &proxy);
  auto input = OIIO::ImageInput::open(fileName, &config);
  if (!input) return Fail(fmt::format("{}: cannot read image: {}", nameForMessages, io::OneLine(OIIO::geterror())));

  const OIIO::ImageSpec& spec = input->spec();
  if (spec.width < 1 || spec.height < 1 || spec.depth != 1 || spec.nchannels < 1)
    return Fail(fmt::format("{}: unsupported image shape {}x{}x{} with {} channels", nameForMessages,
                            spec.width, spec.height, spec.depth, spec.nchannels));
  const bool readAlpha = keepAlpha && spec.alpha_channel >= 0 && spec.alpha_channel < spec.nchannels;
  if (auto ok = CheckImageSize(spec.width, spec.height, nameForMessages, readAlpha ? 4 : 3); !ok) return ok.error();

  // Grey (+ alpha) reads one channel, colour (+ alpha) reads three.
  const int channels = spec.nchannels >= 3 ? 3 : 1;
  const size_t pixels = size_t(spec.width) * size_t(spec.height);
  std::vector<float> stored(pixels * size_t(channels));
  if (!input->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, stored.data()))
    return Fail(fmt::format("{}: cannot decode image: {}", nameForMessages, io::OneLine(input->geterror())));

  Image image;
  image.width = spec.width;
  image.height = spec.height;
  image.storedAsFloat = IsFloatFormat(spec.format);
  if (channels == 3) {
    image.rgb = std::move(stored);
  } else {
    image.rgb.resize(pixels * 3);
    for (size_t i = 0; i < pixels; ++i) std::fill_n(&image.rgb[3 * i], 3, stored[i]);
  }
  if (readAlpha) {
    image.alpha.resize(pixels);
    const int a = spec.alpha_channel;
    if (!input->read_image(0, 0, a, a + 1, OIIO::TypeDesc::FLOAT, image.alpha.data()))
      return Fail(fmt::format("{}: cannot decode the alpha channel: {}", nameForMessages,
                              io::OneLine(input->geterror())));
  }
  return image;
}

}  // namespace

Status CheckImageSize(int64_t width, int64_t height, const std::string& nameForMessages, int channels) {
  if (width < 1 || height < 1)
    return Fail(fmt::format("{}: unsupported image shape {}x{}", nameForMessages, width, height));
  if (width > kMaxImageSide || height > kMaxImageSide || width * height > kMaxImagePixels)
    return Fail(fmt::format("{}: image of {}x{} pixels is larger than the supported {} pixels", nameForMessages,
                            width, height, kMaxImagePixels));
  const int64_t decodedBytes = width * height * std::max(channels, 1) * int64_t(sizeof(float));
  if (decodedBytes > kMaxImageBytes)
    return Fail(fmt::format("{}: image of {}x{} pixels would take {} MiB decoded; at most {} MiB are supported",
                            nameForMessages, width, height, decodedBytes >> 20, kMaxImageBytes >> 20));
  return Status::Ok();
}

Status WriteImage(const fs::path& path, int width, int height, std::span<const float> linearRgb) {
  return WriteImage(path, width, height, linearRgb, {});
}

Status WriteImage(const fs::path& path, int width, int height, std::span<const float> linearRgb,
                  std::span<const float> alpha) {
  const std::string name = path.string();
  if (width < 1 || height < 1 || width > kMaxImageSide || height > kMaxImageSide)
    return Fail(fmt::format("{}: cannot write an image of {}x{} pixels", name, width, height));
  if (linearRgb.size() != size_t(width) * size_t(height) * 3)
    return Fail(fmt::format("{}: {} values given for {}x{} RGB pixels", name, linearRgb.size(), width, height));

  const std::string ext = io::LowerExtension(path);
  const bool floatFile = ext == ".exr" || ext == ".hdr";
  const bool srgbFile = ext == ".png" || ext == ".jpg" || ext == ".jpeg";
  if (!floatFile && !srgbFile)
    return Fail(fmt::format("{}: unsupported image extension '{}' (use .exr, .hdr, .png or .jpg)", name, ext));
  const bool withAlpha = !alpha.empty();
  if (withAlpha && ext != ".exr")
    return Fail(fmt::format("{}: an alpha channel is written to .exr files only, not '{}'", name, ext));
  if (withAlpha && alpha.size() != size_t(width) * size_t(height))
    return Fail(fmt::format("{}: {} alpha values given for {}x{} pixels", name, alpha.size(), width, height));

  std::vector<uint8_t> encoded;
  if (srgbFile) {
    encoded.resize(linearRgb.size());
    for (size_t i = 0; i < linearRgb.size(); ++i) {
      // NaN would survive the clamp inside LinearToSrgb; write it as black.
      const float v = std::isnan(linearRgb[i]) ? 0.0f : linearRgb[i];
      encoded[i] = uint8_t(std::lround(LinearToSrgb(v) * 255.0f));
    }
  }

  auto output = OIIO::ImageOutput::create(name);
  if (!output) return Fail(fmt::format("{}: cannot write image: {}", name, io::OneLine(OIIO::geterror())));
  const OIIO::TypeDesc format = floatFile ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::UINT8;
  OIIO::ImageSpec spec(width, height, withAlpha ? 4 : 3, format);
  std::vector<float> rgba;  // interleaved for OIIO; unassociated, as read back
  if (withAlpha) {
    spec.alpha_channel = 3;
    spec.attribute("oiio:UnassociatedAlpha", 1);
    rgba.resize(alpha.size() * 4);
    for (size_t i = 0; i < alpha.size(); ++i) {
      std::copy_n(&linearRgb[3 * i], 3, &rgba[4 * i]);
      rgba[4 * i + 3] = alpha[i];
    }
  }
  const void* pixels = withAlpha   ? static_cast<const void*>(rgba.data())
                       : floatFile ? static_cast<const void*>(linearRgb.data())
                                   : encoded.data();
  if (!output->open(name, spec) || !output->write_image(format, pixels) || !output->close())
    return Fail(fmt::format("{}: cannot write image: {}", name, io::OneLine(output->geterror())));
  return Status::Ok();
}

Expected<Image> ReadImage(const fs::path& path) {
  const std::string name = path.string();
  if (auto ok = io::CheckRegularFile(path); !ok) return ok.error();
  return Decode(name, nullptr, name);
}

Expected<Image> ReadImageWithAlpha(const fs::path& path) {
  const std::string name = path.string();
  if (auto ok = io::CheckRegularFile(path); !ok) return ok.error();
  return Decode(name, nullptr, name, /*keepAlpha=*/true);
}

Expected<Image> ReadImageFromMemory(std::span<const std::byte> encoded, std::string_view formatExtension,
                                    const std::string& nameForMessages) {
  if (encoded.empty()) return Fail(fmt::format("{}: the embedded image is empty", nameForMessages));
  // OIIO picks the decoder by the file name's extension, even for a proxy.
  OIIO::Filesystem::IOMemReader reader(encoded.data(), encoded.size());
  return Decode(fmt::format("embedded.{}", formatExtension), &reader, nameForMessages);
}

}  // namespace penumbra
