// Small file helpers with errors that name the file.
#pragma once

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/result.h"

namespace commonlight {

// Reads a whole file into `out` (its capacity is reused).
Result<void> readFileInto(const std::filesystem::path& file, std::vector<std::uint8_t>& out);
Result<std::string> readTextFile(const std::filesystem::path& file);

// Writes `bytes` to "<dir>/.<name>.tmp", flushes it to disk (fdatasync when `sync`), then renames
// it to `file`: readers see either the old file, nothing, or the whole new file.
Result<void> writeFileAtomic(const std::filesystem::path& file, std::span<const std::uint8_t> bytes,
                             bool sync = true);
Result<void> writeTextFileAtomic(const std::filesystem::path& file, std::string_view text, bool sync = true);

// An error for a failed system call on a file: "<file>: <what>: <strerror(errno_value)>", with
// code kNotFound for ENOENT and kIo otherwise.
Error fileError(const std::filesystem::path& file, std::string_view what, int errno_value);

// Appends whole lines to a file with one write(2) each (O_APPEND), so a crash never leaves half
// a line. Not copyable; closes on destruction.
class LineAppender {
public:
    LineAppender() = default;
    ~LineAppender();
    LineAppender(LineAppender&& other) noexcept;
    LineAppender& operator=(LineAppender&& other) noexcept;
    LineAppender(const LineAppender&) = delete;
    LineAppender& operator=(const LineAppender&) = delete;

    // Opens (creating if needed) for appending. When the file is new or empty, `header` is written.
    static Result<LineAppender> open(const std::filesystem::path& file, std::string_view header);
    // Appends `line` (which must end with '\n').
    Result<void> append(std::string_view line);
    Result<void> sync();
    void close() noexcept;
    bool isOpen() const noexcept { return fd_ >= 0; }
    const std::filesystem::path& path() const noexcept { return path_; }

private:
    int fd_ = -1;
    std::filesystem::path path_;
};

}  // namespace commonlight
