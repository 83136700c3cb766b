// OpenCL entry point for the thin semi-transparent layer (kernels/models/thin_layer.h); the launch-uniform value
// is the scattering mode (TL_SCATTERING_SINGLE or TL_SCATTERING_ALL).
#include "common/shim.h"
#include "common/eval_kernel.h"
#include "models/thin_layer.h"

LL_DEFINE_EVAL_KERNEL(thin_layer_eval, tl_eval_scattering)

// The direct (unscattered) transmittance exp(-tau / |n.wo|) toward each query's wo, in every channel (wi is
// ignored): how much of what lies behind the layer is seen through it.
#define TL_TRANSMITTANCE_EVAL(mat, uniform, ix, iy, iz, ox, oy, oz, out) \
  (out)[0] = (out)[1] = (out)[2] = tl_transmittance(mat, ox, oy, oz)
LL_DEFINE_EVAL_KERNEL(thin_layer_transmittance, TL_TRANSMITTANCE_EVAL)
