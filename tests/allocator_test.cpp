// KeepFreedMemory (server/runtime/allocator.h): a call's buffers freed and allocated again by the next call must
// reuse the pages already mapped, not fault in fresh ones. Counted with the process's minor page faults.
#include "server/runtime/allocator.h"

#include <gtest/gtest.h>
#include <sys/resource.h>

#include <cstdlib>
#include <cstring>
#include <thread>
#include <vector>

namespace {

long MinorFaults() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_minflt;
}

// The page faults of one "call": its buffers (a render's chunk buffers are a few MiB each) allocated, written
// and freed, on a thread of its own as the server's workers do.
long FaultsOfOneCall() {
  long faults = 0;
  std::thread worker([&] {
    const long before = MinorFaults();
    std::vector<void*> blocks;
    for (size_t bytes : {size_t{6} << 20, size_t{3} << 20, size_t{12} << 20, size_t{1} << 20}) {
      void* p = std::malloc(bytes);
      ASSERT_NE(p, nullptr);
      std::memset(p, 1, bytes);
      blocks.push_back(p);
    }
    for (void* p : blocks) std::free(p);
    faults = MinorFaults() - before;
  });
  worker.join();
  return faults;
}

TEST(KeepFreedMemory, ACallsBuffersReuseThePreviousCallsPages) {
  // glibc's defaults first: the 22 MiB are mmapped and unmapped each time, about 5,600 faults a call.
  const long cold = FaultsOfOneCall();
  const long again = FaultsOfOneCall();
  EXPECT_GT(again, 2000) << "the default allocator already kept the pages (cold " << cold << ")";

  ASSERT_TRUE(loomlight::runtime::KeepFreedMemory(size_t{256} << 20));
  FaultsOfOneCall();  // maps the heap once
  long kept = 0;
  for (int call = 0; call < 3; ++call) kept += FaultsOfOneCall();
  std::printf("minor faults per call: default %ld, kept %ld over 3 calls\n", again, kept);
  // A thread's stack and the arena's bookkeeping fault a few pages; 22 MiB afresh would be 5,600.
  EXPECT_LT(kept, 300);
}

}  // namespace
