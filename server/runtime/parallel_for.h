// Host-side work spread over threads: the one helper for loops whose iterations are independent (yarn
// fibers, environment folds, host kernel chunks, the fiber pilot's passes).
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <functional>
#include <thread>
#include <vector>

namespace loomlight::runtime {

// Runs work(i) for every i in [0, count) on up to `threads` threads, the caller's among them. Each thread
// takes the next i as it comes free, so one slowed by another process does not hold back the rest; work(i)
// must write only its own results, so the outcome depends neither on the thread count nor on their timing.
// `cancelled` (may be empty) is asked before each i; returns false when it stopped the loop.
template <class Work>
bool ParallelFor(size_t count, int threads, const std::function<bool()>& cancelled, Work&& work) {
  std::atomic<size_t> next{0};
  std::atomic<bool> stop{false};
  const auto run = [&] {
    for (size_t i; !stop.load(std::memory_order_relaxed) && (i = next.fetch_add(1)) < count;) {
      if (cancelled && cancelled()) {
        stop = true;
        return;
      }
      work(i);
    }
  };
  const size_t workers = std::min<size_t>(size_t(std::max(threads, 1)), std::max<size_t>(count, 1));
  std::vector<std::thread> pool;
  for (size_t t = 1; t < workers; ++t) pool.emplace_back(run);
  run();
  for (std::thread& t : pool) t.join();
  return !stop;
}

}  // namespace loomlight::runtime
