// The border of every reader of user input: the libraries behind them (yaml-cpp, tinygltf,
// tinyobjloader, OpenCV) and the standard library may throw on bad bytes; no exception leaves a
// reader. A reader's body runs inside guardReader(), which turns an exception into an error value
// naming the file (kBadInput). The readers check what they read before the libraries can throw,
// so that their errors also name the key; the guard is the net under them. In the fuzz build
// (COMMONLIGHT_FUZZ_STRICT_READERS) an exception reaching the net aborts instead, so that the
// fuzzer reports every place where a reader relied on it.
#pragma once

#include <filesystem>
#include <string_view>
#include <utility>

#include "core/result.h"

namespace commonlight {

// The error for the exception being handled (call inside a catch block): kBadInput,
// "<file>[:line:column]: cannot be read: <what>".
Error readerExceptionError(std::string_view file) noexcept;

template <typename F>
auto guardReader(const std::filesystem::path& file, F&& body) -> decltype(std::forward<F>(body)()) {
    try {
        return std::forward<F>(body)();
    } catch (...) {
        return fail(readerExceptionError(file.native()));
    }
}

}  // namespace commonlight
