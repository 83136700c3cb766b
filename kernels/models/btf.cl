// OpenCL entry points for PCA-compressed BTF assets (kernels/models/btf.h): the tile's mean (the BRDF) and the
// BTF at each query's (u, v). The launch-uniform value is the number of components used.
#include "common/shim.h"
#include "common/eval_kernel.h"
#include "models/btf.h"

#define BT_BRDF_EVAL(mat, uniform, ix, iy, iz, ox, oy, oz, out) \
  bt_eval(mat, uniform, ix, iy, iz, ox, oy, oz, 0, R(0.0), R(0.0), out)
LL_DEFINE_EVAL_KERNEL(btf_brdf, BT_BRDF_EVAL)

#define BT_BTF_EVAL(mat, uniform, ix, iy, iz, ox, oy, oz, u, v, out) \
  bt_eval(mat, uniform, ix, iy, iz, ox, oy, oz, 1, u, v, out)
LL_DEFINE_EVAL_UV_KERNEL(btf_btf, BT_BTF_EVAL)
