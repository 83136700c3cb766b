// A material's BRDF tabulated from its analytic model (server/models/tabulated_brdf.h): a 4D grid read with
// quadrilinear interpolation. Shared source: compiled as OpenCL C (tabulated_brdf.cl) and as C++ (the host's
// Evaluate, double arithmetic on the float table). Include kernels/common/shim.h first.
//
// Coordinates of a pair, in the cloth frame (threads along x and y):
//   h = (wi + wo) / |wi + wo|, as eta_x = atan2(h.x, h.z) and eta_y = atan2(h.y, h.z), each in [-90, 90] degrees.
//     A thread along x with tangent t = (cos a, 0, sin a) has its specular peak where h.t = 0, which is exactly
//     eta_x = -a whatever else the pair is (and along y likewise eta_y = -a): every thread's lobe is a grid line,
//     narrow across it and smooth along it.
//   wi = cos(chi) sin(psi) E + sin(chi) P + cos(chi) cos(psi) h, in the frame of h with E in the plane of h and the
//     normal (E = (h.z e, -|h_xy|), e = h_xy / |h_xy|, (1, 0) at the normal) and P = (-e.y, e.x, 0); wo is wi
//     mirrored about h. Then n.wi = cos(chi) cos(psi + theta_h) and n.wo = cos(chi) cos(psi - theta_h): both above
//     the surface exactly for |psi| < 90 - theta_h and |chi| < 90 degrees, a rectangle once psi is taken relative
//     to its range. The axes are s = psi / (90 - theta_h) and c = chi / 90, each warped to
//     t = sign(s) (1 - sqrt(1 - |s|)): f (n.wi) grows like sqrt(n.w) from the horizon, linear in t.
// Nodes are uniform on each axis from its -1 (eta: -90 degrees) to its +1 (90), ends included.
//
// Packed material: TB_HEADER_SIZE values, then the nodes:
//   [0] nodes along eta_x  [1] along eta_y  [2] along psi  [3] along chi  [4..7] 0
//   node (i, j, k, l) at TB_HEADER_SIZE + 3 * (((i * n1 + j) * n2 + k) * n3 + l): X = f (n.wi), RGB.
// f = X / (n.wi) for wi and wo above the surface, else 0.
#define TB_HEADER_SIZE 8

// The host reads its float table in double arithmetic; a kernel reads the material in its own precision.
#ifdef __OPENCL_C_VERSION__
typedef scalar tb_stored;
#else
typedef float tb_stored;
#endif

// Node indices per lane, as integers (a float holds whole numbers only up to 2^24, fewer than a table's values).
#if defined(__OPENCL_C_VERSION__) && LL_WIDTH > 1 && defined(LL_FP64)
typedef LL_CAT(long, LL_WIDTH) tb_index;
#define TB_TO_INDEX(x) LL_CAT(convert_long, LL_WIDTH)(x)
#elif defined(__OPENCL_C_VERSION__) && LL_WIDTH > 1
typedef LL_CAT(int, LL_WIDTH) tb_index;
#define TB_TO_INDEX(x) LL_CAT(convert_int, LL_WIDTH)(x)
#else
typedef int tb_index;
#define TB_TO_INDEX(x) ((int)(x))
#endif

// The lower node along an axis of n >= 2 nodes at grid coordinate x (clamped to the axis), and the weight of the
// upper one.
LL_INLINE tb_index tb_axis(real x, scalar n, real* t) {
  const real xc = LL_FMIN(LL_FMAX(x, R(0.0)), (real)(n - (scalar)1));
  const real lower = LL_FMIN(floor(xc), (real)(n - (scalar)2));
  *t = xc - lower;
  return TB_TO_INDEX(lower);
}

// The three values at node index `at` (the node's first value) of every lane. OpenCL C has no vector gather: each
// lane's loads are made into a vector literal from the index vector's components (an array in private memory in
// between would cost a failed store-to-load forward per vector); the arithmetic around stays vectors.
#if defined(__OPENCL_C_VERSION__) && LL_WIDTH > 1
#if LL_WIDTH == 2
#define TB_VECTOR_OF(p, at, c) ((real)(p[(at).s0 + c], p[(at).s1 + c]))
#elif LL_WIDTH == 4
#define TB_VECTOR_OF(p, at, c) ((real)(p[(at).s0 + c], p[(at).s1 + c], p[(at).s2 + c], p[(at).s3 + c]))
#elif LL_WIDTH == 8
#define TB_VECTOR_OF(p, at, c)                                                                               \
  ((real)(p[(at).s0 + c], p[(at).s1 + c], p[(at).s2 + c], p[(at).s3 + c], p[(at).s4 + c], p[(at).s5 + c], \
          p[(at).s6 + c], p[(at).s7 + c]))
#elif LL_WIDTH == 16
#define TB_VECTOR_OF(p, at, c)                                                                               \
  ((real)(p[(at).s0 + c], p[(at).s1 + c], p[(at).s2 + c], p[(at).s3 + c], p[(at).s4 + c], p[(at).s5 + c], \
          p[(at).s6 + c], p[(at).s7 + c], p[(at).s8 + c], p[(at).s9 + c], p[(at).sa + c], p[(at).sb + c], \
          p[(at).sc + c], p[(at).sd + c], p[(at).se + c], p[(at).sf + c]))
#endif
LL_INLINE void tb_gather3(LL_GLOBAL const tb_stored* nodes, tb_index at, real* r, real* g, real* b) {
  *r = TB_VECTOR_OF(nodes, at, 0);
  *g = TB_VECTOR_OF(nodes, at, 1);
  *b = TB_VECTOR_OF(nodes, at, 2);
}
#else
LL_INLINE void tb_gather3(LL_GLOBAL const tb_stored* nodes, tb_index at, real* r, real* g, real* b) {
  *r = (real)nodes[at], *g = (real)nodes[at + 1], *b = (real)nodes[at + 2];
}
#endif

