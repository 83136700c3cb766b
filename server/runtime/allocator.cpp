#include "server/runtime/allocator.h"

#include <malloc.h>

#include <algorithm>
#include <climits>

namespace loomlight::runtime {

bool KeepFreedMemory(size_t retained_bytes) {
  constexpr int kMmapThreshold = 32 << 20;  // glibc's HEAP_MAX / 2 on 64-bit: larger values are refused
  const int trim = static_cast<int>(std::min<size_t>(retained_bytes, INT_MAX));
  // Setting either also stops glibc's own adjustment of both, so the behaviour does not depend on the history.
  const bool mmap_ok = mallopt(M_MMAP_THRESHOLD, kMmapThreshold) == 1;
  const bool trim_ok = mallopt(M_TRIM_THRESHOLD, std::max(trim, kMmapThreshold)) == 1;
  return mmap_ok && trim_ok;
}

}  // namespace loomlight::runtime
