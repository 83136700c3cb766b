// Fiber scattering of Wu and Yuksel Sec. 4.3, exactly as pinned in SPEC.md section 5. Shared source:
// compiled as OpenCL C (fiber.cl) and as C++ (double reference, float baseline). Include
// kernels/common/shim.h first.
//
// Fiber frame: axis t; for a direction w, theta = asin(w.t) and phi its azimuth around t. Two models,
// chosen by the launch-uniform value (the `mode` parameter: the paths differ, so a launch runs one):
//   FB_MODE_SIMPLE (Eq. 5):  f = ks cos(phi/2) exp(-theta_h^2 / (2 beta^2)) + f_d,
//                            phi = phi_o - phi_i in [-pi, pi], theta_h = (theta_i + theta_o) / 2;
//   FB_MODE_PHYSICAL (Eq. 6, R + TT):
//     f = Fs M(theta_o; -theta_i, beta_R) / (2 pi) + C_TT (1 - Fs) M(theta_o; -theta_i, beta_TT) N_TT(phi) + f_d,
//     Fs = C_R + (1 - C_R)(1 - cos theta_i)^5, M(theta; m, s) = g(s, theta - m) / G(m, s),
//     G(m, s) = int_{-pi/2}^{pi/2} cos^2(theta) g(s, theta - m) dtheta,
//     N_TT(phi) = exp(-kappa (1 + cos phi)) / (2 pi i0e(kappa)), kappa = gamma_TT^-2 (the von Mises density in
//     phi - pi: 2 sin^2((phi - pi)/2) = 1 + cos phi).
// Both add f_d = (kd / pi) max(0, u.wi) / cos(theta_i) where u.wo > 0: a Lambertian surface with the fiber's
// surface normal u (the shading normal +z made perpendicular to t), written in the fiber convention
// L_o = int f L_i cos(theta_i) dw_i of SPEC.md section 5 (so f_d cos(theta_i) = kd/pi (u.wi)).
//
// G without integrals in the kernel: G(m, s) is even in m, and with c = cos m
//   G = G_inf(c) rho(delta),  G_inf = A + B c^2,  A = -expm1(-2 s^2) / 2,  B = exp(-2 s^2),
// where G_inf is the integral over the whole line (closed form) and rho = G / G_inf <= 1 corrects for the
// truncation at +-pi/2. rho differs from 1 only within a few s of the ends, so it is tabulated (by the host, at
// packing) over delta = pi/2 - |m| in [0, D], D = min(pi/2, 12 s), FB_RHO_N intervals, and is 1 beyond D.
// Ambient term (Eqs. 7-10): the integral of f cos(theta_i) dw_i over the sphere depends on theta_o only (the
// azimuthal integrals are 1 for N_R = 1/(2 pi) and for the normalised N_TT, and 4 for cos(phi/2)), is even in
// theta_o, and is tabulated per channel by the host over |theta_o| in [0, pi/2] (FB_AMB_N intervals); the
// Lambertian part adds kd where u.wo > 0.
//
// Packed material (array of scalar), FB_MATERIAL_SIZE values:
#define FB_T 0          // [0..2]   fiber axis t (unit)
#define FB_U 3          // [3..5]   fiber surface normal u (unit, perpendicular to t)
#define FB_V 6          // [6..8]   t x u
#define FB_KD 9         // [9..11]  kd / pi (RGB)
#define FB_KS 12        // [12..14] ks (RGB), simple model
#define FB_INV_2B2 15   // [15]     1 / (2 beta^2), simple model
#define FB_CR 16        // [16..18] C_R (RGB)
#define FB_CTT 19       // [19..21] C_TT (RGB)
#define FB_KAPPA 22     // [22]     kappa = gamma_TT^-2
#define FB_VM_NORM 23   // [23]     1 / (2 pi i0e(kappa))
#define FB_LOBE_R 24    // [24..27] R lobe: 1 / beta_R, A, B, FB_RHO_N / D
#define FB_LOBE_TT 28   // [28..31] TT lobe: the same for beta_TT
#define FB_AMB_SCALE 32 // [32]     FB_AMB_N / (pi / 2)
#define FB_HEADER 33    // then rho_R, rho_TT (FB_RHO_N + 1 each), ambient r, g, b (FB_AMB_N + 1 each)
#define FB_RHO_N 1024
#define FB_AMB_N 1024
#define FB_RHO_R FB_HEADER
#define FB_RHO_TT (FB_RHO_R + FB_RHO_N + 1)
#define FB_AMB (FB_RHO_TT + FB_RHO_N + 1)
#define FB_MATERIAL_SIZE (FB_AMB + 3 * (FB_AMB_N + 1))
#define FB_MODE_SIMPLE 0
#define FB_MODE_PHYSICAL 1

