// Woven cotton BTF and BRDF of Irawan and Marschner 2006 (Secs. 4-5), exactly as pinned in SPEC.md section 3,
// with a yarn type per thread (up to 256 types per pattern, as ThunderLoom takes).
// Shared source: compiled as OpenCL C and as C++ (double reference, float baseline).
// Include kernels/common/shim.h and kernels/common/ellipse_window.h first.
//
// Thread records. A thread of direction d (warp or weft) and yarn type k has its own parameters (the host
// resolves them: yarns.X[k] where given, else d.X). Each distinct (d, k) the pattern's threads name is one record
// of WV_RECORD_SIZE = 15 values:
//   +0..2  kd (r, g, b)
//   +3..5  ks (r, g, b)
//   +6, 7  segment size s = (s_x, s_y), local y along the thread
//   +8     alpha, semi-major axis of the highlight ellipse (local units)
//   +9     eccentricity eta_e in [0, 1)
//   +10,11 cos, sin of phi_E, the ellipse's major-axis angle from local +x
//   +12,13 k = (k_x, k_y), highlight travel per unit of the local half vector
//   +14    direction: 0 warp, 1 weft
// Records are ordered by (direction, type), warp first and "no type" (-1) first: a pattern without yarn types
// has record 0 = the warp.* parameters and record 1 = the weft.* ones.
//
// Lobes. Records with the same ellipse geometry (values +6..+14: direction, s, alpha, eta_e, phi_E, k) have
// the same highlight-window area for every half vector; the BRDF needs one area per such group, a lobe of
// WV_LOBE_SIZE = 16 values: the 15 of a record, with kd and ks the area-weighted means of its records (a lobe of
// one record carries that record's kd and ks unchanged), then +15 its area fraction of the repeat. Only records
// on top somewhere (area > 0) make lobes.
//
// Packed material (array of scalar):
//   [0] eta (Fresnel index, default 1.5)     [1] L, the number of lobes
//   [2] offset of the records                [3] offset of the thread table
//   [4] offset of the cell table             [5] warps W      [6] picks P      [7] R, the number of records
//   [8], [9] offset of a warp record and of a weft record whose geometry (+6..+13) every record of its direction
//            shares, or -1 when the direction's records differ in geometry
//   [WV_HEADER = 10 ...]  L lobes, then R records, then
//   thread table: W + P values, the offset (in the material) of the record of warp w at [w], of pick p at [W + p]
//   cell table: per cell c = pick * W + warp two values: the cell's offset (in cells) from its float's first
//     cell, and the float's length, positive for a warp float, negative for weft.
// Offsets and counts are whole numbers, exact in float (a material is at most ~150,000 values).
//
// Texture layout. The repeat is warps x picks cells; cell (w, p) covers u in [w/W, (w+1)/W),
// v in [p/P, (p+1)/P). Weft runs along x (u), warp along y (v). Each float (one segment window: a maximal
// run of cells along one thread with that thread on top, weave::ExtractFloats) is mapped affinely onto its
// record's segment-local window [0, s_x] x [0, s_y] with local y along its thread:
//   warp float (column w, picks p0 .. p0 + L - 1, wrapping):  local = (s_x (uW - w), s_y (vP - p0) / L)
//   weft float (row p, warps w0 .. w0 + L - 1, wrapping):      local = (s_x (p + 1 - vP), s_y (uW - w0) / L)
// i.e. for directions the warp frame is the global frame and the weft frame maps a global (x, y) to local
// (-y, x) (a +90 degree rotation; positions get the same rotation, translated into the window). A float lies
// on one thread, so it has one record. wv_locate (host only, below) performs this uv -> (record, local x,
// local y) mapping from the cells.
//
// BTF of a segment of record r at local point p (Sec. 4), h = normalize(wi + wo), (h_x, h_y) its local part:
//   f = kd_r + ks_r I_r(p, h) Fr(eta, wi.h) G / ((n.wi)(n.wo)),
//   centre c = (s_x/2 (k_x h_x + 1), s_y/2 (k_y h_y + 1)), foci c +- alpha eta_e (cos phi_E, sin phi_E),
//   I = 1 when |F1 - p| + |F2 - p| <= 2 alpha, else 0,
//   G = min(1, 2 (n.h)(n.wo)/(wo.h), 2 (n.h)(n.wi)/(wo.h)).
// Returns 0 when n.wi or n.wo <= LL_HORIZON_EPS. The kernel form (wv_btf) finds the cell and its float by
// per-lane gathers, then its thread's record's values: selected per lane between the two records when there are
// two (no yarn types: 2 gathers per query in all, as before them), the geometry selected per lane between [8] and
// [9] and kd, ks gathered when each direction has one geometry (a colour draft: 9 gathers), every value gathered
// otherwise (17). No branch on lane data (the choice is the material's), one ellipse test per query whatever the
// number of records.
//
// BRDF (Sec. 5) = the mean of the BTF over one repeat = sum over floats F of (area of F / area of repeat) x
// (mean of the BTF over F's window). The affine map of F onto [0, s_x] x [0, s_y] preserves means, and in
// local units every float of record r has the same window and the same ellipse (c, a, b depend only on r's
// geometry and h), so the mean over any float of record r is
//   kd_r + ks_r (A_r / (s_x s_y)) Fr G / ((n.wi)(n.wo)),   A_r = ll_ellipse_rect_area(c, a, b, [0,s_x]x[0,s_y]),
// with a = alpha (cos phi_E, sin phi_E), b = alpha sqrt(1 - eta_e^2) (-sin phi_E, cos phi_E) (the ellipse of
// the foci above). Summing, the areas of the floats of record r add up to r's area fraction, and records of
// one lobe share A:
//   BRDF = sum_lobes fraction_l [kd_l + ks_l (A_l / (s_x s_y)) Fr G / ((n.wi)(n.wo))]   (kd_l, ks_l the means),
// exactly the BTF's mean. Cost: one ellipse-window area per lobe, i.e. per distinct geometry in use: two for a
// pattern without yarn types and for a colour draft (types differing in kd and ks only), at most 2 x 257 in all.
// kd stays inside the lobe sum rather than folded into one constant: the same operations in the same order as
// the two-type model, so its results are bit for bit those of the layout before yarn types.
// Fr and G do not depend on the record (eta is global).
//
// Reciprocity is exact in floating point: h comes from wi + wo (commutative), wi.h = wo.h = |wi + wo| / 2
// for unit vectors and is evaluated that way (one symmetric expression instead of two dot products that
// differ by rounding), and G / ((n.wi)(n.wo)) = min(1/((n.wi)(n.wo)), 2 (n.h)/((wi.h)(n.wi)),
// 2 (n.h)/((wi.h)(n.wo))) is a min over a set that the swap permutes. That form also keeps every
// intermediate bounded near the horizon (each term <= 1e14 for n.w > 1e-7).

