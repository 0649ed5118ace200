#include "core/file_util.h"

#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>
#include <utility>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace commonlight {

Error fileError(const std::filesystem::path& file, std::string_view what, int errno_value) {
    std::string msg = file.string();
    msg += ": ";
    msg += what;
    msg += ": ";
    msg += std::strerror(errno_value);
    return Error{errno_value == ENOENT ? ErrorCode::kNotFound : ErrorCode::kIo, std::move(msg)};
}

namespace {

// write(2) until done, retrying on EINTR.
bool writeAll(int fd, const std::uint8_t* data, std::size_t size) {
    while (size > 0) {
        const ssize_t n = ::write(fd, data, size);
        if (n < 0) {
            if (errno == EINTR) continue;
            return false;
        }
        data += n;
        size -= static_cast<std::size_t>(n);
    }
    return true;
}

}  // namespace

Result<void> readFileInto(const std::filesystem::path& file, std::vector<std::uint8_t>& out) {
    const int fd = ::open(file.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return fail(fileError(file, "cannot open", errno));
    struct stat st {};
    if (::fstat(fd, &st) != 0) {
        const int err = errno;
        ::close(fd);
        return fail(fileError(file, "cannot stat", err));
    }
    out.resize(static_cast<std::size_t>(st.st_size));
    std::size_t done = 0;
    while (done < out.size()) {
        const ssize_t n = ::read(fd, out.data() + done, out.size() - done);
        if (n < 0 && errno == EINTR) continue;
        if (n < 0) {
            const int err = errno;
            ::close(fd);
            return fail(fileError(file, "read failed", err));
        }
        if (n == 0) break;  // the file shrank while we read it
        done += static_cast<std::size_t>(n);
    }
    out.resize(done);
    ::close(fd);
    return {};
}

Result<std::string> readTextFile(const std::filesystem::path& file) {
    std::vector<std::uint8_t> bytes;
    CL_TRY_VOID(readFileInto(file, bytes));
    return std::string(bytes.begin(), bytes.end());
}

Result<void> writeFileAtomic(const std::filesystem::path& file, std::span<const std::uint8_t> bytes, bool sync) {
    std::string tmp_name = ".";  // built by appends: GCC 12 warns falsely (-Wrestrict) on "." + s
    tmp_name.append(file.filename().string()).append(".tmp");
    const std::filesystem::path tmp = file.parent_path() / tmp_name;
    const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) return fail(fileError(tmp, "cannot create", errno));
    if (!writeAll(fd, bytes.data(), bytes.size()) || (sync && ::fdatasync(fd) != 0)) {
        const int err = errno;
        ::close(fd);
        ::unlink(tmp.c_str());
        return fail(fileError(tmp, "write failed", err));
    }
    if (::close(fd) != 0) {
        const int err = errno;
        ::unlink(tmp.c_str());
        return fail(fileError(tmp, "close failed", err));
    }
    if (::rename(tmp.c_str(), file.c_str()) != 0) {
        const int err = errno;
        ::unlink(tmp.c_str());
        return fail(fileError(file, "rename failed", err));
    }
    return {};
}

Result<void> writeTextFileAtomic(const std::filesystem::path& file, std::string_view text, bool sync) {
    return writeFileAtomic(file, {reinterpret_cast<const std::uint8_t*>(text.data()), text.size()}, sync);
}

LineAppender::~LineAppender() { close(); }

LineAppender::LineAppender(LineAppender&& other) noexcept
    : fd_(std::exchange(other.fd_, -1)), path_(std::move(other.path_)) {}

LineAppender& LineAppender::operator=(LineAppender&& other) noexcept {
    if (this != &other) {
        close();
        fd_ = std::exchange(other.fd_, -1);
        path_ = std::move(other.path_);
    }
    return *this;
}

Result<LineAppender> LineAppender::open(const std::filesystem::path& file, std::string_view header) {
    LineAppender appender;
    appender.path_ = file;
    appender.fd_ = ::open(file.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
    if (appender.fd_ < 0) return fail(fileError(file, "cannot open for appending", errno));
    struct stat st {};
    if (::fstat(appender.fd_, &st) != 0) return fail(fileError(file, "cannot stat", errno));
    if (st.st_size == 0 && !header.empty()) CL_TRY_VOID(appender.append(header));
    return appender;
}

Result<void> LineAppender::append(std::string_view line) {
    if (fd_ < 0) return fail(ErrorCode::kIo, path_.string() + ": not open");
    // One write(2) for the whole line: O_APPEND makes it atomic with respect to other writers,
    // and a kill between lines never leaves half of one.
    const ssize_t n = ::write(fd_, line.data(), line.size());
    if (n < 0) return fail(fileError(path_, "append failed", errno));
    if (static_cast<std::size_t>(n) != line.size()) {
        // Short write (disk full): cut the partial line off again so the file stays parseable.
        struct stat st {};
        if (::fstat(fd_, &st) == 0) {
            if (::ftruncate(fd_, st.st_size - n) != 0) { /* the reader reports the partial line */ }
        }
        return fail(fileError(path_, "append failed", ENOSPC));
    }
    return {};
}

Result<void> LineAppender::sync() {
    if (fd_ >= 0 && ::fdatasync(fd_) != 0) return fail(fileError(path_, "fdatasync failed", errno));
    return {};
}

void LineAppender::close() noexcept {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
}

}  // namespace commonlight
