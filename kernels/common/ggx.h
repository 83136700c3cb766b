// GGX (Trowbridge-Reitz) microfacet terms shared by the standard lobes (kernels/models/gltf_sheen.h,
// kernels/models/openpbr.h). Include kernels/common/shim.h first. alpha2 = alpha^2 of the material.

// Smallest GGX alpha the standard lobes evaluate: alpha 0 is a mirror (D a delta, 0/0 at its peak); at 1e-4
// the peak 1 / (pi alpha^2) = 3.2e7 keeps f finite in float at every pair, grazing included.
#define LL_GGX_ALPHA_MIN 1e-4

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
