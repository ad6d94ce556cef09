#pragma once
// Small helpers shared by the scene and image readers (private to
// penumbra_scene_io).

#include <algorithm>
#include <filesystem>
#include <string>
#include <system_error>

#include <fmt/format.h>

#include "penumbra/common/expected.h"

namespace penumbra::io {

/// Third-party messages may span lines or end in newlines; ours are one line.
inline std::string OneLine(std::string text) {
  std::replace(text.begin(), text.end(), '\r', ' ');
  std::replace(text.begin(), text.end(), '\n', ' ');
  while (!text.empty() && text.back() == ' ') text.pop_back();
  return text.empty() ? std::string("unknown error") : text;
}

/// The extension of `path` in lower case, with its dot (".obj").
inline std::string LowerExtension(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

/// An Error unless `path` names an existing regular file (or a link to one).
/// Readers check first because fopen() happily opens a directory.
inline Status CheckRegularFile(const std::filesystem::path& path) {
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (!std::filesystem::exists(status)) return Fail(fmt::format("{}: no such file", path.string()));
  if (!std::filesystem::is_regular_file(status))
    return Fail(fmt::format("{}: not a regular file", path.string()));
  return Status::Ok();
}

}  // namespace penumbra::io
