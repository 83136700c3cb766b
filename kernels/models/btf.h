// A measured or synthesised BTF compressed per view slot with PCA (Sattler, Sarlette and Klein 2003, Eqs. 1-5;
// SPEC.md section 7). Shared source: compiled as OpenCL C and as C++ (double reference, float baseline).
// Include kernels/common/shim.h first.
//
// The grid of directions (the same for views and lights) is a set of rings of constant theta, ascending,
// ring r holding count_r directions at phi = 360 j / count_r degrees (Table 1's H1 and H2 are such grids);
// directions are numbered ring by ring.
//
// Packed material (array of scalar), BT_HEADER_SIZE values, then the rings, then three blocks:
//   [0] K, the components kept   [1] texels along u   [2] texels along v   [3] rings   [4] directions N
//   [5] offset of the weights    [6] offset of the texels   [7] offset of the tile means (informative: the
//   kernels compute them, bt_means_offset)
//   rings:      per ring: theta (radians), count, first direction
//   weights:    [view][light][k], k < K: the PCA coefficient of component k for that light (Eq. 1's p_ikj)
//   texels:     [view][texel t = iv * texels_u + iu][channel][1 + K]: the view's mean, then its K components
//   tile means: [view][channel][1 + K]: the same averaged over the tile (the BRDF)
// Texel (iu, iv) has its centre at uv = ((iu + 0.5) / texels_u, (iv + 0.5) / texels_v); the tile repeats with
// period 1 in u and v. The launch-uniform value is c, the components used (at most K).
//
// f(wi, wo, uv): the view slots around wo and the light directions around wi, each the (up to) 4 grid
// directions bilinear in (theta, phi) over the rings (Eq. 3's four nearest; beyond the last ring, the last
// ring's), the light weights folded into per-view coefficients gamma_k (Eq. 3), the views blended (Eq. 5),
// texels filtered bilinearly. Without uv: the tile's mean, the same with the tile-mean block.
#define BT_HEADER_SIZE 8
#define BT_RING_STRIDE 3
#define BT_MAX_COMPONENTS 64
#define BT_MAX_RINGS 64

// The up to 4 grid directions around the unit direction (x, y, z), z > 0, and their bilinear weights (zero
// weights where fewer are needed), for every lane at once: the slots are whole numbers held in reals, the ring
// search a select per ring (the rings are the material's, the same for every lane), the angles ll_atan2's
// polynomial (no library call, so the lanes stay one vector).
LL_INLINE void bt_neighbours(LL_GLOBAL const scalar* mat, real x, real y, real z, real* slot, real* weight) {
  const int rings = (int)mat[3];
  LL_GLOBAL const scalar* ring = mat + BT_HEADER_SIZE;
  // theta from atan2, accurate at the pole and the horizon alike (acos loses half its digits near z = 1).
  const real theta = ll_atan2(sqrt(x * x + y * y), z);
  // The ring at or below theta (the first inside the first ring, the last beyond the last) and the one above
  // it, as their (count, first direction), and t, the weight of the one above.
  real t = R(0.0);
  real count0 = (real)ring[1], first0 = (real)ring[2];
  real count1 = count0, first1 = first0;
  for (int r = 0; r + 1 < rings; ++r) {
    LL_GLOBAL const scalar* lo = ring + BT_RING_STRIDE * r;
    LL_GLOBAL const scalar* hi = lo + BT_RING_STRIDE;
    const mask above = theta >= (real)lo[0];
    const real tr = theta >= (real)hi[0] ? R(1.0) : (theta - (real)lo[0]) * (real)(1 / (hi[0] - lo[0]));
    t = above ? tr : t;
    count0 = above ? (real)lo[1] : count0;
    first0 = above ? (real)lo[2] : first0;
    count1 = above ? (real)hi[1] : count1;
    first1 = above ? (real)hi[2] : first1;
  }
  real phi = ll_atan2(y, x);
  phi = phi < R(0.0) ? phi + R(2 * 3.14159265358979323846) : phi;
  for (int side = 0; side < 2; ++side) {
    const real count = side == 0 ? count0 : count1, first = side == 0 ? first0 : first1;
    const real p = phi * count * R(0.5 / 3.14159265358979323846);
    const real p0 = floor(p);
    const real s = p - p0;
    const real j0 = p0 >= count ? p0 - count : p0;  // phi rounds up to 2 pi
    const real j1 = j0 + R(1.0) == count ? R(0.0) : j0 + R(1.0);
    const real w = side == 0 ? R(1.0) - t : t;
    slot[2 * side] = first + j0;
    slot[2 * side + 1] = first + j1;
    weight[2 * side] = w * (R(1.0) - s);
    weight[2 * side + 1] = w * s;
  }
}

