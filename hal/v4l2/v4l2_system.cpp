#include "hal/v4l2/v4l2_system.h"

#include <fcntl.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>

namespace commonlight::hal::v4l2 {

namespace {

class LibcSystem final : public System {
public:
    int open(const char* path, int flags) override { return ::open(path, flags); }
    int close(int fd) override { return ::close(fd); }
    int ioctl(int fd, unsigned long request, void* arg) override { return ::ioctl(fd, request, arg); }
    void* mmap(void* addr, std::size_t length, int prot, int flags, int fd, off_t offset) override {
        return ::mmap(addr, length, prot, flags, fd, offset);
    }
    int munmap(void* addr, std::size_t length) override { return ::munmap(addr, length); }
    int poll(pollfd* fds, nfds_t count, int timeout_ms) override { return ::poll(fds, count, timeout_ms); }
};

}  // namespace

System& realSystem() {
    static LibcSystem system;
    return system;
}

int xioctl(System& system, int fd, unsigned long request, void* arg) {
    int result = 0;
    do {
        result = system.ioctl(fd, request, arg);
    } while (result == -1 && errno == EINTR);
    return result;
}

}  // namespace commonlight::hal::v4l2
