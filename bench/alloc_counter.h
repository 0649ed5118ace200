// Counts heap allocations of the whole process (every thread), for "allocations per frame".
// Linking commonlight_alloc_counter replaces the global operator new/delete of the binary.
#pragma once

#include <cstdint>

namespace commonlight::bench {

std::uint64_t allocationCount() noexcept;

}  // namespace commonlight::bench
