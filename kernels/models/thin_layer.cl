// OpenCL entry point for the thin semi-transparent layer (kernels/models/thin_layer.h); the launch-uniform value
// is the scattering mode (TL_SCATTERING_SINGLE or TL_SCATTERING_ALL).
#include "common/shim.h"
#include "common/eval_kernel.h"
#include "models/thin_layer.h"

LL_DEFINE_EVAL_KERNEL(thin_layer_eval, tl_eval_scattering)
