// The process's allocator kept from handing memory back to the kernel between calls. A render allocates its
// chunk buffers, queries and images afresh each call; glibc's defaults return large freed blocks (mmap above
// 128 KiB at first, heap tops past 128 KiB) to the kernel, so the next call takes a page fault for every page
// again: in a VM that cost a 256 x 256 twill render 0.43 s instead of 0.30 s (a fresh server against one
// whose thresholds glibc had raised on its own after larger renders).
#pragma once

#include <cstddef>

namespace loomlight::runtime {

// Blocks up to 32 MiB (glibc's largest mmap threshold) come from the heap, and a heap keeps up to
// `retained_bytes` of free memory at its top (M_TRIM_THRESHOLD, per arena) before trimming. Process-wide: call
// once at start-up, before threads allocate. Returns false when the allocator refused either setting.
bool KeepFreedMemory(size_t retained_bytes);

}  // namespace loomlight::runtime