#define WV_HEADER 10
#define WV_RECORD_SIZE 15
#define WV_LOBE_SIZE 16

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

// A record's (or lobe's) ellipse geometry, per lane: values +6..+13 of the record.
typedef struct {
  real s_x, s_y, alpha, ecc, c, s, kx, ky;
} wv_geometry;

// The geometry of the record at r (the same for every lane: a lobe, or a record chosen by the host).
LL_INLINE wv_geometry wv_geometry_at(LL_GLOBAL const scalar* r) {
  wv_geometry g;
  g.s_x = (real)(r[6]);
  g.s_y = (real)(r[7]);
  g.alpha = (real)(r[8]);
  g.ecc = (real)(r[9]);
  g.c = (real)(r[10]);
  g.s = (real)(r[11]);
  g.kx = (real)(r[12]);
  g.ky = (real)(r[13]);
  return g;
}

// The geometry of the record at material offset `record` per lane (a gather per value).
LL_INLINE wv_geometry wv_geometry_gather(LL_GLOBAL const scalar* mat, real record) {
  wv_geometry g;
  g.s_x = ll_gather(mat + 6, record);
  g.s_y = ll_gather(mat + 7, record);
  g.alpha = ll_gather(mat + 8, record);
  g.ecc = ll_gather(mat + 9, record);
  g.c = ll_gather(mat + 10, record);
  g.s = ll_gather(mat + 11, record);
  g.kx = ll_gather(mat + 12, record);
  g.ky = ll_gather(mat + 13, record);
  return g;
}

// Per lane the geometry of the warp record rw or the weft record rf.
LL_INLINE wv_geometry wv_geometry_select(LL_GLOBAL const scalar* rw, LL_GLOBAL const scalar* rf, mask warp) {
  wv_geometry g;
  g.s_x = warp ? (real)(rw[6]) : (real)(rf[6]);
  g.s_y = warp ? (real)(rw[7]) : (real)(rf[7]);
  g.alpha = warp ? (real)(rw[8]) : (real)(rf[8]);
  g.ecc = warp ? (real)(rw[9]) : (real)(rf[9]);
  g.c = warp ? (real)(rw[10]) : (real)(rf[10]);
  g.s = warp ? (real)(rw[11]) : (real)(rf[11]);
  g.kx = warp ? (real)(rw[12]) : (real)(rf[12]);
  g.ky = warp ? (real)(rw[13]) : (real)(rf[13]);
  return g;
}