// The blocks' offsets, computed from the header's small integers rather than read from [5]-[7]: in a float32
// table those can exceed 2^24, beyond which a float does not hold every integer (a large asset's tile means
// would be read one value off).
LL_INLINE int bt_weights_offset(LL_GLOBAL const scalar* mat) { return BT_HEADER_SIZE + BT_RING_STRIDE * (int)mat[3]; }
LL_INLINE int bt_texels_offset(LL_GLOBAL const scalar* mat) {
  const int n = (int)mat[4];
  return bt_weights_offset(mat) + n * n * (int)mat[0];
}
LL_INLINE int bt_means_offset(LL_GLOBAL const scalar* mat) {
  return bt_texels_offset(mat) + (int)mat[4] * (int)mat[1] * (int)mat[2] * 3 * (1 + (int)mat[0]);
}

// Where a query reads its texels: the bilinear footprint of (u, v) over the wrapped tile (it repeats), or the
// tile-mean block's one "texel" when not textured. Gives the texels' indices and weights, the block's offset in
// the packed material and one view slot's stride in it; returns how many texels (4 or 1).
LL_INLINE int bt_footprint(LL_GLOBAL const scalar* mat, int textured, scalar u, scalar v, int* texel, scalar* texel_w,
                           int* block, int* view_stride) {
  const int kept = (int)mat[0], nu = (int)mat[1], nv = (int)mat[2];
  const int texel_stride = 3 * (1 + kept);
  if (!textured) {
    texel[0] = 0, texel_w[0] = 1;
    *block = bt_means_offset(mat);
    *view_stride = texel_stride;
    return 1;
  }
  const scalar x = (u - floor(u)) * (scalar)nu - (scalar)0.5, y = (v - floor(v)) * (scalar)nv - (scalar)0.5;
  const scalar x0 = floor(x), y0 = floor(y);
  const scalar ax = x - x0, ay = y - y0;
  int iu0 = (int)x0, iv0 = (int)y0;
  iu0 = iu0 < 0 ? iu0 + nu : iu0;  // x0 is -1 left of the first centre
  iv0 = iv0 < 0 ? iv0 + nv : iv0;
  const int iu1 = iu0 + 1 == nu ? 0 : iu0 + 1, iv1 = iv0 + 1 == nv ? 0 : iv0 + 1;
  texel[0] = iv0 * nu + iu0, texel_w[0] = (1 - ax) * (1 - ay);
  texel[1] = iv0 * nu + iu1, texel_w[1] = ax * (1 - ay);
  texel[2] = iv1 * nu + iu0, texel_w[2] = (1 - ax) * ay;
  texel[3] = iv1 * nu + iu1, texel_w[3] = ax * ay;
  *block = bt_texels_offset(mat);
  *view_stride = nu * nv * texel_stride;
  return 4;
}

// Components are summed in blocks of BT_BLOCK as explicit vectors (OpenCL's float16 or double16, a GCC vector
// in C++): a lane's query shares nothing else to vectorise (each reads its own view slots and texels), and
// PoCL leaves loops over a block rolled, with their sums in memory.
#define BT_BLOCK 16
#ifdef __OPENCL_C_VERSION__
#ifdef LL_FP64
typedef double16 bt_block;
typedef double8 bt_half_block;
typedef double4 bt_quarter_block;
#else
typedef float16 bt_block;
typedef float8 bt_half_block;
typedef float4 bt_quarter_block;
#endif
#define BT_LOAD(v, p) ((v) = vload16(0, p))
#define BT_ZERO(v) ((v) = (bt_block)(0))
LL_INLINE scalar bt_sum(const bt_block* v) {
  const bt_half_block a = v->lo + v->hi;
  const bt_quarter_block b = a.lo + a.hi;
  return (b.x + b.y) + (b.z + b.w);
}
#else
typedef scalar bt_block __attribute__((vector_size(BT_BLOCK * sizeof(scalar))));
#define BT_LOAD(v, p) __builtin_memcpy(&(v), (p), sizeof(bt_block))
#define BT_ZERO(v) ((v) = bt_block{})
LL_INLINE scalar bt_sum(const bt_block* v) {  // the same order as OpenCL's halving
  scalar b[4];
  for (int j = 0; j < 4; ++j) b[j] = ((*v)[j] + (*v)[j + 8]) + ((*v)[j + 4] + (*v)[j + 12]);
  return (b[0] + b[1]) + (b[2] + b[3]);
}
#endif

