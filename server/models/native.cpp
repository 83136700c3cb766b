// The native float baseline: the shared model source compiled as C++ with real = float, -O3 -march=native,
// the queries split over every hardware thread. Benchmarks compare the OpenCL kernels against it.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <thread>
#include <vector>

#include "server/models/host_models.h"

namespace loomlight::native {
namespace device {
typedef float real;
#include "common/shim.h"
#include "models/microcylinder.h"
#include "common/ellipse_window.h"
#include "models/woven.h"
#include "models/thin_layer.h"
#include "models/fiber.h"
#include "server/models/host_queries.h"
}  // namespace device

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
  for (unsigned t = 1; t < std::max(1u, std::thread::hardware_concurrency()); ++t) threads.emplace_back(work);
  work();
  for (auto& t : threads) t.join();
}
}  // namespace

void MicrocylinderEval(const float* material, int tangent_samples, const float* wi, const float* wo, size_t n,
                       float* f) {
  ParallelFor(n, [&](size_t begin, size_t end) { device::mc_queries(material, tangent_samples, wi, wo, begin, end, f); });
}
void WovenEval(const float* material, const float* wi, const float* wo, const float* uv, size_t n, float* f) {
  ParallelFor(n, [&](size_t begin, size_t end) { device::wv_queries(material, wi, wo, uv, begin, end, f); });
}
void ThinLayerEval(const float* material, int scattering, const float* wi, const float* wo, size_t n, float* f) {
  ParallelFor(n, [&](size_t begin, size_t end) { device::tl_queries(material, scattering, wi, wo, begin, end, f); });
}
void FiberEval(const float* material, int mode, const float* wi, const float* wo, size_t n, float* f) {
  ParallelFor(n, [&](size_t begin, size_t end) { device::fb_queries(material, mode, wi, wo, begin, end, f); });
}
}  // namespace loomlight::native
