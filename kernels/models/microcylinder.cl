// OpenCL entry point for the microcylinder model; the launch-uniform value is the tangent sample count.
#include "common/shim.h"
#include "common/eval_kernel.h"
#include "models/microcylinder.h"

LL_DEFINE_EVAL_KERNEL(microcylinder_eval, mc_eval)
