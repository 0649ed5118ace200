// Checks shared by the option structs' validate(): the message names the struct and the field.
#pragma once

#include <cmath>
#include <sstream>
#include <string_view>

#include "core/result.h"

namespace commonlight::tracking {

// kUsage unless `value` is finite and > 0: "<owner>.<field> must be a finite number > 0, got v".
inline Result<void> requirePositive(double value, std::string_view owner, std::string_view field) {
    if (std::isfinite(value) && value > 0.0) return {};
    std::ostringstream msg;
    msg << owner << "." << field << " must be a finite number > 0, got " << value;
    return fail(ErrorCode::kUsage, msg.str());
}

}  // namespace commonlight::tracking