// The highlight ellipse of geometry g for the local half vector (lhx, lhy): centre c, semi-axis vectors a, b.
// The local half vector of a warp segment is the global (hx, hy), of a weft segment (-hy, hx).
LL_INLINE void wv_ellipse(wv_geometry g, real lhx, real lhy, real* cx, real* cy, real* ax, real* ay, real* bx,
                          real* by) {
  *cx = R(0.5) * g.s_x * (g.kx * lhx + R(1.0));
  *cy = R(0.5) * g.s_y * (g.ky * lhy + R(1.0));
  // 1 - e^2 as (1 - e)(1 + e): no cancellation for e near 1 (0.995 in the twill preset).
  const real minor = g.alpha * sqrt((R(1.0) - g.ecc) * (R(1.0) + g.ecc));
  *ax = g.alpha * g.c;
  *ay = g.alpha * g.s;
  *bx = -minor * g.s;
  *by = minor * g.c;
}

// BRDF f(wi, wo), RGB into f[0..2]: the lobe sum above. wi, wo are renormalised here (the API accepts
// directions within its unit tolerance).
LL_INLINE void wv_brdf(LL_GLOBAL const scalar* mat, real wix, real wiy, real wiz, real wox, real woy, real woz,
                       real* f) {
  ll_normalize(&wix, &wiy, &wiz);
  ll_normalize(&wox, &woy, &woz);
  real hx, hy;
  mask lit;
  const real spec = wv_common(mat[0], wix, wiy, wiz, wox, woy, woz, &hx, &hy, &lit);
  const int lobes = (int)mat[1];
  real acc[3] = {R(0.0), R(0.0), R(0.0)};
  for (int l = 0; l < lobes; ++l) {
    LL_GLOBAL const scalar* lobe = mat + WV_HEADER + WV_LOBE_SIZE * l;
    const wv_geometry g = wv_geometry_at(lobe);
    const int warp = lobe[14] == 0;
    real cx, cy, ax, ay, bx, by;
    wv_ellipse(g, warp ? hx : -hy, warp ? hy : hx, &cx, &cy, &ax, &ay, &bx, &by);
    // R(0.0) + x: a -0.0 axis component (phi_E = 0 gives b_x = -0) enters the area as +0.0.
    const real area = ll_ellipse_rect_area(cx, cy, R(0.0) + ax, R(0.0) + ay, R(0.0) + bx, R(0.0) + by, R(0.0),
                                           R(0.0), g.s_x, g.s_y);
    const real ibar = area * (R(1.0) / (g.s_x * g.s_y));
    const scalar fraction = lobe[15];
    for (int c = 0; c < 3; ++c) acc[c] += fraction * (lobe[c] + lobe[3 + c] * (ibar * spec));
  }
  for (int c = 0; c < 3; ++c) f[c] = lit ? acc[c] : R(0.0);
}

// 1 where local point (lx, ly) lies inside the highlight ellipse of geometry g for the local half vector
// (lhx, lhy), else 0: |F1 - p| + |F2 - p| <= 2 alpha, foci c +- eta_e a.
LL_INLINE real wv_in_highlight(wv_geometry g, real lhx, real lhy, real lx, real ly) {
  real cx, cy, ax, ay, bx, by;
  wv_ellipse(g, lhx, lhy, &cx, &cy, &ax, &ay, &bx, &by);
  const real fx = g.ecc * ax, fy = g.ecc * ay;
  const real dx = lx - cx, dy = ly - cy;
  const real d1x = dx - fx, d1y = dy - fy, d2x = dx + fx, d2y = dy + fy;
  const real d = sqrt(d1x * d1x + d1y * d1y) + sqrt(d2x * d2x + d2y * d2y);
  return d <= R(2.0) * g.alpha ? R(1.0) : R(0.0);
}

// The record of index `record` (0 .. R - 1, in the order above).
LL_INLINE LL_GLOBAL const scalar* wv_record(LL_GLOBAL const scalar* mat, int record) {
  return mat + (int)mat[2] + WV_RECORD_SIZE * record;
}

// BTF of one segment of record `record` at segment-local point (local_x, local_y) in [0, s_x] x [0, s_y] (see
// the texture layout above for the uv mapping), RGB into f[0..2].
LL_INLINE void wv_btf_local(LL_GLOBAL const scalar* mat, int record, real local_x, real local_y, real wix,
                            real wiy, real wiz, real wox, real woy, real woz, real* f) {
  ll_normalize(&wix, &wiy, &wiz);
  ll_normalize(&wox, &woy, &woz);
  real hx, hy;
  mask lit;
  const real spec = wv_common(mat[0], wix, wiy, wiz, wox, woy, woz, &hx, &hy, &lit);
  LL_GLOBAL const scalar* r = wv_record(mat, record);
  const int warp = r[14] == 0;
  const real ind = wv_in_highlight(wv_geometry_at(r), warp ? hx : -hy, warp ? hy : hx, local_x, local_y);
  for (int c = 0; c < 3; ++c) {
    const real v = r[c] + r[3 + c] * (ind * spec);
    f[c] = lit ? v : R(0.0);
  }
}

