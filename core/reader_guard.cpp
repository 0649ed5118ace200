#include "core/reader_guard.h"

#include <yaml-cpp/exceptions.h>

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <new>
#include <opencv2/core.hpp>
#include <string>

namespace commonlight {

Error readerExceptionError(std::string_view file) noexcept {
    std::string where(file);
    std::string what;
    try {
        throw;
    } catch (const YAML::Exception& e) {
        if (!e.mark.is_null()) where += ":" + std::to_string(e.mark.line + 1) + ":" + std::to_string(e.mark.column + 1);
        what = "YAML: " + e.msg;
    } catch (const cv::Exception& e) {
        what = "OpenCV: " + e.msg;
    } catch (const std::bad_alloc&) {
        what = "it asks for more memory than there is";
    } catch (const std::exception& e) {
        what = e.what();
    } catch (...) {
        what = "unknown exception";
    }
    std::string message = where + ": cannot be read: " + what;
#ifdef COMMONLIGHT_FUZZ_STRICT_READERS
    std::fprintf(stderr, "reader_guard: an exception reached a reader's border: %s\n", message.c_str());
    std::abort();
#endif
    return Error{ErrorCode::kBadInput, std::move(message)};
}

}  // namespace commonlight
