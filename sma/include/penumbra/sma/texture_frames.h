#pragma once
// The scene's textures as clients receive them (TextureData): box-filtered
// down by powers of two to fit a frame, sRGB-encoded to 8 bits and framed
// -- once per texture, off the I/O threads, and shared by every client (a
// burst of requests once redid this work on the network thread for each
// request, issue 12). The SMA starts encoding them all right after the scene
// loads (PrepareAll); a request that comes before its texture is ready waits
// for that encoding.

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "penumbra/common/scene.h"
#include "penumbra/wire.pb.h"

namespace penumbra::sma {

/// `texture` as a TextureData message whose texels take at most
/// `maxTexelBytes` (3 bytes per texel): halved in each direction until they
/// fit, each output texel the average of its block in linear space, then
/// sRGB-encoded. Pure.
wire::TextureData EncodeTextureData(const Texture& texture, uint32_t index, size_t maxTexelBytes);

/// Encoded TextureData frames, one per scene texture, made on demand.
/// Thread-safe.
class TextureFrames {
 public:
  using Frame = std::shared_ptr<const std::string>;
  using ReadyHandler = std::function<void(Frame)>;
  /// Runs an encoding job somewhere other than the calling thread.
  using JobPoster = std::function<void(std::function<void()>)>;

  /// `scene` must outlive this.
  TextureFrames(const Scene& scene, size_t maxTexelBytes, JobPoster post);

  /// The frame of texture `index` (< the scene's texture count) if it is
  /// encoded; otherwise nullptr, and `onReady` is called with it later, on
  /// the encoding thread (post from there to where it is wanted). Starts
  /// the encoding if PrepareAll has not; later requests wait for it.
  Frame Get(uint32_t index, ReadyHandler onReady);

  /// Starts encoding every texture not yet encoded or being encoded (one
  /// job per texture, in index order), so that requests find them ready.
  void PrepareAll();

  /// Textures encoded so far.
  size_t EncodedCount() const;

 private:
  struct Slot {
    Frame frame;
    bool encoding = false;
    std::vector<ReadyHandler> waiters;
  };
  void Encode(uint32_t index);

  const Scene& scene_;
  const size_t maxTexelBytes_;
  JobPoster post_;
  mutable std::mutex mutex_;
  std::vector<Slot> slots_;
};

}  // namespace penumbra::sma
