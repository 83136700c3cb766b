// Microcylinder cloth BRDF of Sadeghi et al. 2012, exactly as pinned in SPEC.md section 2.
// Shared source: compiled as OpenCL C (microcylinder.cl) and as C++ (double reference, float baseline).
// Include kernels/common/shim.h first.
//
// Packed material (array of real), for T tangent samples per thread:
//   [0]              eta
//   [1 ...]          thread 1 (along x), then thread 2 (along y), each MC_THREAD_HEADER + 2n values:
//                    coverage a, albedo A (r, g, b), kd, gamma_s, gamma_v (radians), n,
//                    then n pairs count (cos alpha, sin alpha): the distinct sampled tangent offsets in arc-length
//                    order, each scaled by how many of the T samples it stands for (the counts sum to T).
// Equal samples (a flat stretch of the tangent curve: the satin's thread 2 entirely, a third of its thread 1)
// add equal terms to both sums of SPEC.md section 2's X, so each is evaluated once and weighed by its count;
// the count rides in the pair's length, so a material is never larger than with one pair per sample.

#define MC_THREAD_HEADER 8
#define MC_MAX_TANGENT_SAMPLES 256
// 1 / (2 sigma_u^2) with sigma_u = 20 degrees (Sec. 5.2): the masking and reweighting blend width.
#define MC_U_INV2S2 R(4.1035862571313326)

// A thread's values: its header and its n distinct tangents (n is the header's last value).
LL_INLINE int mc_thread_size(int n) { return MC_THREAD_HEADER + 2 * n; }

#ifndef __OPENCL_C_VERSION__
// Tangent offset (degrees) at arc length s on a piecewise-linear tangent curve: offsets[0..n-1] at the control
// points, lengths[0..n-2] between them; a zero-length segment is a jump. Used by the host to pack materials.
LL_INLINE real mc_curve_offset(const real* offsets, const real* lengths, int n, real s) {
  real start = R(0.0);
  for (int k = 0; k + 1 < n; ++k) {
    const real end = start + lengths[k];
    if (s < end && lengths[k] > R(0.0))
      return offsets[k] + (offsets[k + 1] - offsets[k]) * ((s - start) / lengths[k]);
    start = end;
  }
  return offsets[n - 1];
}
#endif

