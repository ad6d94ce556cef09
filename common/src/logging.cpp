#include "penumbra/common/logging.h"

#include <algorithm>
#include <chrono>
#include <ctime>
#include <iterator>

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

namespace {

void Append(spdlog::memory_buf_t& out, std::string_view text) { out.append(text.data(), text.data() + text.size()); }

// The length of the valid UTF-8 sequence at text[i], or 0.
size_t Utf8Length(std::string_view text, size_t i) {
  const auto b = [&](size_t k) { return static_cast<unsigned char>(text[k]); };
  const unsigned char c = b(i);
  size_t n = c >= 0xf0 && c <= 0xf4 ? 4 : c >= 0xe0 ? 3 : c >= 0xc2 && c <= 0xdf ? 2 : 0;
  if (n == 0 || i + n > text.size()) return 0;
  for (size_t k = 1; k < n; ++k)
    if ((b(i + k) & 0xc0) != 0x80) return 0;
  if (n == 3 && ((c == 0xe0 && b(i + 1) < 0xa0) || (c == 0xed && b(i + 1) >= 0xa0))) return 0;  // overlong, surrogate
  if (n == 4 && ((c == 0xf0 && b(i + 1) < 0x90) || (c == 0xf4 && b(i + 1) >= 0x90))) return 0;  // overlong, > U+10FFFF
  return n;
}

// A JSON string: escapes as JSON requires; a byte that is not valid UTF-8
// becomes U+FFFD, so that every line parses whatever a message holds.
void AppendJsonString(spdlog::memory_buf_t& out, std::string_view text) {
  out.push_back('"');
  for (size_t i = 0; i < text.size(); ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    if (c == '"') {
      Append(out, "\\\"");
    } else if (c == '\\') {
      Append(out, "\\\\");
    } else if (c == '\n') {
      Append(out, "\\n");
    } else if (c < 0x20 || c == 0x7f) {
      fmt::format_to(std::back_inserter(out), "\\u{:04x}", unsigned(c));
    } else if (c < 0x80) {
      out.push_back(char(c));
    } else if (const size_t n = Utf8Length(text, i); n > 0) {
      Append(out, text.substr(i, n));
      i += n - 1;
    } else {
      Append(out, "\\ufffd");
    }
  }
  out.push_back('"');
}

class JsonLogFormatter final : public spdlog::formatter {
 public:
  void format(const spdlog::details::log_msg& msg, spdlog::memory_buf_t& dest) override {
    const auto since = msg.time.time_since_epoch();
    const auto seconds = std::chrono::duration_cast<std::chrono::seconds>(since);
    const auto millis = std::chrono::duration_cast<std::chrono::milliseconds>(since - seconds).count();
    const std::time_t t = std::time_t(seconds.count());
    std::tm utc{};
    gmtime_r(&t, &utc);
    fmt::format_to(std::back_inserter(dest), "{{\"time\":\"{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:03}Z\",\"level\":",
                   utc.tm_year + 1900, utc.tm_mon + 1, utc.tm_mday, utc.tm_hour, utc.tm_min, utc.tm_sec, millis);
    const auto level = spdlog::level::to_string_view(msg.level);
    AppendJsonString(dest, std::string_view(level.data(), level.size()));
    Append(dest, ",\"logger\":");
    AppendJsonString(dest, std::string_view(msg.logger_name.data(), msg.logger_name.size()));
    fmt::format_to(std::back_inserter(dest), ",\"thread\":{},\"message\":", msg.thread_id);
    AppendJsonString(dest, std::string_view(msg.payload.data(), msg.payload.size()));
    Append(dest, "}\n");
  }
  std::unique_ptr<spdlog::formatter> clone() const override { return std::make_unique<JsonLogFormatter>(); }
};

}  // namespace

std::unique_ptr<spdlog::formatter> MakeJsonLogFormatter() { return std::make_unique<JsonLogFormatter>(); }

bool SetupLogFormat(std::string_view format) {
  std::lock_guard lock(SetupMutex());
  if (format == "text") return true;
  if (format != "json") return false;
  // Every logger writes through the one shared sink, now and later.
  SharedSink()->set_formatter(MakeJsonLogFormatter());
  return true;
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
