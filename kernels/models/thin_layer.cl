// OpenCL entry point for the thin semi-transparent layer (kernels/models/thin_layer.h); no launch-uniform value.
#include "common/shim.h"
#include "common/eval_kernel.h"
#include "models/thin_layer.h"

#define TL_EVAL(mat, uniform, ix, iy, iz, ox, oy, oz, out) tl_eval(mat, ix, iy, iz, ox, oy, oz, out)
LL_DEFINE_EVAL_KERNEL(thin_layer_eval, TL_EVAL)
