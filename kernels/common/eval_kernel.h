// The entry point every model kernel shares: each work-item evaluates LL_WIDTH consecutive queries ("lanes")
// of one material as explicit vectors. Directions and results are planar (x of every lane, then y, then z;
// r, then g, then b); the host groups lanes by material and pads, so no work-item branches.
// EVAL(mat, uniform, wix, wiy, wiz, wox, woy, woz, out) is the model's per-query function.
#define LL_DEFINE_EVAL_KERNEL(NAME, EVAL)                                                                    \
  __kernel __attribute__((reqd_work_group_size(LL_LOCAL_SIZE, 1, 1))) void NAME(                           \
      __global const scalar* materials, const int material_stride, const int uniform,                      \
      __global const int* group_material, __global const float* wi, __global const float* wo,              \
      __global scalar* f, const int lanes) {                                                               \
    const int g = get_global_id(0);                                                                        \
    __global const scalar* mat = materials + group_material[g] * material_stride;                          \
    real out[3];                                                                                           \
    EVAL(mat, uniform, LL_LOAD(g, wi), LL_LOAD(g, wi + lanes), LL_LOAD(g, wi + 2 * lanes), LL_LOAD(g, wo), \
         LL_LOAD(g, wo + lanes), LL_LOAD(g, wo + 2 * lanes), out);                                         \
    LL_STORE(out[0], g, f);                                                                                \
    LL_STORE(out[1], g, f + lanes);                                                                        \
    LL_STORE(out[2], g, f + 2 * lanes);                                                                    \
  }
