// GGX (Trowbridge-Reitz) microfacet terms and the pair's microfacet angles, shared by the standard lobes (kernels/models/gltf_sheen.h,
// kernels/models/openpbr.h). Include kernels/common/shim.h first. alpha2 = alpha^2 of the material.

// Smallest GGX alpha the standard lobes evaluate: alpha 0 is a mirror (D a delta, 0/0 at its peak); at 1e-4
// the peak 1 / (pi alpha^2) = 3.2e7 keeps f finite in float at every pair, grazing included.
#define LL_GGX_ALPHA_MIN 1e-4

// A material's GGX alpha from its roughness, alpha = roughness^2 floored at LL_GGX_ALPHA_MIN: what both standard
// lobes pack. Host side (packing).
#ifndef __OPENCL_C_VERSION__
LL_INLINE scalar ll_ggx_alpha(scalar roughness) { return LL_FMAX(roughness * roughness, LL_GGX_ALPHA_MIN); }
#endif

// D(h) = alpha^2 / (pi (cos^2 theta_h (alpha^2 - 1) + 1)^2), the bracket written sin^2 + alpha^2 cos^2 so that
// the peak survives alpha^2 below float's epsilon (1 + (alpha^2 - 1) rounds to 0 there).
LL_INLINE real ll_ggx_d(scalar alpha2, real cos2h, real sin2h) {
  const real b = sin2h + alpha2 * cos2h;
  return alpha2 / (LL_PI * b * b);
}

// Height-correlated Smith G2 / (4 mu_i mu_o), mu the cosines (> 0): glTF Appendix B's V_GGX,
// 0.5 / (mu_i sqrt(alpha^2 + (1 - alpha^2) mu_o^2) + mu_o sqrt(alpha^2 + (1 - alpha^2) mu_i^2)).
LL_INLINE real ll_ggx_visibility(scalar alpha2, real mu_i, real mu_o) {
  const real root_o = sqrt(alpha2 + (R(1.0) - alpha2) * mu_o * mu_o);
  const real root_i = sqrt(alpha2 + (R(1.0) - alpha2) * mu_i * mu_i);
  return R(0.5) / (mu_i * root_o + mu_o * root_i);
}

// The pair's cosines and half-vector angles, after renormalising wi and wo (within the API's unit tolerance):
// returns whether both lie above the horizon (by LL_HORIZON_EPS); on lanes that do not, the cosines are 1, so
// every division a lobe makes stays finite. *h2 = |wi + wo|^2 = 2 + 2 wi.wo, so V.H = sqrt(h2) / 2.
LL_INLINE mask ll_microfacet_pair(real* wix, real* wiy, real* wiz, real* wox, real* woy, real* woz, real* mu_i,
                                  real* mu_o, real* h2, real* sin2h, real* cos2h) {
  ll_normalize(wix, wiy, wiz);
  ll_normalize(wox, woy, woz);
  const mask live = *wiz > LL_HORIZON_EPS && *woz > LL_HORIZON_EPS;
  *mu_i = live ? *wiz : R(1.0);
  *mu_o = live ? *woz : R(1.0);
  const real hx = *wix + *wox, hy = *wiy + *woy, hz = *mu_i + *mu_o;
  *h2 = hx * hx + hy * hy + hz * hz;  // >= hz^2 > 0
  *sin2h = (hx * hx + hy * hy) / *h2;
  *cos2h = hz * hz / *h2;
  return live;
}

// A directional albedo tabulated at `nodes` cosines uniform in sqrt(mu) from mat[at], read linearly: the standard
// lobes' albedo slices (their packing interpolates them from tables over roughness).
LL_INLINE real ll_sqrt_mu_lookup(LL_GLOBAL const scalar* mat, int at, int nodes, real mu) {
  const real last = R(1.0) * (nodes - 1);
  const real t = sqrt(mu) * last;
  const real k = LL_FMIN(floor(t), last - R(1.0));
  const real u = t - k;
  const real index = R(1.0) * at + k;
  return (R(1.0) - u) * ll_gather(mat, index) + u * ll_gather(mat, index + R(1.0));
}
