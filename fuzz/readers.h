// The readers of user input that the fuzz harnesses drive (one harness per entry) and that
// tests/fuzz/replay_test.cpp replays the seed and regression corpora through.
//
// Each entry reads one file through the project's own reader, as a user's file would be read,
// and the contract every reader keeps on any bytes is checked by contractViolation(): it
// returns (never throws, never crashes), and a failure is an error value of the reader's
// bad-input code (kBadInput; kUsage for camera URIs) whose message names the file (the URI).
#pragma once

#include <filesystem>
#include <span>
#include <string>
#include <string_view>

#include "core/result.h"

namespace commonlight::fuzz {

struct Reader {
    std::string_view name;       // the harness: fuzz_<name>, corpus folders <name>/
    std::string_view extension;  // given to the file an input is written to (readers that go by it)
    ErrorCode bad_input_code;    // the code of every failure
    std::string_view what;       // one line for --help and messages
    // Reads `file`. A failure's message must name `file` (or, for camera URIs, the URI).
    Result<void> (*read)(const std::filesystem::path& file);
};

std::span<const Reader> readers();
const Reader* findReader(std::string_view name);

// Empty when `result` keeps the contract for `file`, else what is wrong with it.
std::string contractViolation(const Reader& reader, const std::filesystem::path& file, const Result<void>& result);

}  // namespace commonlight::fuzz
