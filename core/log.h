// Minimal thread-safe logging to stderr: "commonlight: warning: <message>".
#pragma once

#include <string_view>

namespace commonlight::log {

enum class Level { kDebug, kInfo, kWarning, kError, kQuiet };

void setLevel(Level level) noexcept;
Level level() noexcept;

void debug(std::string_view message);
void info(std::string_view message);
void warning(std::string_view message);
void error(std::string_view message);

}  // namespace commonlight::log
