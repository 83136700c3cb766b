// Per-model loops over queries [begin, end) for the host builds of the shared model source: reference.cpp
// (real = double, the whole range) and native.cpp (real = float, chunks on every core) include this inside
// their `device` namespace, after the model headers, so each loop is written once. No include guard, like
// the model headers it follows.

inline void mc_queries(const scalar* m, int tangent_samples, const float* wi, const float* wo, size_t begin,
                       size_t end, real* f) {
  for (size_t q = begin; q < end; ++q)
    mc_eval(m, tangent_samples, wi[3 * q], wi[3 * q + 1], wi[3 * q + 2], wo[3 * q], wo[3 * q + 1], wo[3 * q + 2],
            f + 3 * q);
}

// With uv (pairs) the BTF, with uv = nullptr the BRDF.
inline void wv_queries(const scalar* m, const float* wi, const float* wo, const float* uv, size_t begin, size_t end,
                       real* f) {
  for (size_t q = begin; q < end; ++q) {
    const float* a = wi + 3 * q;
    const float* b = wo + 3 * q;
    if (uv)
      wv_btf(m, a[0], a[1], a[2], b[0], b[1], b[2], uv[2 * q], uv[2 * q + 1], f + 3 * q);
    else
      wv_brdf(m, a[0], a[1], a[2], b[0], b[1], b[2], f + 3 * q);
  }
}

inline void tl_queries(const scalar* m, int scattering, const float* wi, const float* wo, size_t begin, size_t end,
                       real* f) {
  for (size_t q = begin; q < end; ++q)
    tl_eval_scattering(m, scattering, wi[3 * q], wi[3 * q + 1], wi[3 * q + 2], wo[3 * q], wo[3 * q + 1],
                       wo[3 * q + 2], f + 3 * q);
}

inline void fb_queries(const scalar* m, int mode, const float* wi, const float* wo, size_t begin, size_t end,
                       real* f) {
  for (size_t q = begin; q < end; ++q)
    fb_eval(m, mode, wi[3 * q], wi[3 * q + 1], wi[3 * q + 2], wo[3 * q], wo[3 * q + 1], wo[3 * q + 2], f + 3 * q);
}
