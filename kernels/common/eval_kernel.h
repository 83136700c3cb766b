// The entry point every model kernel shares: each work-item evaluates LL_WIDTH consecutive queries ("lanes")
// of one material as explicit vectors. Directions, texture coordinates and results are planar (x of every
// lane, then y, then z; u then v; r, then g, then b); the host groups lanes by material and pads, so no
// work-item branches. A work-item's material starts at materials[group_offset[g]] (materials differ in size:
// a woven material carries its pattern).
// EVAL(mat, uniform, wix, wiy, wiz, wox, woy, woz, out) is the model's per-query function; a spatially
// varying model's BTF entry uses LL_DEFINE_EVAL_UV_KERNEL, whose EVAL also takes (u, v) after the directions.
// Both kernels have the same arguments; uv is a dummy buffer for the first kind.
// Compiled as C++ (the host builds, server/models/host_kernels.h), each entry becomes a loop over queries
// [begin, end) with interleaved arrays (xyz per query, uv pairs, RGB per query), listed by name through
// exported by name by the generated host sources (cmake/ModelList.cmake).
#ifdef __OPENCL_C_VERSION__
#define LL_EVAL_KERNEL_HEAD(NAME)                                                                          \
  __kernel __attribute__((reqd_work_group_size(LL_LOCAL_SIZE, 1, 1))) void NAME(                           \
      __global const scalar* materials, const int uniform, __global const int* group_offset,               \
      __global const float* wi, __global const float* wo, __global const float* uv, __global scalar* f,    \
      const int lanes)

#define LL_EVAL_KERNEL_BODY(CALL)                                                                          \
  {                                                                                                        \
    const int g = get_global_id(0);                                                                        \
    __global const scalar* mat = materials + group_offset[g];                                              \
    real out[3];                                                                                           \
    CALL;                                                                                                  \
    LL_STORE(out[0], g, f);                                                                                \
    LL_STORE(out[1], g, f + lanes);                                                                        \
    LL_STORE(out[2], g, f + 2 * lanes);                                                                    \
  }

#define LL_EVAL_DIRECTIONS                                                                                 \
  LL_LOAD(g, wi), LL_LOAD(g, wi + lanes), LL_LOAD(g, wi + 2 * lanes), LL_LOAD(g, wo), LL_LOAD(g, wo + lanes), \
      LL_LOAD(g, wo + 2 * lanes)

// Calls F with its arguments macro-expanded first (LL_EVAL_DIRECTIONS becomes six arguments).
#define LL_CALL(F, ...) F(__VA_ARGS__)

#define LL_DEFINE_EVAL_KERNEL(NAME, EVAL) \
  LL_EVAL_KERNEL_HEAD(NAME) LL_EVAL_KERNEL_BODY(LL_CALL(EVAL, mat, uniform, LL_EVAL_DIRECTIONS, out))

#define LL_DEFINE_EVAL_UV_KERNEL(NAME, EVAL) \
  LL_EVAL_KERNEL_HEAD(NAME)                  \
  LL_EVAL_KERNEL_BODY(LL_CALL(EVAL, mat, uniform, LL_EVAL_DIRECTIONS, LL_LOAD(g, uv), LL_LOAD(g, uv + lanes), out))
#else
#define LL_HOST_EVAL_LOOP(NAME, CALL)                                                                       \
  inline void NAME(const scalar* mat, int uniform, const float* wi, const float* wo, const float* uv,         \
                   size_t begin, size_t end, real* f) {                                                       \
    for (size_t q = begin; q < end; ++q) CALL;                                                                \
  }
#define LL_HOST_DIRECTIONS wi[3 * q], wi[3 * q + 1], wi[3 * q + 2], wo[3 * q], wo[3 * q + 1], wo[3 * q + 2]
#define LL_CALL(F, ...) F(__VA_ARGS__)
#define LL_DEFINE_EVAL_KERNEL(NAME, EVAL) \
  LL_HOST_EVAL_LOOP(NAME, LL_CALL(EVAL, mat, uniform, LL_HOST_DIRECTIONS, f + 3 * q))
#define LL_DEFINE_EVAL_UV_KERNEL(NAME, EVAL) \
  LL_HOST_EVAL_LOOP(NAME, LL_CALL(EVAL, mat, uniform, LL_HOST_DIRECTIONS, uv[2 * q], uv[2 * q + 1], f + 3 * q))
#endif
