#pragma once
// One logging setup for every process; named loggers per subsystem
// ("renderer", "sma.cache", "net", ...). Libraries log through Logger(name)
// and never write to std::cout.

#include <memory>
#include <string>
#include <string_view>

#include <spdlog/spdlog.h>

namespace penumbra {

/// Configures spdlog for a process: level ("trace".."off"), stderr sink,
/// a pattern with time, logger name and thread. Call once from main().
/// Returns false (and leaves the level at info) for an unknown level name.
bool SetupLogging(std::string_view level = "info");

/// Chooses the line format after SetupLogging: "text" (the default) or
/// "json", one object per line for log collectors:
/// {"time":"2026-11-24T11:20:03.123Z","level":"info","logger":"sma",
///  "thread":1234,"message":"..."} (UTC; the message JSON-escaped).
/// Returns false, changing nothing, for another name.
bool SetupLogFormat(std::string_view format);

/// The JSON line formatter of SetupLogFormat("json"), for tests.
std::unique_ptr<spdlog::formatter> MakeJsonLogFormatter();

/// The named logger, created on first use with the process's sink and level.
/// Thread-safe.
std::shared_ptr<spdlog::logger> Logger(const std::string& name);

/// `text` from a peer, made safe to log: printable ASCII kept, every other
/// byte (newlines, escapes, UTF-8) as \xNN, and cut after `maxBytes` of
/// input with a note of the full length -- so a peer can neither forge log
/// lines nor flood the log.
std::string Printable(std::string_view text, size_t maxBytes = 64);

}  // namespace penumbra
