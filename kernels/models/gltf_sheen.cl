// OpenCL entry point for the glTF metallic-roughness material with KHR_materials_sheen
// (kernels/models/gltf_sheen.h); no launch-uniform value.
#include "common/shim.h"
#include "common/eval_kernel.h"
#include "common/ggx.h"
#include "models/gltf_sheen.h"

LL_DEFINE_EVAL_KERNEL(gltf_sheen_eval, gs_eval)
