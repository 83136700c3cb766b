#include "bench/kernel_runs.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

namespace loomlight::bench {

std::vector<double> Reference(const Workload& w, size_t n, size_t threads) {
  n = std::min(n, w.pairs.size());
  std::vector<double> f(3 * n);
  const size_t chunk = (n + threads - 1) / threads;
  std::vector<std::thread> workers;
  for (size_t begin = 0; begin < n; begin += chunk) {
    const size_t count = std::min(chunk, n - begin);
    workers.emplace_back([&, begin, count] {
      w.model.ReferenceEval(w.material, &w.pairs.wi[3 * begin], &w.pairs.wo[3 * begin],
                            w.uv ? w.uv + 2 * begin : nullptr, count, &f[3 * begin]);
    });
  }
  for (auto& t : workers) t.join();
  return f;
}

void RunOpenCl(runtime::ClRuntime& rt, bool fp64, const Workload& w, std::vector<double>* f, double* kernel_seconds) {
  std::string error;
  if (!rt.RunSingle(w.model, w.material, fp64, w.pairs.wi.data(), w.pairs.wo.data(), w.uv, w.pairs.size(), f,
                    &error, models::Quantity::kScattering, kernel_seconds)) {
    std::fprintf(stderr, "OpenCL launch failed: %s\n", error.c_str());
    std::exit(1);
  }
}

void RunNative(const Workload& w, std::vector<float>* f) {
  f->resize(3 * w.pairs.size());
  w.model.NativeEval(w.material, w.pairs.wi.data(), w.pairs.wo.data(), w.uv, w.pairs.size(), f->data());
}

}  // namespace loomlight::bench
