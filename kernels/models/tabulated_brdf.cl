// OpenCL entry point for tabulated BRDFs (kernels/models/tabulated_brdf.h, server/models/tabulated_brdf.h): not
// a registered model (its materials are tables built from one), embedded through CMakeLists.txt's kernel list.
#include "common/shim.h"
#include "common/eval_kernel.h"
#include "models/tabulated_brdf.h"

LL_DEFINE_EVAL_KERNEL(tabulated_brdf_eval, tb_eval)
