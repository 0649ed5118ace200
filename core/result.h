// Result<T>: the value of a runtime operation that can fail, or an Error saying why.
//
// Runtime failures (a missing file, a malformed key, a camera that went away) are values;
// contract violations (calling start() on a closed camera) are assertions. Every Error carries
// a message that names the file, key, line or device at fault.
#pragma once

#include <expected>
#include <string>
#include <string_view>
#include <utility>

namespace commonlight {

enum class ErrorCode {
    kUsage,        // bad command line or camera URI (exit 2)
    kBadInput,     // malformed or inconsistent file contents (exit 3)
    kNotFound,     // a named file or device does not exist (exit 3)
    kIo,           // reading or writing failed: permissions, disk full (exit 3)
    kDevice,       // a camera failed or disconnected (exit 4)
    kUnsupported,  // valid request the backend cannot do (exit 2)
    kTimeout,      // nothing arrived in time (exit 4)
    kCancelled,    // stopped on request
    kInternal,     // a bug or a library failure we did not expect (exit 1)
};

std::string_view errorCodeName(ErrorCode code) noexcept;

// The process exit code for an error, following docs/cli.md: 2 usage, 3 bad input, 4 device.
int exitCodeFor(ErrorCode code) noexcept;

struct Error {
    ErrorCode code = ErrorCode::kInternal;
    std::string message;

    // Prefixes the message with context ("reading SEQ/cam0/data.csv: ...").
    Error& prepend(std::string_view context) &;
    Error&& prepend(std::string_view context) &&;
};

template <typename T>
using Result = std::expected<T, Error>;

// Builds the unexpected value for a failed Result: `return fail(ErrorCode::kBadInput, msg);`
inline std::unexpected<Error> fail(ErrorCode code, std::string message) {
    return std::unexpected<Error>(Error{code, std::move(message)});
}
inline std::unexpected<Error> fail(Error error) { return std::unexpected<Error>(std::move(error)); }

}  // namespace commonlight

// Propagates an error: CL_TRY(auto value, expression); or CL_TRY_VOID(expression);
// CL_TRY expands to several statements: brace the body of an if/for that uses it (an unbraced
// use fails to compile).
#define CL_CONCAT_INNER(a, b) a##b
#define CL_CONCAT(a, b) CL_CONCAT_INNER(a, b)
#define CL_TRY_IMPL(tmp, decl, expr)                                        \
    auto tmp = (expr);                                                      \
    if (!tmp) return ::commonlight::fail(std::move(tmp).error());           \
    decl = std::move(*tmp)
#define CL_TRY(decl, expr) CL_TRY_IMPL(CL_CONCAT(cl_try_, __LINE__), decl, expr)
#define CL_TRY_VOID(expr)                                                   \
    do {                                                                    \
        auto cl_try_void_ = (expr);                                         \
        if (!cl_try_void_) return ::commonlight::fail(std::move(cl_try_void_).error()); \
    } while (false)
