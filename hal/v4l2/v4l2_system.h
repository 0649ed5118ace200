// The system calls the V4L2 backend makes, behind one small interface (the "seam"), so that unit
// tests drive the backend against a fake device (mocks/fake_v4l2_device.h) and the real backend
// calls libc (through which PipeWire's libpw-v4l2.so can intercept them when preloaded).
//
// Every function behaves like its libc namesake: -1 (MAP_FAILED for mmap) with errno set on
// failure. Implementations must be callable from several threads at once (the control thread sets
// controls while the camera thread dequeues buffers).
#pragma once

#include <poll.h>
#include <sys/types.h>

#include <cstddef>

namespace commonlight::hal::v4l2 {

class System {
public:
    virtual ~System() = default;
    virtual int open(const char* path, int flags) = 0;
    virtual int close(int fd) = 0;
    virtual int ioctl(int fd, unsigned long request, void* arg) = 0;
    virtual void* mmap(void* addr, std::size_t length, int prot, int flags, int fd, off_t offset) = 0;
    virtual int munmap(void* addr, std::size_t length) = 0;
    virtual int poll(pollfd* fds, nfds_t count, int timeout_ms) = 0;
};

// The libc implementation (one per process).
System& realSystem();

// ioctl() retried while it fails with EINTR.
int xioctl(System& system, int fd, unsigned long request, void* arg);

}  // namespace commonlight::hal::v4l2