// f of one query given its view slots and light directions (bt_neighbours; slots as whole numbers) and its
// (u, v). textured = 0: the tile's mean (u, v unused).
LL_INLINE void bt_reconstruct(LL_GLOBAL const scalar* mat, int c, const scalar* view_slot, const scalar* view_w,
                              const scalar* light_slot, const scalar* light_w, int textured, scalar u, scalar v,
                              scalar* out) {
  const int kept = (int)mat[0], n = (int)mat[4];
  c = c < kept ? (c < 0 ? 0 : c) : kept;
  const int stride = 1 + kept, blocks = c / BT_BLOCK;
  LL_GLOBAL const scalar* weights = mat + bt_weights_offset(mat);
  int texel[4], block_offset, view_stride;
  scalar texel_w[4];
  const int texels = bt_footprint(mat, textured, u, v, texel, texel_w, &block_offset, &view_stride);
  LL_GLOBAL const scalar* block = mat + block_offset;
  const int texel_stride = 3 * stride;
  // The component terms stay elementwise until the end (summed over views, blocks and texels): one reduction
  // per channel per query instead of one per view.
  bt_block acc0, acc1, acc2;
  BT_ZERO(acc0);
  BT_ZERO(acc1);
  BT_ZERO(acc2);
  scalar total[3] = {0, 0, 0};
  for (int m = 0; m < 4; ++m) {
    const scalar vw = view_w[m];
    if (vw == 0) continue;
    const int view = (int)view_slot[m];
    LL_GLOBAL const scalar* slot = block + view * view_stride;
    LL_GLOBAL const scalar* texel_data[4];
    scalar w[4];  // the view's and the texels' weights together
    for (int t = 0; t < texels; ++t) {
      texel_data[t] = slot + texel[t] * texel_stride;
      w[t] = vw * texel_w[t];
      for (int ch = 0; ch < 3; ++ch) total[ch] += w[t] * texel_data[t][ch * stride];  // the view's mean
    }
    LL_GLOBAL const scalar* light_p[4];
    for (int l = 0; l < 4; ++l) light_p[l] = weights + (view * n + (int)light_slot[l]) * kept;
    for (int b = 0; b < blocks; ++b) {
      const int k0 = b * BT_BLOCK;
      // Eq. 3: the four light directions' coefficients folded into one per component.
      bt_block gamma, e, s0, s1, s2;
      BT_ZERO(gamma);
      for (int l = 0; l < 4; ++l) {
        if (light_w[l] == 0) continue;
        BT_LOAD(e, light_p[l] + k0);
        gamma += light_w[l] * e;
      }
      // The texels' filter first, then the product with gamma: one multiply-add per texel and value.
      BT_ZERO(s0);
      BT_ZERO(s1);
      BT_ZERO(s2);
      for (int t = 0; t < texels; ++t) {
        LL_GLOBAL const scalar* p = texel_data[t] + 1 + k0;
        BT_LOAD(e, p);
        s0 += w[t] * e;
        BT_LOAD(e, p + stride);
        s1 += w[t] * e;
        BT_LOAD(e, p + 2 * stride);
        s2 += w[t] * e;
      }
      acc0 += gamma * s0;
      acc1 += gamma * s1;
      acc2 += gamma * s2;
    }
    for (int k = blocks * BT_BLOCK; k < c; ++k) {  // the components beyond the last whole block
      scalar gamma = 0;
      for (int l = 0; l < 4; ++l) gamma += light_w[l] * light_p[l][k];
      for (int ch = 0; ch < 3; ++ch) {
        scalar sum = 0;
        for (int t = 0; t < texels; ++t) sum += w[t] * texel_data[t][ch * stride + 1 + k];
        total[ch] += gamma * sum;
      }
    }
  }
  const scalar value[3] = {total[0] + bt_sum(&acc0), total[1] + bt_sum(&acc1), total[2] + bt_sum(&acc2)};
  // The data are non-negative; a truncated PCA series can undershoot near zero, which no BTF value can be.
  for (int ch = 0; ch < 3; ++ch) out[ch] = value[ch] > 0 ? value[ch] : 0;
}

#if defined(__OPENCL_C_VERSION__) && LL_WIDTH > 1
// A cache prefetch: clang's builtin (PoCL compiles with clang) emits the CPU's prefetch instruction; OpenCL's
// own prefetch() is the portable fallback.
#if defined(__has_builtin)
#if __has_builtin(__builtin_prefetch)
#define BT_PREFETCH(p) __builtin_prefetch(p)
#endif
#endif
#ifndef BT_PREFETCH
#define BT_PREFETCH(p) prefetch(p, 1)
#endif

