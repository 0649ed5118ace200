// A thread's scheduling priority (Linux nice values, which apply per thread): the threads whose
// lag is acceptable (the lighting thread, measurements against ground truth) yield the CPU to the
// ones that hold the frame rate (tracking, compositing) when both want it.
#pragma once

namespace commonlight {

// The calling thread's nice value (0 when it cannot be read).
int currentThreadNice() noexcept;
// Sets the calling thread's nice value, clamped to [-20, 19]. False when the system refused:
// raising a nice value is always allowed, lowering it again needs CAP_SYS_NICE or RLIMIT_NICE.
bool setCurrentThreadNice(int nice) noexcept;

}  // namespace commonlight
