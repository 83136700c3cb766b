// The native float baseline: the shared model source compiled as C++ with real = float, -O3 -march=native,
// the queries split over every hardware thread. Benchmarks compare the OpenCL kernels against it.
#include <algorithm>
#include <cmath>
#include <thread>
#include <vector>

#include "server/models/host_models.h"

namespace loomlight::native {
namespace device {
typedef float real;
#include "common/shim.h"
#include "models/microcylinder.h"
}  // namespace device

namespace {
template <class Body>
void ParallelFor(size_t n, Body body) {
  const size_t workers = std::max(1u, std::thread::hardware_concurrency());
  const size_t chunk = (n + workers - 1) / workers;
  std::vector<std::thread> threads;
  for (size_t begin = 0; begin < n; begin += chunk)
    threads.emplace_back([=] { body(begin, std::min(n, begin + chunk)); });
  for (auto& t : threads) t.join();
}
}  // namespace

void MicrocylinderEval(const float* material, int tangent_samples, const float* wi, const float* wo, size_t n,
                       float* f) {
  ParallelFor(n, [&](size_t begin, size_t end) {
    for (size_t q = begin; q < end; ++q)
      device::mc_eval(material, tangent_samples, wi[3 * q], wi[3 * q + 1], wi[3 * q + 2], wo[3 * q],
                      wo[3 * q + 1], wo[3 * q + 2], f + 3 * q);
  });
}
}  // namespace loomlight::native
