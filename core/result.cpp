#include "core/result.h"

namespace commonlight {

std::string_view errorCodeName(ErrorCode code) noexcept {
    switch (code) {
        case ErrorCode::kUsage: return "usage error";
        case ErrorCode::kBadInput: return "bad input";
        case ErrorCode::kNotFound: return "not found";
        case ErrorCode::kIo: return "I/O error";
        case ErrorCode::kDevice: return "device error";
        case ErrorCode::kUnsupported: return "unsupported";
        case ErrorCode::kTimeout: return "timeout";
        case ErrorCode::kCancelled: return "cancelled";
        case ErrorCode::kInternal: return "internal error";
    }
    return "unknown error";
}

int exitCodeFor(ErrorCode code) noexcept {
    switch (code) {
        case ErrorCode::kUsage:
        case ErrorCode::kUnsupported: return 2;
        case ErrorCode::kBadInput:
        case ErrorCode::kNotFound:
        case ErrorCode::kIo: return 3;
        case ErrorCode::kDevice:
        case ErrorCode::kTimeout: return 4;
        case ErrorCode::kCancelled: return 130;
        case ErrorCode::kInternal: return 1;
    }
    return 1;
}

Error& Error::prepend(std::string_view context) & {
    message.insert(0, std::string(context) + ": ");
    return *this;
}

Error&& Error::prepend(std::string_view context) && {
    message.insert(0, std::string(context) + ": ");
    return std::move(*this);
}

}  // namespace commonlight
