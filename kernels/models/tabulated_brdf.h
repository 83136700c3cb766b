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

#if defined(__OPENCL_C_VERSION__) && LL_WIDTH > 1
#define TB_LANES LL_WIDTH
#define TB_SPILL(v, lanes) LL_CAT(vstore, LL_WIDTH)(v, 0, lanes)
#define TB_FILL(lanes) LL_CAT(vload, LL_WIDTH)(0, lanes)
#else
#define TB_LANES 1
#define TB_SPILL(v, lanes) ((lanes)[0] = (v))
#define TB_FILL(lanes) ((lanes)[0])
#endif

// The lower node and the weight of the upper one along an axis of n nodes, at grid coordinate x (clamped).
LL_INLINE int tb_axis(scalar x, int n, scalar* t) {
  const scalar top = (scalar)(n - 1);
  const scalar xc = x < (scalar)0 ? (scalar)0 : (x > top ? top : x);
  int i = (int)floor(xc);
  i = i > n - 2 ? n - 2 : i;
  i = i < 0 ? 0 : i;
  *t = xc - (scalar)i;
  return i;
}

// One lane's quadrilinear lookup at grid coordinates (x0, x1, x2, x3): X in out[0..2].
LL_INLINE void tb_lookup(LL_GLOBAL const tb_stored* mat, scalar x0, scalar x1, scalar x2, scalar x3, scalar* out) {
  const int n0 = (int)mat[0], n1 = (int)mat[1], n2 = (int)mat[2], n3 = (int)mat[3];
  int i[2], j[2], k[2], l[2];
  scalar ti, tj, tk, tl;
  i[0] = tb_axis(x0, n0, &ti), i[1] = i[0] + 1;
  j[0] = tb_axis(x1, n1, &tj), j[1] = j[0] + 1;
  k[0] = tb_axis(x2, n2, &tk), k[1] = k[0] + 1;
  l[0] = tb_axis(x3, n3, &tl), l[1] = l[0] + 1;
  LL_GLOBAL const tb_stored* nodes = mat + TB_HEADER_SIZE;
  scalar r = (scalar)0, g = (scalar)0, b = (scalar)0;
  for (int a = 0; a < 2; ++a) {
    const scalar wa = a ? ti : (scalar)1 - ti;
    for (int c = 0; c < 2; ++c) {
      const scalar wc = wa * (c ? tj : (scalar)1 - tj);
      const int row = (i[a] * n1 + j[c]) * n2;
      for (int e = 0; e < 2; ++e) {
        const scalar we = wc * (e ? tk : (scalar)1 - tk);
        const int base = (row + k[e]) * n3;
        LL_GLOBAL const tb_stored* p0 = nodes + 3 * (base + l[0]);
        LL_GLOBAL const tb_stored* p1 = nodes + 3 * (base + l[1]);
        const scalar w0 = we * ((scalar)1 - tl), w1 = we * tl;
        r += w0 * (scalar)p0[0] + w1 * (scalar)p1[0];
        g += w0 * (scalar)p0[1] + w1 * (scalar)p1[1];
        b += w0 * (scalar)p0[2] + w1 * (scalar)p1[2];
      }
    }
  }
  out[0] = r;
  out[1] = g;
  out[2] = b;
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
  real x0, x1, x2, x3;
  tb_coordinates(mat, wix, wiy, wiz, wox, woy, woz, &x0, &x1, &x2, &x3);
  // The lookup reads each lane's own nodes: a loop over the lanes (OpenCL C has no vector gather).
  scalar c0[TB_LANES], c1[TB_LANES], c2[TB_LANES], c3[TB_LANES], r[TB_LANES], g[TB_LANES], b[TB_LANES];
  TB_SPILL(x0, c0);
  TB_SPILL(x1, c1);
  TB_SPILL(x2, c2);
  TB_SPILL(x3, c3);
  for (int lane = 0; lane < TB_LANES; ++lane) {
    scalar out[3];
    tb_lookup(mat, c0[lane], c1[lane], c2[lane], c3[lane], out);
    r[lane] = out[0], g[lane] = out[1], b[lane] = out[2];
  }
  const real inv_cos = lit ? R(1.0) / wiz : R(0.0);
  f[0] = LL_FMAX(TB_FILL(r), R(0.0)) * inv_cos;
  f[1] = LL_FMAX(TB_FILL(g), R(0.0)) * inv_cos;
  f[2] = LL_FMAX(TB_FILL(b), R(0.0)) * inv_cos;
}
