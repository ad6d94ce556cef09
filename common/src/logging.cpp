#include "penumbra/common/logging.h"

#include <algorithm>

#include <fmt/format.h>

#include "penumbra/common/check.h"

#include <mutex>

#include <spdlog/sinks/stdout_color_sinks.h>

namespace penumbra {
namespace {

std::mutex& SetupMutex() {
  static std::mutex m;
  return m;
}

spdlog::sink_ptr& SharedSink() {
  static spdlog::sink_ptr sink = std::make_shared<spdlog::sinks::stderr_color_sink_mt>();
  return sink;
}

}  // namespace

bool SetupLogging(std::string_view level) {
  std::lock_guard lock(SetupMutex());
  const auto parsed = spdlog::level::from_str(std::string(level));
  // from_str maps unknown names to "off"; only accept "off" when asked for.
  const bool known = parsed != spdlog::level::off || level == "off";
  spdlog::set_level(known ? parsed : spdlog::level::info);
  spdlog::set_pattern("%Y-%m-%d %H:%M:%S.%e [%n] %^%l%$ %v");
  spdlog::flush_on(spdlog::level::info);
  return known;
}

std::shared_ptr<spdlog::logger> Logger(const std::string& name) {
  std::lock_guard lock(SetupMutex());
  if (auto existing = spdlog::get(name)) return existing;
  auto logger = std::make_shared<spdlog::logger>(name, SharedSink());
  logger->set_level(spdlog::get_level());
  logger->flush_on(spdlog::level::info);
  spdlog::register_logger(logger);
  return logger;
}

}  // namespace penumbra

namespace penumbra {

std::string Printable(std::string_view text, size_t maxBytes) {
  std::string out;
  const size_t shown = std::min(text.size(), maxBytes);
  out.reserve(shown + 16);
  for (size_t i = 0; i < shown; ++i) {
    const unsigned char c = static_cast<unsigned char>(text[i]);
    if (c >= 0x20 && c < 0x7f && c != '\\')
      out += char(c);
    else
      out += fmt::format("\\x{:02x}", c);
  }
  if (shown < text.size()) out += fmt::format("... ({} bytes)", text.size());
  return out;
}

}  // namespace penumbra

namespace penumbra::detail {

void CheckFailed(const char* file, int line, const char* condition, std::string_view message) {
  Logger("check")->critical("{}:{}: CHECK({}) failed: {}", file, line, condition, message);
  spdlog::shutdown();
  std::abort();
}

}  // namespace penumbra::detail
