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

/// The named logger, created on first use with the process's sink and level.
/// Thread-safe.
std::shared_ptr<spdlog::logger> Logger(const std::string& name);

}  // namespace penumbra