// Accumulates one thread's tangent samples for a query (its distinct ones, weighed by their counts).
// (ia, ib, iz) are wi's components along the thread's own axis, the other cloth axis and the normal
// (thread along x: (x, y, z); along y: (y, x, z)); likewise (oa, ob, oz) for wo. Adds sum P Q to
// *surf (achromatic surface part) and *vol (volume part, to be multiplied by A) and sum P to *psum.
// The loop body is branch-free (selects only, no library calls): no divergent paths per work-item.
LL_INLINE void mc_accumulate_thread(LL_GLOBAL const scalar* thread, scalar eta,
                                    real ia, real ib, real iz, real oa, real ob, real oz,
                                    real* surf, real* vol, real* psum) {
  const scalar kd = thread[4];
  const real inv_gamma_s = R(1.0) / thread[5];
  const real inv_gamma_v = R(1.0) / thread[6];
  const int distinct = (int)thread[7];
  LL_GLOBAL const scalar* tangents = thread + MC_THREAD_HEADER;

  // (w.t, w.nt) is (wa, wz) rotated by the tangent offset, so its length and psi_i - psi_r do not depend
  // on the tangent: computed once here. P > 0 needs wi.nt > 0 and wo.nt > 0, hence |psi| < 90 degrees and
  // psi_i - psi_r as one atan2 of the cross and dot products has no wrap-around where it is used.
  const real li = sqrt(ia * ia + iz * iz), lr = sqrt(oa * oa + oz * oz);
  const real inv_li = li > R(0.0) ? R(1.0) / li : R(0.0), inv_lr = lr > R(0.0) ? R(1.0) / lr : R(0.0);
  const real psi_d = ll_atan2(ia * oz - iz * oa, iz * oz + ia * oa);
  const real u_psi = ll_unit_gaussian(MC_U_INV2S2, psi_d);

  real s_surf = R(0.0), s_vol = R(0.0), s_p = R(0.0);
  for (int m = 0; m < distinct; ++m) {  // the same for every query of a work-item (one material)
    // Per material, not per lane: the count is the pair's length (a whole number), the tangent its direction.
    const scalar sc = tangents[2 * m], ss = tangents[2 * m + 1];
    const scalar count = floor(sqrt(sc * sc + ss * ss) + (scalar)0.5);
    const scalar ca = sc / count, sa = ss / count;
    // t = (ca, 0, sa), nt = (-sa, 0, ca), b = the other cloth axis, in the thread's (a, b, z) frame.
    const real si = ia * ca + iz * sa, ni = iz * ca - ia * sa, bi = ib;
    const real sr = oa * ca + oz * sa, nr = oz * ca - oa * sa, br = ob;

    // Reweighting (Sec. 5.3).
    const real pi_ = LL_FMAX(ni, R(0.0)) * inv_li, pr_ = LL_FMAX(nr, R(0.0)) * inv_lr;
    const real ci = sqrt(ni * ni + bi * bi), cr = sqrt(nr * nr + br * br);  // cos theta = |w_p|
    const real cc = ci * cr;
    const mask live = pi_ > R(0.0) && pr_ > R(0.0) && cc > R(0.0);  // then every division below is finite
    const real p = live ? (R(1.0) - u_psi) * pi_ * pr_ + u_psi * LL_FMIN(pi_, pr_) : R(0.0);

    // Masking (Sec. 5.2): cos phi_w = (w.nt) / |w_p|, positive here.
    const real mi = ni / ci, mr = nr / cr;
    const real dot_p = ni * nr + bi * br, cross_p = ni * br - bi * nr;  // of wi_p and wo_p
    const real phi_d = ll_atan2(fabs(cross_p), dot_p);
    const real u_phi = ll_unit_gaussian(MC_U_INV2S2, phi_d);
    const real mask = (R(1.0) - u_phi) * mi * mr + u_phi * LL_FMIN(mi, mr);
    // 2 cos^2(phi_d/2) = 1 + cos phi_d = (cc + dot_p) / cc; for dot_p < 0 the numerator is rewritten as
    // cross_p^2 / (cc - dot_p) (Lagrange: cc^2 = dot_p^2 + cross_p^2), which has no cancellation as phi_d -> pi.
    const real one_plus_cos_phi = (dot_p >= R(0.0) ? cc + dot_p : cross_p * cross_p / (cc - dot_p)) / cc;
    const real cos_half_phi_d = sqrt(R(0.5) * one_plus_cos_phi);

    // theta_i + theta_r from one atan2 of the sum formulas (cos theta >= 0 keeps it in [-pi, pi]).
    const real theta_h = R(0.5) * ll_atan2(si * cr + ci * sr, cc - si * sr);
    // 2 cos^2(theta_d) = 1 + cos(theta_i - theta_r) = 1 + si sr + ci cr; when si sr < 0 the 1 + si sr part
    // is rewritten as ci^2/(1+|si|) + |si| cr^2/(1+|sr|), which has no cancellation as theta_d -> 90 degrees.
    const real asi = fabs(si), asr = fabs(sr);
    const real one_plus_sisr =
        si * sr >= R(0.0) ? R(1.0) + si * sr : ci * ci / (R(1.0) + asi) + asi * cr * cr / (R(1.0) + asr);
    const real cos2_d = R(0.5) * (one_plus_sisr + cc);
    const real cos_d = sqrt(cos2_d);

    // Thread scattering (Sec. 4.3), divided by cos^2(theta_d) below.
    const real f_rs = ll_fresnel_dielectric(eta, cos_d * cos_half_phi_d) * cos_half_phi_d *
                      ll_gaussian(inv_gamma_s, theta_h);
    const real ft = (R(1.0) - ll_fresnel_dielectric(eta, ci)) * (R(1.0) - ll_fresnel_dielectric(eta, cr));
    const real f_rv = ft * ((R(1.0) - kd) * ll_gaussian(inv_gamma_v, theta_h) + kd) / (ci + cr);

    // P Q = P f_s M cos(theta_i), with f_s = (f_rs + f_rv A) / cos^2(theta_d). Dead lanes may hold NaN
    // (0/0 above), so they are selected out rather than multiplied by 0.
    const real w = count * p * mask * ci / cos2_d;
    s_surf += live ? w * f_rs : R(0.0);
    s_vol += live ? w * f_rv : R(0.0);
    s_p += count * p;
  }
  *surf = s_surf;
  *vol = s_vol;
  *psum = s_p;
}

// f(wi, wo) for one query (RGB into f[0..2]). wi, wo are renormalised here: the API accepts directions
// within its unit tolerance, and the model's projections assume exactly unit vectors. T (the launch's uniform)
// is in the material already: its tangents' counts.
LL_INLINE void mc_eval(LL_GLOBAL const scalar* mat, int T, real wix, real wiy, real wiz, real wox, real woy,
                       real woz, real* f) {
  ll_normalize(&wix, &wiy, &wiz);
  ll_normalize(&wox, &woy, &woz);
  const scalar eta = mat[0];
  LL_GLOBAL const scalar* t1 = mat + 1;
  LL_GLOBAL const scalar* t2 = t1 + mc_thread_size((int)t1[MC_THREAD_HEADER - 1]);
  real surf1, vol1, p1, surf2, vol2, p2;
  mc_accumulate_thread(t1, eta, wix, wiy, wiz, wox, woy, woz, &surf1, &vol1, &p1);
  mc_accumulate_thread(t2, eta, wiy, wix, wiz, woy, wox, woz, &surf2, &vol2, &p2);
  const scalar a1 = t1[0], a2 = t2[0];
  const real denom = a1 * p1 + a2 * p2;
  const mask lit = wiz > LL_HORIZON_EPS && woz > LL_HORIZON_EPS && denom > R(0.0);
  // X = (a1 + a2) sum_j a_j sum P Q / sum_j a_j sum P, and f = X / (n.wi); the weighted mean is taken
  // first so that a tiny sum of P cannot overflow before it cancels.
  const real inv_denom = lit ? R(1.0) / denom : R(0.0);
  const real scale = lit ? (a1 + a2) / wiz : R(0.0);
  for (int c = 0; c < 3; ++c)
    f[c] = scale * ((a1 * (surf1 + vol1 * t1[1 + c]) + a2 * (surf2 + vol2 * t2[1 + c])) * inv_denom);
}