// The quadrilinear lookup at grid coordinates (x0, x1, x2, x3): X in out[0..2].
LL_INLINE void tb_lookup(LL_GLOBAL const tb_stored* mat, real x0, real x1, real x2, real x3, real* out) {
  const scalar n0 = (scalar)mat[0], n1 = (scalar)mat[1], n2 = (scalar)mat[2], n3 = (scalar)mat[3];
  real t0, t1, t2, t3;
  const tb_index i = tb_axis(x0, n0, &t0), j = tb_axis(x1, n1, &t1);
  const tb_index k = tb_axis(x2, n2, &t2), l = tb_axis(x3, n3, &t3);
  const int m1 = (int)n1, m2 = (int)n2, m3 = (int)n3;
  LL_GLOBAL const tb_stored* nodes = mat + TB_HEADER_SIZE;
  real r = R(0.0), g = R(0.0), b = R(0.0);
  for (int a = 0; a < 2; ++a) {
    const real wa = a ? t0 : R(1.0) - t0;
    for (int c = 0; c < 2; ++c) {
      const real wc = wa * (c ? t1 : R(1.0) - t1);
      const tb_index row = ((i + a) * m1 + j + c) * m2 + k;
      for (int e = 0; e < 2; ++e) {
        const real we = wc * (e ? t2 : R(1.0) - t2);
        const tb_index at = 3 * ((row + e) * m3 + l);
        for (int q = 0; q < 2; ++q) {
          const real w = we * (q ? t3 : R(1.0) - t3);
          real vr, vg, vb;
          tb_gather3(nodes, at + 3 * q, &vr, &vg, &vb);
          r += w * vr, g += w * vg, b += w * vb;
        }
      }
    }
  }
  out[0] = r, out[1] = g, out[2] = b;
}

// The warp of an axis relative to its range: s in [-1, 1] to t = sign(s) (1 - sqrt(1 - |s|)).
LL_INLINE real tb_warp(real s) {
  const real a = R(1.0) - sqrt(LL_FMAX(R(1.0) - fabs(s), R(0.0)));
  return s < R(0.0) ? -a : a;
}

// The grid coordinates of a pair (unit wi, wo, both above the surface): continuous node indices on each axis.
LL_INLINE void tb_coordinates(LL_GLOBAL const tb_stored* mat, real wix, real wiy, real wiz, real wox, real woy,
                              real woz, real* x0, real* x1, real* x2, real* x3) {
  real hx = wix + wox, hy = wiy + woy, hz = wiz + woz;
  const real inv = R(1.0) / sqrt(hx * hx + hy * hy + hz * hz);
  hx *= inv, hy *= inv, hz *= inv;
  const real rho = sqrt(hx * hx + hy * hy);
  const mask tilted = rho > R(1e-12);
  const real inv_rho = tilted ? R(1.0) / rho : R(0.0);
  const real ex = tilted ? hx * inv_rho : R(1.0), ey = tilted ? hy * inv_rho : R(0.0);
  // wi along E = (h.z e, -rho), P = (-e.y, e.x, 0) and h.
  const real d_par = (wix * ex + wiy * ey) * hz - wiz * rho;
  const real d_perp = wiy * ex - wix * ey;
  const real d_h = wix * hx + wiy * hy + wiz * hz;
  const real half_pi = R(1.57079632679489661923);
  const real psi = ll_atan2(d_par, d_h);
  const real chi = ll_atan2(d_perp, sqrt(d_par * d_par + d_h * d_h));
  const real psi_range = ll_atan2(hz, rho);  // 90 degrees - theta_h
  const real s = psi_range > R(0.0) ? psi / psi_range : R(0.0);
  const scalar eta_scale = (scalar)(mat[0] - 1) / (scalar)3.14159265358979323846;
  const scalar eta_y_scale = (scalar)(mat[1] - 1) / (scalar)3.14159265358979323846;
  *x0 = (ll_atan2(hx, hz) + half_pi) * eta_scale;
  *x1 = (ll_atan2(hy, hz) + half_pi) * eta_y_scale;
  *x2 = (tb_warp(s) + R(1.0)) * (R(0.5) * (scalar)(mat[2] - 1));
  *x3 = (tb_warp(chi / half_pi) + R(1.0)) * (R(0.5) * (scalar)(mat[3] - 1));
}

// f(wi, wo), RGB into f[0..2]; the launch-uniform value is unused. wi and wo are renormalised as every model's.
LL_INLINE void tb_eval(LL_GLOBAL const tb_stored* mat, int uniform, real wix, real wiy, real wiz, real wox, real woy,
                       real woz, real* f) {
  ll_normalize(&wix, &wiy, &wiz);
  ll_normalize(&wox, &woy, &woz);
  const mask lit = wiz > LL_HORIZON_EPS && woz > LL_HORIZON_EPS;
  // Unlit lanes look up the normal pair (whose h is defined) and are selected out below.
  wix = lit ? wix : R(0.0), wiy = lit ? wiy : R(0.0), wiz = lit ? wiz : R(1.0);
  wox = lit ? wox : R(0.0), woy = lit ? woy : R(0.0), woz = lit ? woz : R(1.0);
  real x0, x1, x2, x3, x[3];
  tb_coordinates(mat, wix, wiy, wiz, wox, woy, woz, &x0, &x1, &x2, &x3);
  tb_lookup(mat, x0, x1, x2, x3, x);
  const real inv_cos = lit ? R(1.0) / wiz : R(0.0);
  for (int c = 0; c < 3; ++c) f[c] = LL_FMAX(x[c], R(0.0)) * inv_cos;
}
