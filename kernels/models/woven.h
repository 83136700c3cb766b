// Woven cotton BTF and BRDF of Irawan and Marschner 2006 (Secs. 4-5), exactly as pinned in SPEC.md section 3.
// Shared source: compiled as OpenCL C and as C++ (double reference, float baseline).
// Include kernels/common/shim.h and kernels/common/ellipse_window.h first.
//
// Packed material (array of scalar), WV_MATERIAL_SIZE = 30 values, then the cell table of wv_btf:
//   [0]               eta (Fresnel index, default 1.5)
//   [1]               warp area fraction of the repeat (number of 1 cells / cells); weft = 1 - this
//   [2 + 14 t ...]    thread type t (t = 0: warp, t = 1: weft), WV_THREAD_STRIDE = 14 values:
//                       +0..2  kd (r, g, b)
//                       +3..5  ks (r, g, b)
//                       +6, 7  segment size s = (s_x, s_y), local y along the thread
//                       +8     alpha, semi-major axis of the highlight ellipse (local units)
//                       +9     eccentricity eta_e in [0, 1)
//                       +10,11 cos, sin of phi_E, the ellipse's major-axis angle from local +x
//                       +12,13 k = (k_x, k_y), highlight travel per unit of the local half vector
//
// Texture layout. The repeat is warps x picks cells; cell (w, p) covers u in [w/W, (w+1)/W),
// v in [p/P, (p+1)/P). Weft runs along x (u), warp along y (v). Each float (one segment window: a maximal
// run of cells along one thread with that thread on top, weave::ExtractFloats) is mapped affinely onto its
// segment-local window [0, s_x] x [0, s_y] with local y along its thread:
//   warp float (column w, picks p0 .. p0 + L - 1, wrapping):  local = (s_x (uW - w), s_y (vP - p0) / L)
//   weft float (row p, warps w0 .. w0 + L - 1, wrapping):      local = (s_x (p + 1 - vP), s_y (uW - w0) / L)
// i.e. for directions the warp frame is the global frame and the weft frame maps a global (x, y) to local
// (-y, x) (a +90 degree rotation; positions get the same rotation, translated into the window).
// wv_locate (host only, below) performs this uv -> (thread type, local x, local y) mapping from the cells.
//
// BTF of a segment of type t at local point p (Sec. 4), h = normalize(wi + wo), (h_x, h_y) its local part:
//   f = kd_t + ks_t I_t(p, h) Fr(eta, wi.h) G / ((n.wi)(n.wo)),
//   centre c = (s_x/2 (k_x h_x + 1), s_y/2 (k_y h_y + 1)), foci c +- alpha eta_e (cos phi_E, sin phi_E),
//   I = 1 when |F1 - p| + |F2 - p| <= 2 alpha, else 0,
//   G = min(1, 2 (n.h)(n.wo)/(wo.h), 2 (n.h)(n.wi)/(wo.h)).
// Returns 0 when n.wi or n.wo <= LL_HORIZON_EPS.
//
// BRDF (Sec. 5) = the mean of the BTF over one repeat = sum over floats F of (area of F / area of repeat) x
// (mean of the BTF over F's window). The affine map of F onto [0, s_x] x [0, s_y] preserves means, and in
// local units every float of thread type t has the same window and the same ellipse (c, a, b depend only on
// t and h), so the mean over any float of type t is
//   kd_t + ks_t (A_t / (s_x s_y)) Fr G / ((n.wi)(n.wo)),   A_t = ll_ellipse_rect_area(c, a, b, [0,s_x]x[0,s_y]),
// with a = alpha (cos phi_E, sin phi_E), b = alpha sqrt(1 - eta_e^2) (-sin phi_E, cos phi_E) (the ellipse of
// the foci above). Summing, the areas of the floats of type t add up to that type's area fraction:
//   BRDF = sum_t fraction_t [kd_t + ks_t (A_t / (s_x s_y)) Fr G / ((n.wi)(n.wo))],
// two ellipse-window areas per query whatever the pattern; the pattern enters only through the warp area
// fraction [1]. Fr and G do not depend on t (eta is global).
//
// Reciprocity is exact in floating point: h comes from wi + wo (commutative), wi.h = wo.h = |wi + wo| / 2
// for unit vectors and is evaluated that way (one symmetric expression instead of two dot products that
// differ by rounding), and G / ((n.wi)(n.wo)) = min(1/((n.wi)(n.wo)), 2 (n.h)/((wi.h)(n.wi)),
// 2 (n.h)/((wi.h)(n.wo))) is a min over a set that the swap permutes. That form also keeps every
// intermediate bounded near the horizon (each term <= 1e14 for n.w > 1e-7).

