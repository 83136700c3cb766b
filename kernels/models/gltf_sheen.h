// glTF 2.0 metallic-roughness material (Appendix B, metallic 0, ior 1.5) under KHR_materials_sheen's sheen
// (Conty and Kulla's "Charlie" distribution and visibility, albedo scaling), as pinned in docs/models.md
// "Standard lobes for export". Shared source: compiled as OpenCL C (gltf_sheen.cl) and as C++ (double
// reference, float baseline). Include kernels/common/shim.h and kernels/common/ggx.h first.
//
// Packed material, GS_PACKED_SIZE values:
//   [0..2]  base_color / pi (the diffuse lobe)
//   [3]     alpha_b^2, alpha_b = max(roughness^2, LL_GGX_ALPHA_MIN)
//   [4..6]  sheen_color
//   [7]     max3(sheen_color), the albedo scaling's weight
//   [8]     1 / alpha_s, alpha_s = max(sheen_roughness^2, GS_SHEEN_ALPHA_MIN)
//   [9..13] a, b, c, d, e of the visibility fit l(x) at alpha_s (gs_visibility_fit)
//   [14]    2 l(0.5)
//   [GS_ALBEDO_AT + k]  E(mu_k), the directional albedo of the Charlie lobe (sheen_color 1) at alpha_s,
//           mu_k = (k / (n - 1))^2, n = GS_ALBEDO_NODES (server/models/plugins/gltf_sheen.cpp tabulates it)
//
// With L = wi, V = wo, H their half vector (SPEC.md section 1; f without the cosine), per channel
//   f = sheen_color D_c V_c + (1 - max3(sheen_color) max(E(N.V), E(N.L))) ((1 - F) base_color / pi + F D_ggx V_ggx)
//   F = 0.04 + 0.96 (1 - V.H)^5, D_c = (2 + 1/alpha_s) sin(theta_h)^(1/alpha_s) / (2 pi),
//   V_c = 1 / ((1 + lambda(N.V) + lambda(N.L)) 4 N.V N.L), lambda the README's lambdaSheen.
// The min of the README's two scalings is written as one minus the larger albedo. Every term is symmetric in
// (L, V): f is reciprocal. f is 0 unless N.L and N.V exceed LL_HORIZON_EPS (a reflection-only lobe).

// The sheen's alpha floor: the README's visibility fit interpolates its two end fits by (1 - alpha)^2 over
// [0, 1], and below 0.005 (MaterialX's floor on the same Charlie alpha) its lobe is a sliver at grazing that a
// table in mu cannot resolve.
#define GS_SHEEN_ALPHA_MIN 0.005
#define GS_MATERIAL_SIZE 15
#define GS_ALBEDO_AT GS_MATERIAL_SIZE
// Nodes uniform in sqrt(mu): E changes fastest toward grazing (docs/models.md "Standard lobes for export").
#define GS_ALBEDO_NODES 33
#define GS_PACKED_SIZE (GS_MATERIAL_SIZE + GS_ALBEDO_NODES)

// log x for x > 0 without a library call (PoCL's builtin reads tables, like expf: see ll_exp_poly): x = m 2^e
// with m in [sqrt(1/2), sqrt(2)) from the bits, Cephes' logf polynomial in m - 1 (about 1 ulp). Inputs below
// 1e-30 read as 1e-30 (the bits of a normal float; callers select 0 for x = 0 themselves).
#if !(defined(__OPENCL_C_VERSION__) && defined(LL_FP64))
#ifdef __OPENCL_C_VERSION__
#define GS_INT mask  // int or intN: what comparing float reals gives
#if LL_WIDTH == 1
#define GS_FLOAT_BITS(x) as_int(x)
#define GS_INT_TO_REAL(i) convert_float(i)
#else
#define GS_FLOAT_BITS(x) LL_CAT(as_int, LL_WIDTH)(x)
#define GS_INT_TO_REAL(i) LL_CAT(convert_float, LL_WIDTH)(i)
#endif
#else
#define GS_INT int
#define GS_FLOAT_BITS(x) __builtin_bit_cast(int, static_cast<float>(x))
#define GS_INT_TO_REAL(i) real(i)
#endif
LL_INLINE real gs_log_poly(real x) {
  const real xc = LL_FMAX(x, R(1e-30));
  const GS_INT bits = GS_FLOAT_BITS(xc);
  const real m0 = LL_AS_FLOAT((bits & 0x007fffff) | 0x3f000000);  // in [0.5, 1)
  const real e0 = GS_INT_TO_REAL((bits >> 23) - 126);
  const mask below = m0 < R(0.70710678);
  const real e = below ? e0 - R(1.0) : e0;
  const real m = below ? m0 + m0 - R(1.0) : m0 - R(1.0);
  const real z = m * m;
  const real p = (((((((R(7.0376836292e-2) * m - R(1.1514610310e-1)) * m + R(1.1676998740e-1)) * m - R(1.2420140846e-1)) * m +
                     R(1.4249322787e-1)) * m - R(1.6668057665e-1)) * m + R(2.0000714765e-1)) * m - R(2.4999993993e-1)) * m +
                  R(3.3333331174e-1);
  const real y = p * m * z - R(2.12194440e-4) * e - R(0.5) * z;
  return (m + y) + R(0.693359375) * e;
}
#endif
#if defined(__OPENCL_C_VERSION__)
#ifdef LL_FP64
#define gs_log(x) log(LL_FMAX(x, R(1e-30)))
#else
#define gs_log gs_log_poly
#endif
#else
inline float gs_log(float x) { return gs_log_poly(x); }
inline double gs_log(double x) { return std::log(std::fmax(x, 1e-30)); }
#endif

