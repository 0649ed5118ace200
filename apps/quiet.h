// `-q` (errors only, docs/cli.md): a subcommand's messages (what it is doing, its summary) go
// through say() / sayErr(), which print nothing under -q. A subcommand's product (track's CSV on
// standard output, the camera list of `cameras`, a benchmark's tables) is printed regardless.
#pragma once

#include <cstdarg>
#include <cstdio>

#include "core/log.h"

namespace commonlight::apps {

inline bool quiet() noexcept { return log::level() >= log::Level::kError; }

// printf to standard output, unless -q.
[[gnu::format(printf, 1, 2)]] inline void say(const char* format, ...) {
    if (quiet()) return;
    va_list args;
    va_start(args, format);
    std::vprintf(format, args);
    va_end(args);
}

// printf to standard error, unless -q.
[[gnu::format(printf, 1, 2)]] inline void sayErr(const char* format, ...) {
    if (quiet()) return;
    va_list args;
    va_start(args, format);
    std::vfprintf(stderr, format, args);
    va_end(args);
}

}  // namespace commonlight::apps
