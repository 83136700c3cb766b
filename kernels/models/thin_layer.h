// Thin semi-transparent layer of Frisvad et al. (Chandrasekhar's single scattering in a plane-parallel slab,
// isotropic phase), exactly as pinned in SPEC.md section 4. Shared source: compiled as OpenCL C
// (thin_layer.cl) and as C++ (double reference, float baseline). Include kernels/common/shim.h first.
//
// Packed material, TL_PACKED_SIZE values:
//   [0]     tau, optical thickness (>= 0)
//   [1..3]  Lambda / (4 pi) per channel (Lambda the single-scattering albedo in [0, 1])
//   [TL_MATERIAL_SIZE + (2 c + side) TL_TABLE_SIZE ...]  for channel c, reflection (side 0) and transmission
//           (side 1): f of all scattering orders minus single scattering, from the adding-doubling solver
//           (server/models/slab/adding_doubling.h), at mu = (i / (n - 1))^2 and mu0 = (j / (n - 1))^2 in entry
//           [i n + j], n = TL_TABLE_NODES; symmetric (reciprocity).
//
// With mu0 = |n.wi|, mu = |n.wo| (after renormalising wi, wo), f per channel is Lambda/(4 pi) times
//   same side (front-lit):   -expm1(-tau (mu + mu0) / (mu mu0)) / (mu + mu0)
//   opposite sides (back-lit diffuse transmission), with mx = max(mu, mu0), mn = min(mu, mu0) and
//   d = tau (mx - mn) / (mx mn):
//     exp(-tau / mx) * (tau / (mx mn)) psi(d),   psi(d) = -expm1(-d) / d,  for d <= 1,
//     exp(-tau / mx) * (-expm1(-d)) / (mx - mn),                            for d > 1.
// The second line is SPEC's direct form (exp(-tau/mu) - exp(-tau/mu0)) / (mu - mu0) with exp(-tau/mx)
// factored out: exp(-tau/mn) = exp(-tau/mx) exp(-d), so one exp serves both branches and exp(-tau/mn) may
// underflow without taking the result with it. Both are symmetric in (mu, mu0): f is reciprocal.
// f is 0 when |n.wi| or |n.wo| <= LL_HORIZON_EPS (directions in the plane of the layer).

#define TL_MATERIAL_SIZE 4
// The launch-uniform value: single scattering (the closed form) or all orders (closed form plus the tables).
#define TL_SCATTERING_SINGLE 0
#define TL_SCATTERING_ALL 1
// Nodes uniform in sqrt(mu): they crowd toward grazing, where f changes fastest (on the scale tau of a thin
// layer, and like mu log mu for any layer); with 33 bilinear lookup stays within 5e-3 of f, p99 4e-3
// (docs/models.md "The thin layer: all scattering orders").
#define TL_TABLE_NODES 33
#define TL_TABLE_SIZE (TL_TABLE_NODES * TL_TABLE_NODES)
#define TL_PACKED_SIZE (TL_MATERIAL_SIZE + 6 * TL_TABLE_SIZE)

// psi(d) = (1 - exp(-d)) / d, psi(0) = 1, for d >= 0: the series 1 - d/2 + d^2/6 below 1e-3 (error < d^3/24,
// and -expm1(-d)/d would be 0/0 at d = 0), the expm1 quotient above (no cancellation for any d).
LL_INLINE real tl_psi(real d) {
  const real series = R(1.0) - d * (R(0.5) - d * R(1.6666666666666667e-1));
  const real quotient = -ll_expm1(-d) / LL_FMAX(d, R(1e-3));  // finite on every lane, used only above 1e-3
  return d < R(1e-3) ? series : quotient;
}

// |n.w| of a direction within the API's unit tolerance, as for a unit vector.
LL_INLINE real tl_abs_cos(real x, real y, real z) { return fabs(z) / sqrt(x * x + y * y + z * z); }

