// Embree's traversal wants denormals flushed (its start-up check warns that "Flush to Zero" and "Denormals
// are Zero" off "can have a severe performance impact"). The renderer's own double arithmetic keeps IEEE
// denormals, so the modes are set only for the span of an Embree query and restored after it.
#pragma once

#include <xmmintrin.h>

namespace loomlight::yarn {

class FlushDenormalsScope {
 public:
  FlushDenormalsScope() : saved_(_mm_getcsr()) { _mm_setcsr(saved_ | kFlushToZero | kDenormalsAreZero); }
  ~FlushDenormalsScope() { _mm_setcsr(saved_); }
  FlushDenormalsScope(const FlushDenormalsScope&) = delete;
  FlushDenormalsScope& operator=(const FlushDenormalsScope&) = delete;

 private:
  static constexpr unsigned kFlushToZero = 0x8000;      // MXCSR bit 15
  static constexpr unsigned kDenormalsAreZero = 0x0040;  // MXCSR bit 6
  unsigned saved_;
};

}  // namespace loomlight::yarn
