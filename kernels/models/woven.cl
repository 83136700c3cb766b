// OpenCL entry point for the woven-cotton BRDF (the mean of its BTF over a pattern repeat).
#include "common/shim.h"
#include "common/eval_kernel.h"
#include "common/ellipse_window.h"
#include "models/woven.h"

// The BRDF needs no launch-uniform value.
#define WV_BRDF_EVAL(mat, uniform, ix, iy, iz, ox, oy, oz, out) wv_brdf(mat, ix, iy, iz, ox, oy, oz, out)
LL_DEFINE_EVAL_KERNEL(woven_brdf, WV_BRDF_EVAL)
