#include "core/log.h"

#include <atomic>
#include <cstdio>
#include <mutex>
#include <string>

namespace commonlight::log {

namespace {
std::atomic<Level> g_level{Level::kInfo};
std::mutex g_mutex;

void write(Level at, std::string_view prefix, std::string_view message) {
    if (at < g_level.load(std::memory_order_relaxed)) return;
    std::string line = "commonlight: ";
    line += prefix;
    line += message;
    line += '\n';
    std::lock_guard lock(g_mutex);
    std::fwrite(line.data(), 1, line.size(), stderr);
    std::fflush(stderr);
}
}  // namespace

void setLevel(Level level) noexcept { g_level.store(level, std::memory_order_relaxed); }
Level level() noexcept { return g_level.load(std::memory_order_relaxed); }

void debug(std::string_view message) { write(Level::kDebug, "debug: ", message); }
void info(std::string_view message) { write(Level::kInfo, "", message); }
void warning(std::string_view message) { write(Level::kWarning, "warning: ", message); }
void error(std::string_view message) { write(Level::kError, "error: ", message); }

}  // namespace commonlight::log
