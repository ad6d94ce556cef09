#pragma once
// Helpers shared by the libFuzzer targets in this folder (see README.md).
// Each target is one LLVMFuzzerTestOneInput over bytes a peer or a file can
// deliver; these helpers turn those bytes into what the code under test
// takes, the way the real process does.

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <google/protobuf/stubs/logging.h>
#include <spdlog/spdlog.h>

#include "penumbra/common/check.h"
#include "penumbra/common/framing.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/messages.h"

namespace penumbra::fuzz {

/// Largest frame the stream targets accept: a peer's frames are bounded by
/// the connection's limit before any decoding, and a small one here keeps
/// each run fast without hiding anything from the decoders.
inline constexpr uint32_t kFuzzMaxFrameBytes = 1u << 20;

/// Splits `data` into frames as a connection does (FrameDecoder), stopping at
/// the first framing error or incomplete frame, and decodes each payload as
/// an Envelope; undecodable payloads are skipped, as a connection would have
/// closed on them.
inline std::vector<wire::Envelope> DecodeFrameStream(const uint8_t* data, size_t size) {
  std::vector<wire::Envelope> envelopes;
  FrameDecoder decoder(kFuzzMaxFrameBytes);
  decoder.Feed(data, size);
  for (;;) {
    auto frame = decoder.Next();
    if (!frame || !*frame) break;
    if (auto envelope = DecodeEnvelope(**frame)) envelopes.push_back(std::move(*envelope));
  }
  return envelopes;
}

/// Silences logging: the code under test logs every refusal, and Protobuf
/// logs every string field that is not UTF-8, which would cost most of each
/// run's time.
inline void QuietLogs() {
  spdlog::set_level(spdlog::level::off);
  google::protobuf::SetLogHandler(nullptr);
}

/// A private folder for targets that must hand files to a loader, removed
/// when the process exits normally.
class ScratchDir {
 public:
  ScratchDir() {
    std::string pattern = (std::filesystem::temp_directory_path() / "penumbra-fuzz-XXXXXX").string();
    if (!mkdtemp(pattern.data())) std::abort();
    path_ = pattern;
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  const std::filesystem::path& Path() const { return path_; }

 private:
  std::filesystem::path path_;
};

inline void WriteFile(const std::filesystem::path& path, std::string_view bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), std::streamsize(bytes.size()));
}

/// The source tree's folder of the shipped scenes (a compile definition).
inline std::filesystem::path ScenesDir() { return std::filesystem::path(PENUMBRA_SOURCE_DIR) / "scenes"; }

}  // namespace penumbra::fuzz
