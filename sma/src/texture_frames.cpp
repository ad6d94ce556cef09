#include "penumbra/sma/texture_frames.h"

#include <algorithm>
#include <cmath>

#include "penumbra/common/messages.h"
#include "penumbra/common/math.h"

namespace penumbra::sma {

wire::TextureData EncodeTextureData(const Texture& t, uint32_t index, size_t maxTexelBytes) {
  int step = 1;
  while (size_t(t.width / step) * size_t(t.height / step) * 3 > maxTexelBytes && step < 1 << 12) step *= 2;
  const int w = std::max(1, t.width / step), h = std::max(1, t.height / step);
  std::string rgb(size_t(w) * size_t(h) * 3, '\0');
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      Rgb sum(0.0f);
      for (int dy = 0; dy < step; ++dy)
        for (int dx = 0; dx < step; ++dx)
          sum += t.texels[size_t(std::min(t.height - 1, y * step + dy)) * size_t(t.width) +
                          size_t(std::min(t.width - 1, x * step + dx))];
      sum /= float(step * step);
      for (int c = 0; c < 3; ++c)
        rgb[(size_t(y) * size_t(w) + size_t(x)) * 3 + size_t(c)] = char(std::lround(LinearToSrgb(sum[c]) * 255.0f));
    }
  wire::TextureData data;
  data.set_texture(index);
  data.set_width(uint32_t(w));
  data.set_height(uint32_t(h));
  data.set_rgb8(std::move(rgb));
  return data;
}

TextureFrames::TextureFrames(const Scene& scene, size_t maxTexelBytes, JobPoster post)
    : scene_(scene), maxTexelBytes_(maxTexelBytes), post_(std::move(post)), slots_(scene.textures.size()) {}

TextureFrames::Frame TextureFrames::Get(uint32_t index, ReadyHandler onReady) {
  bool start = false;
  {
    std::lock_guard lock(mutex_);
    Slot& slot = slots_.at(index);
    if (slot.frame) return slot.frame;
    slot.waiters.push_back(std::move(onReady));
    start = !std::exchange(slot.encoding, true);
  }
  if (start) post_([this, index] { Encode(index); });
  return nullptr;
}

void TextureFrames::PrepareAll() {
  for (uint32_t index = 0; index < slots_.size(); ++index) {
    {
      std::lock_guard lock(mutex_);
      Slot& slot = slots_[index];
      if (slot.frame || std::exchange(slot.encoding, true)) continue;
    }
    post_([this, index] { Encode(index); });
  }
}

size_t TextureFrames::EncodedCount() const {
  std::lock_guard lock(mutex_);
  return size_t(std::count_if(slots_.begin(), slots_.end(), [](const Slot& s) { return s.frame != nullptr; }));
}

void TextureFrames::Encode(uint32_t index) {
  wire::Envelope envelope;
  *envelope.mutable_texture_data() = EncodeTextureData(scene_.textures[index], index, maxTexelBytes_);
  auto frame = std::make_shared<const std::string>(EncodeEnvelopeFrame(envelope));
  std::vector<ReadyHandler> waiters;
  {
    std::lock_guard lock(mutex_);
    Slot& slot = slots_[index];
    slot.frame = frame;
    slot.encoding = false;
    waiters.swap(slot.waiters);
  }
  for (auto& w : waiters) w(frame);
}

}  // namespace penumbra::sma
