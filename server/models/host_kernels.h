// Host builds of the models' kernels: the shared source in kernels/models compiled as C++, once with
// real = double (the reference: strict IEEE, no contraction, the yardstick every precision is measured
// against) and once with real = float (the native baseline: -O3 -march=native, spread over every core, what
// the benchmarks compare the OpenCL kernels with). Every entry a model's .cl defines (LL_DEFINE_EVAL_KERNEL,
// kernels/common/eval_kernel.h) is here under its name, generated from the model list (cmake/ModelList.cmake).
#pragma once

#include <cstddef>
#include <string>
#include <vector>

namespace loomlight::models::host {

// One kernel entry over queries [begin, end): directions xyz per query, uv pairs (entries that take them; may
// be null otherwise), f RGB per query.
template <class Real>
using KernelFn = void (*)(const Real* material, int uniform, const float* wi, const float* wo, const float* uv,
                          size_t begin, size_t end, Real* f);

struct HostKernel {
  const char* name;   // the OpenCL kernel's name
  const char* model;  // the model whose .cl defines it
  KernelFn<double> reference;
  KernelFn<float> native;
};

// Every model's entries (generated).
const std::vector<HostKernel>& AllKernels();
// The entry of that name, or nullptr.
const HostKernel* FindKernel(const std::string& name);

// The double reference for n queries, on the calling thread.
void RunReference(const HostKernel& kernel, const double* material, int uniform, const float* wi, const float* wo,
                  const float* uv, size_t n, double* f);
// The float native baseline for n queries, on every hardware thread.
void RunNative(const HostKernel& kernel, const float* material, int uniform, const float* wi, const float* wo,
               const float* uv, size_t n, float* f);

}  // namespace loomlight::models::host
