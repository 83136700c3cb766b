// OpenCL entry point for the woven-cotton BRDF (the mean of its BTF over a pattern repeat). Same layout and
// signature as the other model kernels: LL_WIDTH queries of one material per work-item, planar directions.
#include "common/shim.h"
#include "common/ellipse_window.h"
#include "models/woven.h"

__kernel __attribute__((reqd_work_group_size(LL_LOCAL_SIZE, 1, 1)))
void woven_brdf(__global const scalar* materials, const int material_stride, const int uniform,
                __global const int* group_material, __global const float* wi, __global const float* wo,
                __global scalar* f, const int lanes) {
  const int g = get_global_id(0);
  __global const scalar* mat = materials + group_material[g] * material_stride;
  real out[3];
  wv_brdf(mat, LL_LOAD(g, wi), LL_LOAD(g, wi + lanes), LL_LOAD(g, wi + 2 * lanes), LL_LOAD(g, wo),
          LL_LOAD(g, wo + lanes), LL_LOAD(g, wo + 2 * lanes), out);
  LL_STORE(out[0], g, f);
  LL_STORE(out[1], g, f + lanes);
  LL_STORE(out[2], g, f + 2 * lanes);
}