// BTF at texture position (u, v) (pattern repeats; any real, the pattern tiles), RGB into f[0..2]: the
// kernel form. Per lane: the cell, then its float (offset, signed length) from the cell table, then its thread's
// record's values (selected or gathered, as the header comment says); the rest is the segment-local BTF of
// wv_btf_local.
LL_INLINE void wv_btf(LL_GLOBAL const scalar* mat, real wix, real wiy, real wiz, real wox, real woy, real woz,
                      real u, real v, real* f) {
  ll_normalize(&wix, &wiy, &wiz);
  ll_normalize(&wox, &woy, &woz);
  real hx, hy;
  mask lit;
  const real spec = wv_common(mat[0], wix, wiy, wiz, wox, woy, woz, &hx, &hy, &lit);
  const scalar warps = mat[5], picks = mat[6];
  // u - floor(u) rounds to 1 for tiny negative u: the min keeps the cell inside the repeat (fu = 1 then).
  const real gu = (u - floor(u)) * warps, gv = (v - floor(v)) * picks;
  const real w = LL_FMIN(floor(gu), warps - 1), p = LL_FMIN(floor(gv), picks - 1);
  const real fu = gu - w, fv = gv - p;  // position in the cell, [0, 1]
  LL_GLOBAL const scalar* cells = mat + (int)mat[4];
  const real entry = R(2.0) * (p * warps + w);
  const real offset = ll_gather(cells, entry), run = ll_gather(cells + 1, entry);
  const mask warp = run > R(0.0);
  // Fraction along the float and across it (weft: local x = 1 - fv, the +90 degree turn of the layout).
  const real along = (offset + (warp ? fv : fu)) / fabs(run);
  const real across = warp ? fu : R(1.0) - fv;
  // Selects are cheaper than gathers: the record is gathered only where the material needs it.
  const int two_records = mat[7] == 2, one_geometry = mat[8] >= 0 && mat[9] >= 0;
  LL_GLOBAL const scalar* rw = mat + (one_geometry ? (int)mat[8] : 0);
  LL_GLOBAL const scalar* rf = mat + (one_geometry ? (int)mat[9] : 0);
  const real record = two_records ? R(0.0) : ll_gather(mat + (int)mat[3], warp ? w : warps + p);
  const wv_geometry g = one_geometry ? wv_geometry_select(rw, rf, warp) : wv_geometry_gather(mat, record);
  const real ind = wv_in_highlight(g, warp ? hx : -hy, warp ? hy : hx, g.s_x * across, g.s_y * along);
  for (int c = 0; c < 3; ++c) {
    const real kd = two_records ? (warp ? (real)(rw[c]) : (real)(rf[c])) : ll_gather(mat + c, record);
    const real ks = two_records ? (warp ? (real)(rw[3 + c]) : (real)(rf[3 + c])) : ll_gather(mat + 3 + c, record);
    const real val = kd + ks * (ind * spec);
    f[c] = lit ? val : R(0.0);
  }
}

#ifndef __OPENCL_C_VERSION__
// Host only: maps texture (u, v) (any real; the pattern tiles, so taken modulo 1) to the float on top there
// and its segment-local coordinates, as in the texture layout above. cells[pick * warps + warp] is 1 where
// the warp is on top (weave::WeavePattern::cells). Floats are the runs of weave::ExtractFloats: a run
// wrapping over the repeat's edge is one float; a thread on top over the whole repeat is one float of the
// repeat's length starting at index 0. *record: the index of the record of the thread on top (from the
// material's thread table).
inline void wv_locate(const unsigned char* cells, int warps, int picks, real u, real v, int* record,
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
  const int record_offset = static_cast<int>(mat[static_cast<int>(mat[3]) + (warp ? w : warps + p)]);
  *record = (record_offset - static_cast<int>(mat[2])) / WV_RECORD_SIZE;
  const scalar s_x = mat[record_offset + 6], s_y = mat[record_offset + 7];
  if (warp) {
    *local_x = s_x * fu;
    *local_y = s_y * ((offset + fv) / length);
  } else {
    *local_x = s_x * (R(1.0) - fv);
    *local_y = s_y * ((offset + fu) / length);
  }
}
#endif