// Single-scattering f of the layer for (mu0, mu), given which side wo is on; Lambda/(4 pi) left out.
LL_INLINE real tl_single_scattering(scalar tau, real mu0, real mu, mask same_side) {
  const mask live = mu0 > LL_HORIZON_EPS && mu > LL_HORIZON_EPS;
  const real a = live ? mu0 : R(1.0), b = live ? mu : R(1.0);  // dead lanes keep every division finite
  const real sum = a + b, prod = a * b;
  // Same side: 1 - exp(-x) through expm1, exact down to tau -> 0 (1e-9) where 1 - exp(-x) rounds to 0.
  const real reflected = -ll_expm1(-tau * (sum / prod)) / sum;
  const real mx = LL_FMAX(a, b), mn = LL_FMIN(a, b);
  const real d = tau * ((mx - mn) / prod);
  // Opposite sides: near mu = mu0 the difference quotient is 0/0; tau/(mx mn) psi(d) is its exact rewrite.
  const real near_equal = (tau / prod) * tl_psi(d);
  const real far_apart = -ll_expm1(-d) / LL_FMAX(mx - mn, LL_HORIZON_EPS);  // mx > mn here when d > 1
  const real transmitted = ll_exp(-tau / mx) * (d <= R(1.0) ? near_equal : far_apart);
  return live ? (same_side ? reflected : transmitted) : R(0.0);
}

// Bilinear lookup in the symmetric table at `base` at (sqrt(mu), sqrt(mu0)), taken at (larger, smaller) so that
// swapping wi and wo gives bit-identical values. Grazing (mu -> 0) reads the edge node, which holds the true
// limit of the multiply scattered f at mu = 0 (finite); only at mu = mu0 = 0, where it diverges like
// log(1 / mu), the corner node holds its diagonal neighbour's value instead (there single scattering's
// 1 / (mu + mu0) outweighs it over 100 times, docs/models.md
// "The thin layer: all scattering orders").
LL_INLINE real tl_table_lookup(LL_GLOBAL const scalar* mat, real base, real mu0, real mu) {
  const real last = R(1.0) * (TL_TABLE_NODES - 1);
  const real hi = sqrt(LL_FMAX(mu0, mu)) * last, lo = sqrt(LL_FMIN(mu0, mu)) * last;
  const real i = LL_FMIN(floor(hi), last - R(1.0)), j = LL_FMIN(floor(lo), last - R(1.0));
  const real t = hi - i, u = lo - j;
  const real at = base + i * (last + R(1.0)) + j;
  const real row_i = (R(1.0) - u) * ll_gather(mat, at) + u * ll_gather(mat, at + R(1.0));
  const real row_next = (R(1.0) - u) * ll_gather(mat, at + last + R(1.0)) + u * ll_gather(mat, at + last + R(2.0));
  return (R(1.0) - t) * row_i + t * row_next;
}

// f(wi, wo) for one query (RGB into f[0..2]) with the launch's scattering mode (TL_SCATTERING_*): a branch per
// launch, not per lane.
LL_INLINE void tl_eval_scattering(LL_GLOBAL const scalar* mat, int scattering, real wix, real wiy, real wiz,
                                  real wox, real woy, real woz, real* f) {
  const mask same_side = (wiz > R(0.0) && woz > R(0.0)) || (wiz < R(0.0) && woz < R(0.0));
  const real mu0 = tl_abs_cos(wix, wiy, wiz), mu = tl_abs_cos(wox, woy, woz);
  const real s = tl_single_scattering(mat[0], mu0, mu, same_side);
  for (int c = 0; c < 3; ++c) f[c] = mat[1 + c] * s;
  if (scattering == TL_SCATTERING_ALL) {
    const mask live = mu0 > LL_HORIZON_EPS && mu > LL_HORIZON_EPS;  // as single scattering: 0 in the plane
    const real side = same_side ? R(0.0) : R(1.0) * TL_TABLE_SIZE;
    for (int c = 0; c < 3; ++c) {
      const real multiple = tl_table_lookup(mat, side + R(1.0) * (TL_MATERIAL_SIZE + 2 * c * TL_TABLE_SIZE), mu0, mu);
      f[c] += live ? multiple : R(0.0);
    }
  }
}

// Single-scattering f(wi, wo) (RGB into f[0..2]); reads only the first TL_MATERIAL_SIZE values.
LL_INLINE void tl_eval(LL_GLOBAL const scalar* mat, real wix, real wiy, real wiz, real wox, real woy, real woz,
                       real* f) {
  tl_eval_scattering(mat, TL_SCATTERING_SINGLE, wix, wiy, wiz, wox, woy, woz, f);
}

// Direct (unscattered) transmittance toward wo, exp(-tau / |n.wo|): Frisvad's alpha (Eq. 9), the same on both
// sides; 0 in the plane of the layer.
LL_INLINE real tl_transmittance(LL_GLOBAL const scalar* mat, real wox, real woy, real woz) {
  const real mu = tl_abs_cos(wox, woy, woz);
  return mu > LL_HORIZON_EPS ? ll_exp(-mat[0] / LL_FMAX(mu, LL_HORIZON_EPS)) : R(0.0);
}
