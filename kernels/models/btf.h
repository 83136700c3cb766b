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
// weights where fewer are needed).
LL_INLINE void bt_neighbours(LL_GLOBAL const scalar* mat, scalar x, scalar y, scalar z, int* slot, scalar* weight) {
  const int rings = (int)mat[3];
  LL_GLOBAL const scalar* ring = mat + BT_HEADER_SIZE;
  // theta from atan2, accurate at the pole and the horizon alike (acos loses half its digits near z = 1).
  const scalar theta = atan2(sqrt(x * x + y * y), z);
  int r0 = 0;
  scalar t = 0;  // weight of ring r0 + 1
  for (int r = 0; r + 1 < rings; ++r) {
    const scalar lo = ring[BT_RING_STRIDE * r], hi = ring[BT_RING_STRIDE * (r + 1)];
    if (theta >= lo) {
      r0 = r;
      t = theta >= hi ? (scalar)1 : (theta - lo) / (hi - lo);
    }
  }
  if (rings == 1 || theta < ring[0]) t = 0;  // inside the first ring: its directions alone
  scalar phi = atan2(y, x);
  if (phi < 0) phi += (scalar)(2 * 3.14159265358979323846);
  for (int side = 0; side < 2; ++side) {
    LL_GLOBAL const scalar* rr = ring + BT_RING_STRIDE * (side == 0 ? r0 : (r0 + 1 < rings ? r0 + 1 : r0));
    const int count = (int)rr[1], first = (int)rr[2];
    const scalar p = phi * (scalar)count * (scalar)(0.5 / 3.14159265358979323846);
    const scalar p0 = floor(p);
    const scalar s = p - p0;
    int j0 = (int)p0;
    j0 = j0 >= count ? j0 - count : j0;  // phi rounds up to 2 pi
    const int j1 = j0 + 1 == count ? 0 : j0 + 1;
    const scalar w = side == 0 ? 1 - t : t;
    slot[2 * side] = first + j0;
    slot[2 * side + 1] = first + j1;
    weight[2 * side] = w * (1 - s);
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

// f of one query (scalar code: each query reads its own view slots and texels, so a work-item's lanes share
// nothing to vectorise but the loops over components). textured = 0: the tile's mean (u, v unused).
LL_INLINE void bt_eval_one(LL_GLOBAL const scalar* mat, int c, scalar wix, scalar wiy, scalar wiz, scalar wox,
                           scalar woy, scalar woz, int textured, scalar u, scalar v, scalar* out) {
  out[0] = out[1] = out[2] = 0;
  const scalar ni = sqrt(wix * wix + wiy * wiy + wiz * wiz), no = sqrt(wox * wox + woy * woy + woz * woz);
  wix /= ni, wiy /= ni, wiz /= ni;
  wox /= no, woy /= no, woz /= no;
  if (!(wiz > (scalar)1e-7) || !(woz > (scalar)1e-7)) return;  // a reflection model (SPEC.md section 1)
  const int kept = (int)mat[0], n = (int)mat[4];
  c = c < kept ? (c < 0 ? 0 : c) : kept;
  const int stride = 1 + kept;
  LL_GLOBAL const scalar* weights = mat + bt_weights_offset(mat);
  int view[4], light[4];
  scalar view_w[4], light_w[4];
  bt_neighbours(mat, wox, woy, woz, view, view_w);
  bt_neighbours(mat, wix, wiy, wiz, light, light_w);
  int texel[4], block_offset, view_stride;
  scalar texel_w[4];
  const int texels = bt_footprint(mat, textured, u, v, texel, texel_w, &block_offset, &view_stride);
  LL_GLOBAL const scalar* block = mat + block_offset;
  const int texel_stride = 3 * stride;
  scalar acc[3] = {0, 0, 0};
  scalar gamma[BT_MAX_COMPONENTS];
  scalar sum[1 + BT_MAX_COMPONENTS];
  for (int m = 0; m < 4; ++m) {
    if (view_w[m] == 0) continue;
    // Eq. 3: the four light directions' coefficients folded into one per component.
    for (int k = 0; k < c; ++k) gamma[k] = 0;
    for (int l = 0; l < 4; ++l) {
      if (light_w[l] == 0) continue;
      LL_GLOBAL const scalar* p = weights + (view[m] * n + light[l]) * kept;
      const scalar w = light_w[l];
      for (int k = 0; k < c; ++k) gamma[k] += w * p[k];
    }
    LL_GLOBAL const scalar* slot = block + view[m] * view_stride;
    for (int ch = 0; ch < 3; ++ch) {
      // The texels' filter first, elementwise over (mean, components) (contiguous: it vectorises), then one
      // dot product with gamma per channel, instead of one per texel.
      for (int k = 0; k <= c; ++k) sum[k] = 0;
      for (int t = 0; t < texels; ++t) {
        LL_GLOBAL const scalar* e = slot + texel[t] * texel_stride + ch * stride;
        const scalar w = texel_w[t];
        for (int k = 0; k <= c; ++k) sum[k] += w * e[k];
      }
      scalar value = sum[0];  // the view's mean (the PCA is mean-centred)
      for (int k = 0; k < c; ++k) value += gamma[k] * sum[1 + k];
      acc[ch] += view_w[m] * value;
    }
  }
  // The data are non-negative; a truncated PCA series can undershoot near zero, which no BTF value can be.
  for (int ch = 0; ch < 3; ++ch) out[ch] = acc[ch] > 0 ? acc[ch] : 0;
}

// The kernels' per-work-item function: each lane on its own (see bt_eval_one).
#if defined(__OPENCL_C_VERSION__) && LL_WIDTH > 1
LL_INLINE void bt_eval(LL_GLOBAL const scalar* mat, int c, real wix, real wiy, real wiz, real wox, real woy,
                       real woz, int textured, real u, real v, real* out) {
  scalar in[8][LL_WIDTH], res[3][LL_WIDTH];
  LL_CAT(vstore, LL_WIDTH)(wix, 0, in[0]);
  LL_CAT(vstore, LL_WIDTH)(wiy, 0, in[1]);
  LL_CAT(vstore, LL_WIDTH)(wiz, 0, in[2]);
  LL_CAT(vstore, LL_WIDTH)(wox, 0, in[3]);
  LL_CAT(vstore, LL_WIDTH)(woy, 0, in[4]);
  LL_CAT(vstore, LL_WIDTH)(woz, 0, in[5]);
  LL_CAT(vstore, LL_WIDTH)(u, 0, in[6]);
  LL_CAT(vstore, LL_WIDTH)(v, 0, in[7]);
  for (int i = 0; i < LL_WIDTH; ++i) {
    scalar f[3];
    bt_eval_one(mat, c, in[0][i], in[1][i], in[2][i], in[3][i], in[4][i], in[5][i], textured, in[6][i], in[7][i], f);
    res[0][i] = f[0], res[1][i] = f[1], res[2][i] = f[2];
  }
  out[0] = LL_CAT(vload, LL_WIDTH)(0, res[0]);
  out[1] = LL_CAT(vload, LL_WIDTH)(0, res[1]);
  out[2] = LL_CAT(vload, LL_WIDTH)(0, res[2]);
}
#else
LL_INLINE void bt_eval(LL_GLOBAL const scalar* mat, int c, real wix, real wiy, real wiz, real wox, real woy,
                       real woz, int textured, real u, real v, real* out) {
  bt_eval_one(mat, c, wix, wiy, wiz, wox, woy, woz, textured, u, v, out);
}
#endif
