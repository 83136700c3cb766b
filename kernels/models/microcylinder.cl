// OpenCL entry point for the microcylinder model: one work-item per query, materials chosen per query.
// The host pads the query count to a multiple of the fixed local size, so no work-item branches out.
#include "common/shim.h"
#include "models/microcylinder.h"

__kernel __attribute__((reqd_work_group_size(LL_LOCAL_SIZE, 1, 1)))
void microcylinder_eval(__global const real* materials, const int material_stride, const int tangent_samples,
                        __global const int* material_index, __global const float* wi,
                        __global const float* wo, __global real* f) {
  const int q = get_global_id(0);
  __global const real* mat = materials + material_index[q] * material_stride;
  real out[3];
  mc_eval(mat, tangent_samples, wi[3 * q], wi[3 * q + 1], wi[3 * q + 2], wo[3 * q], wo[3 * q + 1],
          wo[3 * q + 2], out);
  f[3 * q] = out[0];
  f[3 * q + 1] = out[1];
  f[3 * q + 2] = out[2];
}
