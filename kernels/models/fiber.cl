// OpenCL entry points for fiber scattering (kernels/models/fiber.h). The launch-uniform value is the mode
// (FB_MODE_SIMPLE or FB_MODE_PHYSICAL): one branch per launch, not per lane.
#include "common/shim.h"
#include "common/eval_kernel.h"
#include "models/fiber.h"

LL_DEFINE_EVAL_KERNEL(fiber_eval, fb_eval)

// The ambient factor of Eq. 7 for each query's wo (wi is ignored), from the packed tables (Evaluate's
// QUANTITY_AMBIENT; the renderer's ambient term).
#define FB_AMBIENT_EVAL(mat, uniform, ix, iy, iz, ox, oy, oz, out) fb_ambient(mat, ox, oy, oz, out)
LL_DEFINE_EVAL_KERNEL(fiber_ambient, FB_AMBIENT_EVAL)
