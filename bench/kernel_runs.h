// One model's material on direction pairs through each implementation (OpenCL fp32 / fp64, the native float
// baseline, the double reference), shared by the kernel sections (kernel_bench.cpp) and the BTF section.
#pragma once

#include <cstddef>
#include <vector>

#include "bench/stats.h"
#include "server/models/registry.h"
#include "server/runtime/cl_runtime.h"

namespace loomlight::bench {

// What one measurement evaluates: a model's material on direction pairs, with texture positions for a BTF.
struct Workload {
  const models::Model& model;
  const models::PackedMaterial& material;
  const Pairs& pairs;
  const float* uv = nullptr;  // a (u, v) per pair, or nullptr for f(wi, wo)
};

// The double reference for the first n pairs, split into contiguous chunks over `threads` threads.
std::vector<double> Reference(const Workload& w, size_t n, size_t threads);

// The OpenCL kernel over all pairs in one launch; f receives 3 values per pair. Exits on a failed launch.
void RunOpenCl(runtime::ClRuntime& rt, bool fp64, const Workload& w, std::vector<double>* f,
               double* kernel_seconds = nullptr);

// The native float baseline over all pairs (all hardware threads).
void RunNative(const Workload& w, std::vector<float>* f);

}  // namespace loomlight::bench
