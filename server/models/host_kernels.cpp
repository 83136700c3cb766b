#include "server/models/host_kernels.h"

#include <algorithm>
#include <atomic>
#include <thread>

namespace loomlight::models::host {
namespace {
// Hands out chunks of queries on demand, so a thread slowed by another process does not hold back the rest
// (fixed equal shares would halve the baseline whenever one core is busy elsewhere).
template <class Body>
void ParallelFor(size_t n, Body body) {
  constexpr size_t kChunk = 1024;
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t begin; (begin = next.fetch_add(kChunk)) < n;) body(begin, std::min(n, begin + kChunk));
  };
  std::vector<std::thread> threads;
  const size_t wanted = std::min<size_t>(std::max(1u, std::thread::hardware_concurrency()), (n + kChunk - 1) / kChunk);
  for (size_t t = 1; t < wanted; ++t) threads.emplace_back(work);
  work();
  for (auto& t : threads) t.join();
}
}  // namespace

const HostKernel* FindKernel(const std::string& name) {
  for (const HostKernel& k : AllKernels())
    if (name == k.name) return &k;
  return nullptr;
}

void RunReference(const HostKernel& kernel, const double* material, int uniform, const float* wi, const float* wo,
                  const float* uv, size_t n, double* f) {
  kernel.reference(material, uniform, wi, wo, uv, 0, n, f);
}

void RunNative(const HostKernel& kernel, const float* material, int uniform, const float* wi, const float* wo,
               const float* uv, size_t n, float* f) {
  ParallelFor(n, [&](size_t begin, size_t end) { kernel.native(material, uniform, wi, wo, uv, begin, end, f); });
}

}  // namespace loomlight::models::host