#define WV_THREAD_STRIDE 14
#define WV_MATERIAL_SIZE (2 + 2 * WV_THREAD_STRIDE)

// Direction-only factors shared by BTF and BRDF. Inputs unit (renormalised by the callers).
// Writes the half vector's cloth-plane components (hx, hy) and returns Fr G / ((n.wi)(n.wo)), or 0 below
// the horizon (*lit = false then).
LL_INLINE real wv_common(scalar eta, real wix, real wiy, real wiz, real wox, real woy, real woz, real* hx,
                         real* hy, mask* lit) {
  const real sx = wix + wox, sy = wiy + woy, sz = wiz + woz;
  const mask up = wiz > LL_HORIZON_EPS && woz > LL_HORIZON_EPS;
  // sz > 2e-7 on lit lanes, so len > 0; dead lanes use 1 to keep every value finite.
  const real len2 = sx * sx + sy * sy + sz * sz;
  const real len = up ? sqrt(len2) : R(1.0);
  const real inv_len = R(1.0) / len;
  *hx = sx * inv_len;
  *hy = sy * inv_len;
  const real nh = sz * inv_len;
  const real cd = R(0.5) * len;  // wi.h = wo.h = |wi + wo| / 2
  const real fr = ll_fresnel_dielectric(eta, LL_FMIN(cd, R(1.0)));
  const real ci = up ? wiz : R(1.0), co = up ? woz : R(1.0);
  const real two_nh_cd = R(2.0) * nh / cd;
  const real g_over = LL_FMIN(R(1.0) / (ci * co), LL_FMIN(two_nh_cd / ci, two_nh_cd / co));
  *lit = up;
  return up ? fr * g_over : R(0.0);
}

// Thread type t's ellipse for local half vector (lhx, lhy): centre c, semi-axis vectors a, b.
LL_INLINE void wv_ellipse(LL_GLOBAL const scalar* th, real lhx, real lhy, real* cx, real* cy, scalar* ax,
                          scalar* ay, scalar* bx, scalar* by) {
  const scalar s_x = th[6], s_y = th[7], alpha = th[8], ecc = th[9];
  const scalar c = th[10], s = th[11];  // cos, sin of phi_E, packed by the host: no trigonometry here
  const scalar kx = th[12], ky = th[13];
  *cx = R(0.5) * s_x * (kx * lhx + R(1.0));
  *cy = R(0.5) * s_y * (ky * lhy + R(1.0));
  // 1 - e^2 as (1 - e)(1 + e): no cancellation for e near 1 (0.995 in the twill preset).
  const scalar minor = alpha * sqrt((1 - ecc) * (1 + ecc));
  *ax = alpha * c;
  *ay = alpha * s;
  *bx = -minor * s;
  *by = minor * c;
}

// The highlight ellipse of thread type t (0 warp, 1 weft) in its segment-local frame, from the global half
// vector's (hx, hy): the warp frame is the global one, the weft frame maps (x, y) to (-y, x).
LL_INLINE void wv_thread_ellipse(LL_GLOBAL const scalar* th, int t, real hx, real hy, real* cx, real* cy,
                                 scalar* ax, scalar* ay, scalar* bx, scalar* by) {
  wv_ellipse(th, t == 0 ? hx : -hy, t == 0 ? hy : hx, cx, cy, ax, ay, bx, by);
}