// The README's coefficients of l(x, alpha) = a / (1 + b x^c) + d x + e, each interpolated between its fit at
// alpha = 1 and at alpha = 0 by (1 - alpha)^2; into fit[0..4], and 2 l(0.5) into fit[5]. Host side (packing).
#ifndef __OPENCL_C_VERSION__
LL_INLINE void gs_visibility_fit(scalar alpha, scalar* fit) {
  const scalar t = (1 - alpha) * (1 - alpha);
  const scalar at_one[5] = {21.5473, 3.82987, 0.19823, -1.97760, -4.32054};
  const scalar at_zero[5] = {25.3245, 3.32435, 0.16801, -1.27393, -4.85967};
  for (int k = 0; k < 5; ++k) fit[k] = at_one[k] + t * (at_zero[k] - at_one[k]);
  fit[5] = 2 * (fit[0] / (1 + fit[1] * std::pow(0.5, fit[2])) + fit[3] * 0.5 + fit[4]);
}
#endif

// lambdaSheen(mu) for mu in (0, 1]: exp(l(mu)) below 0.5, exp(2 l(0.5) - l(1 - mu)) above; fit as packed.
LL_INLINE real gs_lambda(LL_GLOBAL const scalar* fit, real mu) {
  const mask low = mu < R(0.5);
  const real x = low ? mu : R(1.0) - mu;
  const real x_to_c = x > R(0.0) ? ll_exp(fit[2] * gs_log(x)) : R(0.0);  // x = 0 at mu = 1
  const real l = fit[0] / (R(1.0) + fit[1] * x_to_c) + fit[3] * x + fit[4];
  return ll_exp(low ? l : fit[5] - l);
}

// The Charlie distribution D_c(h) from sin^2(theta_h): (2 + 1/alpha) (sin^2)^(1 / (2 alpha)) / (2 pi).
LL_INLINE real gs_charlie_d(scalar inv_alpha, real sin2h) {
  const real power = sin2h > R(0.0) ? ll_exp(R(0.5) * inv_alpha * gs_log(sin2h)) : R(0.0);  // 0 at h = n
  return (R(2.0) + inv_alpha) * power * (R(0.5) / LL_PI);
}

// The Charlie visibility V_c for cosines mu_i, mu_o > 0.
LL_INLINE real gs_charlie_visibility(LL_GLOBAL const scalar* fit, real mu_i, real mu_o) {
  return R(1.0) / ((R(1.0) + gs_lambda(fit, mu_o) + gs_lambda(fit, mu_i)) * (R(4.0) * mu_o * mu_i));
}

// E(mu) from the packed slice.
LL_INLINE real gs_albedo(LL_GLOBAL const scalar* mat, real mu) {
  return ll_sqrt_mu_lookup(mat, GS_ALBEDO_AT, GS_ALBEDO_NODES, mu);
}

// f(wi, wo) for one query (RGB into f[0..2]); the launch-uniform value is unused.
LL_INLINE void gs_eval(LL_GLOBAL const scalar* mat, int uniform, real wix, real wiy, real wiz, real wox, real woy,
                       real woz, real* f) {
  real mu_i, mu_o, h2, sin2h, cos2h;
  const mask live = ll_microfacet_pair(&wix, &wiy, &wiz, &wox, &woy, &woz, &mu_i, &mu_o, &h2, &sin2h, &cos2h);
  const real v_dot_h = R(0.5) * sqrt(h2);
  const real q = R(1.0) - v_dot_h, q2 = q * q;
  const real fresnel = R(0.04) + R(0.96) * (q2 * q2 * q);
  const real specular = fresnel * ll_ggx_d(mat[3], cos2h, sin2h) * ll_ggx_visibility(mat[3], mu_i, mu_o);
  const real sheen = gs_charlie_d(mat[8], sin2h) * gs_charlie_visibility(mat + 9, mu_i, mu_o);
  const real scaling = R(1.0) - mat[7] * LL_FMAX(gs_albedo(mat, mu_o), gs_albedo(mat, mu_i));
  for (int c = 0; c < 3; ++c) {
    const real value = mat[4 + c] * sheen + scaling * ((R(1.0) - fresnel) * mat[c] + specular);
    f[c] = live ? value : R(0.0);
  }
}
