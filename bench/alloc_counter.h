// Counts heap allocations of the whole process (every thread), for "allocations per frame".
// Linking alloc_counter.cpp replaces the global operator new/delete of the binary.
#pragma once

#include <cstdint>

namespace commonlight::bench {

std::uint64_t allocationCount() noexcept;

}  // namespace commonlight::bench