// BRDF f(wi, wo), RGB into f[0..2]. wi, wo are renormalised here (the API accepts directions within its unit
// tolerance).
LL_INLINE void wv_brdf(LL_GLOBAL const scalar* mat, real wix, real wiy, real wiz, real wox, real woy, real woz,
                       real* f) {
  ll_normalize(&wix, &wiy, &wiz);
  ll_normalize(&wox, &woy, &woz);
  const scalar eta = mat[0];
  const scalar frac[2] = {mat[1], 1 - mat[1]};
  real hx, hy;
  mask lit;
  const real spec = wv_common(eta, wix, wiy, wiz, wox, woy, woz, &hx, &hy, &lit);
  real acc[3] = {R(0.0), R(0.0), R(0.0)};
  for (int t = 0; t < 2; ++t) {
    LL_GLOBAL const scalar* th = mat + 2 + WV_THREAD_STRIDE * t;
    real cx, cy;
    scalar ax, ay, bx, by;
    wv_thread_ellipse(th, t, hx, hy, &cx, &cy, &ax, &ay, &bx, &by);
    const scalar s_x = th[6], s_y = th[7];
    const real area = ll_ellipse_rect_area(cx, cy, R(0.0) + ax, R(0.0) + ay, R(0.0) + bx, R(0.0) + by, R(0.0),
                                           R(0.0), R(0.0) + s_x, R(0.0) + s_y);
    const real ibar = area * (R(1.0) / (s_x * s_y));
    for (int c = 0; c < 3; ++c) acc[c] += frac[t] * (th[c] + th[3 + c] * (ibar * spec));
  }
  for (int c = 0; c < 3; ++c) f[c] = lit ? acc[c] : R(0.0);
}

// 1 where local point (lx, ly) of a thread-type-t segment lies inside its highlight ellipse for the global
// half vector's (hx, hy), else 0: |F1 - p| + |F2 - p| <= 2 alpha, foci c +- eta_e a.
LL_INLINE real wv_in_highlight(LL_GLOBAL const scalar* th, int t, real hx, real hy, real lx, real ly) {
  real cx, cy;
  scalar ax, ay, bx, by;
  wv_thread_ellipse(th, t, hx, hy, &cx, &cy, &ax, &ay, &bx, &by);
  const scalar alpha = th[8], ecc = th[9];
  const scalar fx = ecc * ax, fy = ecc * ay;
  const real dx = lx - cx, dy = ly - cy;
  const real d1x = dx - fx, d1y = dy - fy, d2x = dx + fx, d2y = dy + fy;
  const real d = sqrt(d1x * d1x + d1y * d1y) + sqrt(d2x * d2x + d2y * d2y);
  return d <= R(2.0) * alpha ? R(1.0) : R(0.0);
}

// BTF of one segment of thread type t (0 warp, 1 weft) at segment-local point (local_x, local_y) in
// [0, s_x] x [0, s_y] (see the texture layout above for the uv mapping), RGB into f[0..2].
LL_INLINE void wv_btf_local(LL_GLOBAL const scalar* mat, int thread_type, real local_x, real local_y, real wix,
                            real wiy, real wiz, real wox, real woy, real woz, real* f) {
  ll_normalize(&wix, &wiy, &wiz);
  ll_normalize(&wox, &woy, &woz);
  real hx, hy;
  mask lit;
  const real spec = wv_common(mat[0], wix, wiy, wiz, wox, woy, woz, &hx, &hy, &lit);
  const int t = thread_type == 0 ? 0 : 1;
  LL_GLOBAL const scalar* th = mat + 2 + WV_THREAD_STRIDE * t;
  const real ind = wv_in_highlight(th, t, hx, hy, local_x, local_y);
  for (int c = 0; c < 3; ++c) {
    const real v = th[c] + th[3 + c] * (ind * spec);
    f[c] = lit ? v : R(0.0);
  }
}

