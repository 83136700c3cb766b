// OpenCL entry point for OpenPBR Surface's dielectric base under fuzz (kernels/models/openpbr.h); no
// launch-uniform value.
#include "common/shim.h"
#include "common/eval_kernel.h"
#include "common/ggx.h"
#include "models/openpbr.h"

LL_DEFINE_EVAL_KERNEL(openpbr_eval, op_eval)
