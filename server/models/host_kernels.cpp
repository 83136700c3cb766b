#include "server/models/host_kernels.h"

#include <algorithm>
#include <thread>

#include "server/runtime/parallel_for.h"

namespace loomlight::models::host {
namespace {
// Chunks of queries taken as threads come free (runtime::ParallelFor), on every hardware thread.
template <class Body>
void ParallelChunks(size_t n, Body body) {
  constexpr size_t kChunk = 1024;
  runtime::ParallelFor((n + kChunk - 1) / kChunk, int(std::max(1u, std::thread::hardware_concurrency())), {},
                       [&](size_t c) { body(c * kChunk, std::min(n, (c + 1) * kChunk)); });
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
  ParallelChunks(n, [&](size_t begin, size_t end) { kernel.native(material, uniform, wi, wo, uv, begin, end, f); });
}

}  // namespace loomlight::models::host
