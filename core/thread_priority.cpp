#include "core/thread_priority.h"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>

namespace commonlight {

namespace {

// setpriority(PRIO_PROCESS, tid) names one thread on Linux (the nice value is per thread).
id_t threadId() noexcept { return static_cast<id_t>(syscall(SYS_gettid)); }

}  // namespace

int currentThreadNice() noexcept {
    errno = 0;
    const int value = getpriority(PRIO_PROCESS, threadId());
    return errno == 0 ? value : 0;
}

bool setCurrentThreadNice(int nice) noexcept {
    return setpriority(PRIO_PROCESS, threadId(), std::clamp(nice, -20, 19)) == 0;
}

}  // namespace commonlight
