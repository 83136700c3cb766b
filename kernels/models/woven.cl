// OpenCL entry points for the woven-cotton BRDF (the mean of its BTF over a pattern repeat) and its BTF.
#include "common/shim.h"
#include "common/eval_kernel.h"
#include "common/ellipse_window.h"
#include "models/woven.h"

// The BRDF needs no launch-uniform value.
#define WV_BRDF_EVAL(mat, uniform, ix, iy, iz, ox, oy, oz, out) wv_brdf(mat, ix, iy, iz, ox, oy, oz, out)
LL_DEFINE_EVAL_KERNEL(woven_brdf, WV_BRDF_EVAL)

// The BTF at each query's (u, v).
#define WV_BTF_EVAL(mat, uniform, ix, iy, iz, ox, oy, oz, u, v, out) wv_btf(mat, ix, iy, iz, ox, oy, oz, u, v, out)
LL_DEFINE_EVAL_UV_KERNEL(woven_btf, WV_BTF_EVAL)