// Starts loading what bt_reconstruct will read for one query (its view slots' texels and light weights), so
// that the next lane's reads overlap this lane's arithmetic: random queries wait on memory, not on sums.
// Called only where the next lane's nearest view slot differs from this lane's: neighbouring queries of a
// render or a slice share their view slots and nearby texels, already in cache, and would pay for the
// prefetches' instructions alone.
LL_INLINE void bt_prefetch(LL_GLOBAL const scalar* mat, int c, const scalar* view_slot, const scalar* view_w,
                           const scalar* light_slot, int textured, scalar u, scalar v) {
  const int kept = (int)mat[0], n = (int)mat[4];
  const int stride = 1 + kept, last = c < kept ? c : kept;
  LL_GLOBAL const scalar* weights = mat + bt_weights_offset(mat);
  int texel[4], block_offset, view_stride;
  scalar texel_w[4];
  const int texels = bt_footprint(mat, textured, u, v, texel, texel_w, &block_offset, &view_stride);
  for (int m = 0; m < 4; ++m) {
    if (view_w[m] == 0) continue;
    const int view = (int)view_slot[m];
    LL_GLOBAL const scalar* slot = mat + block_offset + view * view_stride;
    for (int t = 0; t < texels; ++t)
      for (int ch = 0; ch < 3; ++ch) {
        LL_GLOBAL const scalar* p = slot + texel[t] * 3 * stride + ch * stride;
        BT_PREFETCH(p);
        BT_PREFETCH(p + last);
      }
    for (int l = 0; l < 4; ++l) {
      LL_GLOBAL const scalar* p = weights + (view * n + (int)light_slot[l]) * kept;
      BT_PREFETCH(p);
      BT_PREFETCH(p + (last > 0 ? last - 1 : 0));
    }
  }
}
#endif

// The kernels' per-work-item function: the directions and their neighbours for every lane at once, then the
// reconstruction lane by lane (see bt_reconstruct).
LL_INLINE void bt_eval(LL_GLOBAL const scalar* mat, int c, real wix, real wiy, real wiz, real wox, real woy,
                       real woz, int textured, real u, real v, real* out) {
  ll_normalize(&wix, &wiy, &wiz);
  ll_normalize(&wox, &woy, &woz);
  // A reflection model (SPEC.md section 1); lanes below the horizon (or not numbers) give 0.
  const real lit = wiz > LL_HORIZON_EPS && woz > LL_HORIZON_EPS ? R(1.0) : R(0.0);
  real view[4], view_w[4], light[4], light_w[4];
  bt_neighbours(mat, wox, woy, woz, view, view_w);
  bt_neighbours(mat, wix, wiy, wiz, light, light_w);
#if defined(__OPENCL_C_VERSION__) && LL_WIDTH > 1
  scalar lane[19][LL_WIDTH], res[3][LL_WIDTH];
  for (int m = 0; m < 4; ++m) {
    LL_CAT(vstore, LL_WIDTH)(view[m], 0, lane[m]);
    LL_CAT(vstore, LL_WIDTH)(view_w[m], 0, lane[4 + m]);
    LL_CAT(vstore, LL_WIDTH)(light[m], 0, lane[8 + m]);
    LL_CAT(vstore, LL_WIDTH)(light_w[m], 0, lane[12 + m]);
  }
  LL_CAT(vstore, LL_WIDTH)(u, 0, lane[16]);
  LL_CAT(vstore, LL_WIDTH)(v, 0, lane[17]);
  LL_CAT(vstore, LL_WIDTH)(lit, 0, lane[18]);
  for (int i = 0; i < LL_WIDTH; ++i) {
    const int next = i + 1;
    scalar nb[16], f[3] = {0, 0, 0};  // one lane's view slots, their weights, light slots, their weights
    if (textured && next < LL_WIDTH && lane[18][next] != 0 && lane[0][next] != lane[0][i]) {
      for (int k = 0; k < 16; ++k) nb[k] = lane[k][next];
      bt_prefetch(mat, c, nb, nb + 4, nb + 8, textured, lane[16][next], lane[17][next]);
    }
    for (int k = 0; k < 16; ++k) nb[k] = lane[k][i];
    if (lane[18][i] != 0) bt_reconstruct(mat, c, nb, nb + 4, nb + 8, nb + 12, textured, lane[16][i], lane[17][i], f);
    res[0][i] = f[0], res[1][i] = f[1], res[2][i] = f[2];
  }
  out[0] = LL_CAT(vload, LL_WIDTH)(0, res[0]);
  out[1] = LL_CAT(vload, LL_WIDTH)(0, res[1]);
  out[2] = LL_CAT(vload, LL_WIDTH)(0, res[2]);
#else
  out[0] = out[1] = out[2] = 0;
  if (lit != 0) bt_reconstruct(mat, c, view, view_w, light, light_w, textured, u, v, out);
#endif
}