// BTF at texture position (u, v) (pattern repeats; any real, the pattern tiles), RGB into f[0..2]: the
// kernel form, which finds the float under (u, v) in the cell table packed after the 30 values above:
//   [30] warps W, [31] picks P, then per cell c = pick * W + warp two values: the cell's offset (in cells)
//   from its float's first cell, and the float's length, positive for a warp float, negative for weft.
// The lookup is a per-lane gather; everything else is the segment-local BTF of wv_btf_local, evaluated for
// both thread types and selected per lane (no branch on lane data).
LL_INLINE void wv_btf(LL_GLOBAL const scalar* mat, real wix, real wiy, real wiz, real wox, real woy, real woz,
                      real u, real v, real* f) {
  ll_normalize(&wix, &wiy, &wiz);
  ll_normalize(&wox, &woy, &woz);
  real hx, hy;
  mask lit;
  const real spec = wv_common(mat[0], wix, wiy, wiz, wox, woy, woz, &hx, &hy, &lit);
  const scalar warps = mat[WV_MATERIAL_SIZE], picks = mat[WV_MATERIAL_SIZE + 1];
  // u - floor(u) rounds to 1 for tiny negative u: the min keeps the cell inside the repeat (fu = 1 then).
  const real gu = (u - floor(u)) * warps, gv = (v - floor(v)) * picks;
  const real w = LL_FMIN(floor(gu), warps - 1), p = LL_FMIN(floor(gv), picks - 1);
  const real fu = gu - w, fv = gv - p;  // position in the cell, [0, 1]
  LL_GLOBAL const scalar* table = mat + WV_MATERIAL_SIZE + 2;
  const real entry = R(2.0) * (p * warps + w);
  const real offset = ll_gather(table, entry), run = ll_gather(table, entry + R(1.0));
  const mask warp = run > R(0.0);
  // Fraction along the float and across it (weft: local x = 1 - fv, the +90 degree turn of the layout).
  const real along = (offset + (warp ? fv : fu)) / fabs(run);
  const real across = warp ? fu : R(1.0) - fv;
  LL_GLOBAL const scalar* tw = mat + 2;
  LL_GLOBAL const scalar* tf = mat + 2 + WV_THREAD_STRIDE;
  const real in_warp = wv_in_highlight(tw, 0, hx, hy, tw[6] * across, tw[7] * along);
  const real in_weft = wv_in_highlight(tf, 1, hx, hy, tf[6] * across, tf[7] * along);
  const real ind = warp ? in_warp : in_weft;
  for (int c = 0; c < 3; ++c) {
    const real kd = warp ? R(0.0) + tw[c] : R(0.0) + tf[c];
    const real ks = warp ? R(0.0) + tw[3 + c] : R(0.0) + tf[3 + c];
    const real val = kd + ks * (ind * spec);
    f[c] = lit ? val : R(0.0);
  }
}

#ifndef __OPENCL_C_VERSION__
// Host only: maps texture (u, v) (any real; the pattern tiles, so taken modulo 1) to the float on top there
// and its segment-local coordinates, as in the texture layout above. cells[pick * warps + warp] is 1 where
// the warp is on top (weave::WeavePattern::cells). Floats are the runs of weave::ExtractFloats: a run
// wrapping over the repeat's edge is one float; a thread on top over the whole repeat is one float of the
// repeat's length starting at index 0. *thread_type: 0 warp, 1 weft.
inline void wv_locate(const unsigned char* cells, int warps, int picks, real u, real v, int* thread_type,
                      real* local_x, real* local_y, LL_GLOBAL const scalar* mat) {
  const real uu = u - std::floor(u), vv = v - std::floor(v);
  const real gu = uu * warps, gv = vv * picks;  // in cells
  int w = static_cast<int>(std::floor(gu)), p = static_cast<int>(std::floor(gv));
  w = w < 0 ? 0 : (w >= warps ? warps - 1 : w);  // uu rounded up to 1
  p = p < 0 ? 0 : (p >= picks ? picks - 1 : p);
  const real fu = gu - w, fv = gv - p;  // position inside the cell, [0, 1]
  const bool warp = cells[p * warps + w] != 0;
  const int n = warp ? picks : warps;                 // cells along the thread
  const int i = warp ? p : w;                         // index along the thread
  auto on = [&](int k) {                              // this thread on top at index k along it
    k = ((k % n) + n) % n;
    const unsigned char c = warp ? cells[k * warps + w] : cells[p * warps + k];
    return warp ? c != 0 : c == 0;
  };
  int back = 0;
  while (back < n && on(i - back - 1)) ++back;
  int start, length;
  if (back >= n) {  // the whole thread is one float starting at 0
    start = 0;
    length = n;
  } else {
    start = i - back;
    length = back + 1;
    while (on(start + length)) ++length;  // terminates: some index is off
  }
  const int offset = ((i - start) % n + n) % n;  // cells from the float's first cell
  const scalar* th = mat + 2 + WV_THREAD_STRIDE * (warp ? 0 : 1);
  const scalar s_x = th[6], s_y = th[7];
  *thread_type = warp ? 0 : 1;
  if (warp) {
    *local_x = s_x * fu;
    *local_y = s_y * ((offset + fv) / length);
  } else {
    *local_x = s_x * (R(1.0) - fv);
    *local_y = s_y * ((offset + fu) / length);
  }
}
#endif
