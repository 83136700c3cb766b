// OpenPBR Surface 1.1 as MaterialX's open_pbr_surface evaluates it, reduced to a dielectric base under fuzz
// (base_weight 1, metalness 0, base_diffuse_roughness 0, specular_weight 1, specular_color 1; no coat,
// transmission, subsurface or thin film), as pinned in docs/models.md "Standard lobes for export". Shared source:
// compiled as OpenCL C (openpbr.cl) and as C++ (double reference, float baseline). Include
// kernels/common/shim.h and kernels/common/ggx.h first.
//
// Packed material, OP_PACKED_SIZE values:
//   [0..2]  base_color / pi
//   [3]     alpha^2, alpha = max(specular_roughness^2, LL_GGX_ALPHA_MIN)
//   [4]     specular_ior (eta)
//   [5..7]  fuzz_weight * fuzz_color
//   [8]     fuzz_weight
//   [9]     y = clamp(fuzz_roughness, 0.01, 1), the range of Zeltner et al.'s fits
//   [10..12] 1 / s, m, o of the fuzz albedo's Gaussian fit at y (op_fuzz_albedo_fit)
//   [OP_ALBEDO_AT + k]  E_spec(mu_k), the directional albedo of the specular lobe at (alpha, eta),
//           mu_k = (k / (n - 1))^2, n = OP_ALBEDO_NODES (server/models/plugins/openpbr.cpp tabulates it)
//
// With L = wi, V = wo, H their half vector (SPEC.md section 1; f without the cosine), per channel
//   f = f_fuzz + (1 - fuzz_weight R(N.V)) (f_spec + (1 - E_spec(N.V)) base_color / pi)
//   f_spec = F(V.H) D_ggx G2 / (4 N.L N.V), F the exact dielectric Fresnel at eta
//   f_fuzz N.L = fuzz_weight fuzz_color R(N.V) D_ltc(L), D_ltc Zeltner et al.'s LTC (MaterialX's
//   mx_zeltner_sheen_brdf) in the frame whose x axis is V's projection onto the surface, R its albedo fit.
// Not reciprocal: the LTC and both albedo scalings depend on V. f is 0 unless N.L and N.V exceed
// LL_HORIZON_EPS (a reflection-only lobe).

#define OP_FUZZ_ROUGHNESS_MIN 0.01
#define OP_MATERIAL_SIZE 13
#define OP_ALBEDO_AT OP_MATERIAL_SIZE
#define OP_ALBEDO_NODES 33
#define OP_PACKED_SIZE (OP_MATERIAL_SIZE + OP_ALBEDO_NODES)

// Zeltner et al.'s albedo of the LTC sheen, R(x, y) = g(s, x - m) + o, g the unit-area Gaussian of width s:
// 1 / s, m, o at roughness y into fit[0..2]. Host side (packing).
#ifndef __OPENCL_C_VERSION__
LL_INLINE void op_fuzz_albedo_fit(scalar y, scalar* fit) {
  const scalar s = y * (0.0206607 + 1.58491 * y) / (0.0379424 + y * (1.32227 + y));
  fit[0] = 1 / s;
  fit[1] = y * (-0.193854 + y * (-1.14885 + y * (1.7932 - 0.95943 * y * y))) / (0.046391 + y);
  fit[2] = y * (0.000654023 + (-0.0207818 + 0.119681 * y) * y) / (1.26264 + y * (-1.92021 + y));
}
#endif

// R(N.V) from the packed fit, within [0, 1] as an albedo is (the fit strays below 0 by up to 2e-5 for
// smooth fuzz at grazing view).
LL_INLINE real op_fuzz_albedo(LL_GLOBAL const scalar* mat, real mu_o) {
  const real r = ll_gaussian(R(1.0) * mat[10], mu_o - mat[11]) + mat[12];
  return LL_FMIN(LL_FMAX(r, R(0.0)), R(1.0));
}

// E_spec(mu) from the packed slice.
LL_INLINE real op_specular_albedo(LL_GLOBAL const scalar* mat, real mu) {
  return ll_sqrt_mu_lookup(mat, OP_ALBEDO_AT, OP_ALBEDO_NODES, mu);
}

// Zeltner et al.'s rational fits (MaterialX's mx_zeltner_sheen_ltc_aInv, _bInv) of the inverse LTC matrix's
// entries at view cosine x and roughness y.
LL_INLINE real op_ltc_a_inv(scalar y, real x) {
  return (R(2.58126) * x + R(0.813703) * y) * y / (R(1.0) + R(0.310327) * x * x + R(2.60994) * x * y);
}
LL_INLINE real op_ltc_b_inv(scalar y, real x) {
  return sqrt(LL_FMAX(R(1.0) - x, R(0.0))) * (y - R(1.0)) * y * y * y /
         (R(0.0000254053) + R(1.71228) * x - R(1.71506) * x * y + R(1.34174) * y * y);
}

// D_ltc(L) / N.L for the fuzz at roughness y: with w = L in the frame (X, n x X, n), X = V's projection on the
// surface, normalised (any X at normal view, where the fits make the lobe round: bInv = 0),
// D_ltc = max(w'.z, 0) / pi (aInv / |w'|^2)^2, w' = (aInv w.x + bInv w.z, aInv w.y, w.z); w'.z = N.L cancels.
LL_INLINE real op_fuzz_lobe(scalar y, real wix, real wiy, real wiz, real wox, real woy, real mu_o) {
  const real len2 = wox * wox + woy * woy;
  const mask tilted = len2 > R(1e-24);
  const real inv_len = R(1.0) / sqrt(tilted ? len2 : R(1.0));
  const real xx = tilted ? wox * inv_len : R(1.0), xy = tilted ? woy * inv_len : R(0.0);
  const real wx = wix * xx + wiy * xy, wy = wiy * xx - wix * xy;
  const real a_inv = op_ltc_a_inv(y, mu_o), b_inv = op_ltc_b_inv(y, mu_o);
  const real px = a_inv * wx + b_inv * wiz, py = a_inv * wy;
  const real w2 = px * px + py * py + wiz * wiz;
  const real q = a_inv / w2;
  return q * q / LL_PI;
}

// f(wi, wo) for one query (RGB into f[0..2]); the launch-uniform value is unused.
LL_INLINE void op_eval(LL_GLOBAL const scalar* mat, int uniform, real wix, real wiy, real wiz, real wox, real woy,
                       real woz, real* f) {
  real mu_i, mu_o, h2, sin2h, cos2h;
  const mask live = ll_microfacet_pair(&wix, &wiy, &wiz, &wox, &woy, &woz, &mu_i, &mu_o, &h2, &sin2h, &cos2h);
  const real fresnel = ll_fresnel_dielectric(mat[4], LL_FMIN(R(0.5) * sqrt(h2), R(1.0)));  // V.H = |wi + wo| / 2
  const real specular = fresnel * ll_ggx_d(mat[3], cos2h, sin2h) * ll_ggx_visibility(mat[3], mu_i, mu_o);
  const real diffuse_share = R(1.0) - op_specular_albedo(mat, mu_o);
  const real fuzz_albedo = op_fuzz_albedo(mat, mu_o);
  const real fuzz = fuzz_albedo * op_fuzz_lobe(mat[9], wix, wiy, mu_i, wox, woy, mu_o);
  const real base_share = R(1.0) - mat[8] * fuzz_albedo;
  for (int c = 0; c < 3; ++c) {
    const real value = mat[5 + c] * fuzz + base_share * (specular + diffuse_share * mat[c]);
    f[c] = live ? value : R(0.0);
  }
}