// Linear interpolation in table[0..last] at x (in table intervals), clamped to the table's ends.
LL_INLINE real fb_table(LL_GLOBAL const scalar* table, scalar last, real x) {
  const real xc = LL_FMIN(LL_FMAX(x, R(0.0)), last);
  const real i = LL_FMIN(floor(xc), last - R(1.0));
  const real lo = ll_gather(table, i), hi = ll_gather(table, i + R(1.0));
  return lo + (xc - i) * (hi - lo);
}

// A direction in the fiber frame, not renormalised: s = w.t, (p, q) = (w.u, w.v), c = |w - (w.t) t| (from the
// perpendicular components, accurate also as theta -> 90 degrees); sin(theta) = s |w|^-1, cos(theta) = c |w|^-1.
// Every angle below is a ratio of these (atan2 of homogeneous arguments), so it is computed from them
// directly: renormalising would round each component once more before the cancellations at the lobe peaks.
LL_INLINE void fb_local(LL_GLOBAL const scalar* mat, real x, real y, real z, real* s, real* c, real* p, real* q) {
  *s = x * mat[FB_T] + y * mat[FB_T + 1] + z * mat[FB_T + 2];
  *p = x * mat[FB_U] + y * mat[FB_U + 1] + z * mat[FB_U + 2];
  *q = x * mat[FB_V] + y * mat[FB_V + 1] + z * mat[FB_V + 2];
  *c = sqrt(*p * *p + *q * *q);
}

// 1 + cos(phi_o - phi_i) from the perpendicular components: (cc + dot) / cc, and for dot < 0 (phi -> pi, the
// peak of the TT lobe) cross^2 / ((cc - dot) cc) (Lagrange: cc^2 = dot^2 + cross^2), which has no cancellation
// there, so kappa (1 + cos phi) keeps its relative accuracy for kappa up to 1e4. 1 when either direction lies
// along the axis (phi undefined there; any finite value does, the lobes' measure vanishes).
LL_INLINE real fb_one_plus_cos_phi(real pi_, real qi, real ci, real po, real qo, real co) {
  const real cc = ci * co;
  // cross -> 0 at the TT peak, where the two products cancel: one fma-compensated difference keeps it exact.
  const real dot = pi_ * po + qi * qo, cross = ll_diff_of_products(pi_, qo, qi, po);
  const mask defined = cc > R(0.0);
  const real safe_cc = defined ? cc : R(1.0);
  const real v = (dot >= R(0.0) ? safe_cc + dot : cross * cross / (safe_cc - dot)) / safe_cc;
  return defined ? v : R(1.0);
}

// The normalised longitudinal lobe M(theta_o; -theta_i, s) of one lobe (FB_LOBE_R or FB_LOBE_TT), given
// theta_i + theta_o, cos(theta_i) and delta_i = pi/2 - |theta_i|.
LL_INLINE real fb_lobe(LL_GLOBAL const scalar* mat, int lobe, LL_GLOBAL const scalar* rho, real theta_sum, real ci,
                       real delta_i) {
  const scalar inv_s = mat[lobe], a = mat[lobe + 1], b = mat[lobe + 2], rho_scale = mat[lobe + 3];
  // A + B c^2 with A = -expm1(-2 s^2)/2 packed: no cancellation of 1 - exp(-2 s^2) for narrow lobes.
  const real g_norm = (a + b * ci * ci) * fb_table(rho, (scalar)FB_RHO_N, delta_i * rho_scale);
  return ll_gaussian(inv_s, theta_sum) / g_norm;
}

// f(wi, wo) for one query (RGB into f[0..2]); mode is the launch-uniform value.
LL_INLINE void fb_eval(LL_GLOBAL const scalar* mat, int mode, real wix, real wiy, real wiz, real wox, real woy,
                       real woz, real* f) {
  real si, ci, pi_, qi, so, co, po, qo;
  fb_local(mat, wix, wiy, wiz, &si, &ci, &pi_, &qi);
  fb_local(mat, wox, woy, woz, &so, &co, &po, &qo);
  const real inv_len_i = R(1.0) / sqrt(wix * wix + wiy * wiy + wiz * wiz);
  // theta_i + theta_o from one atan2 of the sum formulas, whose sine part cancels at the specular cone
  // theta_o = -theta_i (the lobe peaks): computed as an fma-compensated difference of products.
  const real theta_sum = ll_atan2(ll_diff_of_products(si, co, -ci, so), ci * co - si * so);
  const real one_plus_cos_phi = fb_one_plus_cos_phi(pi_, qi, ci, po, qo, co);
  // Lambertian on u: (u.wi) / cos(theta_i) <= 1; 0/0 only when wi is along t, where u.wi = 0 too.
  const real lambert = po > R(0.0) && pi_ > R(0.0) && ci > R(0.0) ? pi_ / LL_FMAX(ci, pi_) : R(0.0);
  if (mode == FB_MODE_SIMPLE) {
    const real cos_half_phi = sqrt(R(0.5) * one_plus_cos_phi);
    const real spec = cos_half_phi * ll_exp(-theta_sum * theta_sum * (R(0.25) * mat[FB_INV_2B2]));
    for (int c = 0; c < 3; ++c) f[c] = mat[FB_KS + c] * spec + mat[FB_KD + c] * lambert;
    return;
  }
  const real delta_i = ll_atan2(ci, fabs(si));
  const real sin_i = si * inv_len_i, cos_i = ci * inv_len_i;
  const real m_r = fb_lobe(mat, FB_LOBE_R, mat + FB_RHO_R, theta_sum, cos_i, delta_i);
  const real m_tt = fb_lobe(mat, FB_LOBE_TT, mat + FB_RHO_TT, theta_sum, cos_i, delta_i);
  const real n_tt = mat[FB_VM_NORM] * ll_exp(-mat[FB_KAPPA] * one_plus_cos_phi);
  // x = 1 - cos(theta_i) as sin^2 / (1 + cos): no cancellation near normal incidence; and
  // 1 - x^5 = cos(theta_i) (1 + x + x^2 + x^3 + x^4): no cancellation as theta_i -> 90 degrees.
  const real x = sin_i * sin_i / (R(1.0) + cos_i);
  const real x2 = x * x;
  const real x5 = x2 * x2 * x;
  const real one_minus_x5 = cos_i * (R(1.0) + x + x2 + x2 * x + x2 * x2);
  for (int c = 0; c < 3; ++c) {
    const scalar cr = mat[FB_CR + c];
    const real fs = cr + (R(1.0) - cr) * x5;
    const real one_minus_fs = (R(1.0) - cr) * one_minus_x5;
    f[c] = fs * m_r * (R(0.5) / LL_PI) + mat[FB_CTT + c] * one_minus_fs * m_tt * n_tt + mat[FB_KD + c] * lambert;
  }
}

// Ambient factor of Eq. 7: the integral of f(wi, wo) cos(theta_i) dw_i over the sphere (RGB into a[0..2]),
// from the packed tables; wo only.
LL_INLINE void fb_ambient(LL_GLOBAL const scalar* mat, real wox, real woy, real woz, real* a) {
  real so, co, po, qo;
  fb_local(mat, wox, woy, woz, &so, &co, &po, &qo);
  const real x = ll_atan2(fabs(so), co) * mat[FB_AMB_SCALE];
  const real lit = po > R(0.0) ? LL_PI : R(0.0);  // the Lambertian part: (kd / pi) pi
  for (int c = 0; c < 3; ++c)
    a[c] = fb_table(mat + FB_AMB + c * (FB_AMB_N + 1), (scalar)FB_AMB_N, x) + mat[FB_KD + c] * lit;
}

#ifndef __OPENCL_C_VERSION__
// Host only (packing): the exponentially scaled Bessel function i0e(k) = exp(-k) I0(k), k >= 0, in double
// without ever forming I0 (which overflows double for k > 713): the power series times exp(-k) up to k = 20
// (positive terms, no cancellation), the asymptotic series 1/sqrt(2 pi k) sum a_j / k^j beyond (its smallest
// term, near j = 2k, is ~exp(-2k) < 1e-17).
inline double fb_i0e(double k) {
  if (k <= 20.0) {
    const double h2 = 0.25 * k * k;
    double term = 1.0, sum = 1.0;
    for (int j = 1; j < 200 && term > 1e-18 * sum; ++j) {
      term *= h2 / (double(j) * j);
      sum += term;
    }
    return sum * std::exp(-k);
  }
  double term = 1.0, sum = 1.0;
  for (int j = 1; j < 40; ++j) {
    term *= (2.0 * j - 1) * (2.0 * j - 1) / (8.0 * j * k);
    sum += term;
    if (term < 1e-18 * sum) break;
  }
  return sum / std::sqrt(2.0 * 3.14159265358979323846 * k);
}
#endif
