// Area of a filled ellipse clipped by an axis-aligned rectangle (Irawan and Marschner 2006, Sec. 5; SPEC.md
// section 3): the woven-cotton BRDF's average of the highlight indicator over a thread-segment window.
// Shared source: compiled as OpenCL C (scalar, floatN lanes, or double) and as C++. Include common/shim.h first.
//
// Ellipse {c + a cos t + b sin t}, filled; a and b are any two conjugate semi-diameters (orthogonal semi-axes
// are the usual case, but nothing here needs orthogonality). Window [x0, x1] x [y0, y1].
//
// Arrangement. M = [a b] maps the unit disk onto the ellipse, so area = |det M| * area(disk ∩ P) with
// P = M^-1 (window - c), a parallelogram (Eq. 7 of the paper). Green's theorem with the disk centre O as the
// reference point splits area(disk ∩ P) over the 4 directed edges of P (counterclockwise): each edge
// contributes the triangle (O, r_a, r_b) over its part [r_a, r_b] inside the disk plus circular sectors for its
// parts outside (their radial projections onto the circle). Writing the sector angles as
// (angle subtended by the whole edge) - (angle theta subtended by [r_a, r_b]), the whole-edge angles sum to the
// winding angle W of P around O, so
//     area(disk ∩ P) = W / 2 - sum_edges B,    B = (theta - |r_a| |r_b| sin theta) / 2,
// where B is the area between the chord [r_a, r_b] and the arc of the same angle (the circular segment
// (theta - sin theta)/2 when both ends lie on the circle, plus a sliver when an end is a corner of P), signed
// + when O is on the window side of the edge. No case analysis: an edge missing the disk has B = 0, and
// W = 2 pi (O inside P), pi (O on an edge), the corner's interior angle (O on a corner) or 0 (outside) is
// decided by exact comparisons of c against the window, never by summing angles (a sum of O(1) angles that
// should be 0 would swamp a tiny segment). The paper's five cases are all this one expression.
//
// Each edge lies on an axis-aligned line, so it is handled in its own 1D frame without forming M^-1: with
// K = adj(M)^T adj(M) (the ellipse's quadratic form times det^2: K11 = ay^2 + by^2, K22 = ax^2 + bx^2,
// K12 = -(ax ay + bx by)), a line at offset dv from c (v = y for horizontal, x for vertical edges) maps to a
// line at distance h = |dv| / e from O, e = sqrt(Kss) being the ellipse's half-extent across the line; it
// cuts the disk in the half chord l = sqrt(1 - h^2) = sqrt((e - |dv|)(e + |dv|)) / e (product form: no
// cancellation near tangency beyond the rounding of e itself); a point at offset s along the line maps to
// tau = (s - m) e / D along it, m = -K12 dv / Kss being the foot of the perpendicular from O, D = |det M|.
// The edge's part inside the disk is [ta, tb] = [max(tau_lo, -l), min(tau_hi, l)], and
//     theta = atan2(h (tb - ta), h^2 + ta tb),   |r_a| |r_b| sin theta = h (tb - ta),
//     1 - |r|^2 = (l - tau)(l + tau)  (exactly 0 at a chord end on the circle).
// Precision: tiny segments are where B matters most relative to the result (a window edge shaving
// 1e-6 of the radius off the ellipse). There B = (theta - sin theta)/2 + (1 - rho) sin theta / 2 with
// rho = |r_a| |r_b|, the first part from its Taylor series theta^3/12 - theta^5/240 + ... below theta = 0.75
// (the closed form loses log2(6/theta^2) bits), the second from 1 - rho = (ea + eb (1 - ea)) / (1 + rho), a sum
// of non-negative terms. Elsewhere B = (theta - h (tb - ta)) / 2 cancels by at most a factor ~6. Sign of theta
// and the winding come from the same exact comparisons, so O on or within rounding of an edge line (theta
// near +-pi, W jumping by 2 pi) stays consistent; an edge whose line passes exactly through O contributes 0.
// A window entirely inside the ellipse returns its own area (x1 - x0)(y1 - y0), exact to one rounding, where
// W / 2 - sum B would carry an absolute error ~ eps * pi (ellipse-sized) into a possibly tiny result.
// What remains is input conditioning: a coordinate known to eps |X| moves the area by up to
// (2 / pi) eps |X| / (minor semi-axis) of the ellipse area, and a segment of depth delta (fraction of the
// radius) by ~ 1.5 eps / delta of itself; the evaluation stays within a small multiple of that.
// Valid for D > 0 and x1 > x0, y1 > y0 (returns 0 otherwise); with real = float, keep the coordinates'
// magnitudes within ~1e-9..1e9 so that the squares (K, D) neither overflow nor underflow. The result is
// clamped to [0, min(pi D, window area)] (rounding only; the clamp's fmin/fmax also map a NaN to 0).

#define LL_EW_SERIES_MAX R(0.75)

// (theta - sin theta) / 2 for 0 <= theta < 0.75 from its Taylor series through theta^15 (the next term is
// < 3e-16 of the sum at 0.75).
LL_INLINE real ll_ew_segment_series(real t) {
  const real u = t * t;
  const real p =
      ((((((R(3.82358186590990820e-13) * u - R(8.02952191841080667e-11)) * u + R(1.25260541927208601e-8)) * u -
          R(1.37786596119929463e-6)) * u + R(9.92063492063492063e-5)) * u - R(4.16666666666666661e-3)) * u +
       R(8.33333333333333287e-2));
  return t * u * p;
}

// Signed B of one window edge (see above), in unit-disk area. dv: offset of the edge's line from c across it;
// g: offset of c from the line toward the window interior (sign decides the side; g = +-dv exactly);
// [slo, shi]: the edge's extent along the line relative to c; kss, e = sqrt(kss): the quadratic-form
// coefficient along the line and the ellipse's half-extent across it; k12, d = |det M| as above.
// *inside: both ends of the edge strictly inside the ellipse.
LL_INLINE real ll_ew_edge(real dv, real g, real slo, real shi, real kss, real e, real k12, real d, mask* inside) {
  const real adv = fabs(dv);
  const real h = adv / e;                             // distance of the mapped line from O
  const real l2 = (e - adv) * (e + adv);              // Kss (1 - h^2)
  const real l = sqrt(LL_FMAX(l2, R(0.0))) / e;       // half chord
  const real m = -k12 * dv / kss;                     // foot of the perpendicular, as an offset s
  const real sc = e / d;                              // disk units per unit of s
  const real tlo = (slo - m) * sc, thi = (shi - m) * sc;
  const real ta = LL_FMAX(tlo, -l), tb = LL_FMIN(thi, l);
  const mask chord = l2 > R(0.0) && ta < tb;
  *inside = l2 > R(0.0) && tlo > -l && thi < l;
  const real cr = h * (tb - ta);                      // |r_a x r_b| = rho sin theta
  const real th = ll_atan2(cr, h * h + ta * tb);      // in [0, pi] on a chord
  const real ea = (l - ta) * (l + ta), eb = (l - tb) * (l + tb);  // 1 - |r|^2, >= 0 on a chord
  const real rho = sqrt(LL_FMAX((R(1.0) - ea) * (R(1.0) - eb), R(0.0)));
  const real omr = (ea + eb * (R(1.0) - ea)) / (R(1.0) + rho);    // 1 - rho
  const real b_series = ll_ew_segment_series(th) + R(0.5) * omr * (cr / LL_FMAX(rho, R(0.5)));
  const real b_direct = R(0.5) * (th - cr);
  const real b = th < LL_EW_SERIES_MAX && rho >= R(0.5) ? b_series : b_direct;
  // Lanes without a chord may hold NaN above (0/0 never arises on a chord); they are selected out here.
  return chord && g != R(0.0) ? (g > R(0.0) ? b : -b) : R(0.0);
}

// Area of {c + a cos t + b sin t, filled} ∩ [x0, x1] x [y0, y1].
LL_INLINE real ll_ellipse_rect_area(real cx, real cy, real ax, real ay, real bx, real by, real x0, real y0,
                                    real x1, real y1) {
  const real k11 = ay * ay + by * by, k22 = ax * ax + bx * bx, k12 = -(ax * ay + bx * by);
  const real det = fabs(ax * by - ay * bx);
  const mask ok = det > R(0.0) && k11 > R(0.0) && k22 > R(0.0) && x1 > x0 && y1 > y0;
  const real d = ok ? det : R(1.0), q11 = ok ? k11 : R(1.0), q22 = ok ? k22 : R(1.0);
  const real ex = sqrt(q22), ey = sqrt(q11);  // half-width and half-height of the ellipse
  const real sx0 = x0 - cx, sx1 = x1 - cx, sy0 = y0 - cy, sy1 = y1 - cy;
  // g of each edge: distance of c from it toward the inside, exactly (x - y == -(y - x) in IEEE arithmetic).
  const real gb = -sy0, gr = sx1, gt = sy1, gl = -sx0;
  mask in_b, in_r, in_t, in_l;
  const real bsum = ll_ew_edge(sy0, gb, sx0, sx1, q11, ey, k12, d, &in_b) +  // bottom, y = y0
                    ll_ew_edge(sx1, gr, sy0, sy1, q22, ex, k12, d, &in_r) +  // right,  x = x1
                    ll_ew_edge(sy1, gt, sx0, sx1, q11, ey, k12, d, &in_t) +  // top,    y = y1
                    ll_ew_edge(sx0, gl, sy0, sy1, q22, ex, k12, d, &in_l);   // left,   x = x0

  // Winding angle of P around O. On a corner it is P's interior angle there: the angle between the mapped
  // edge directions, atan2(D, +-K12) (cos = +-K12 / sqrt(K11 K22), sin = D / sqrt(K11 K22)); + at (x0, y0)
  // and (x1, y1) whose edges run along +-(e_x, e_y), - at the other two.
  const mask all_pos = gb > R(0.0) && gr > R(0.0) && gt > R(0.0) && gl > R(0.0);
  const mask non_neg = gb >= R(0.0) && gr >= R(0.0) && gt >= R(0.0) && gl >= R(0.0);
  const mask corner = (gl == R(0.0) || gr == R(0.0)) && (gb == R(0.0) || gt == R(0.0));
  const real alpha = ll_atan2(d, (gl == R(0.0) && gb == R(0.0)) || (gr == R(0.0) && gt == R(0.0)) ? k12 : -k12);
  const real w = all_pos ? R(2.0) * LL_PI : (non_neg ? (corner ? alpha : LL_PI) : R(0.0));

  const real rect = (x1 - x0) * (y1 - y0);
  const real contained = in_b && in_r && in_t && in_l ? rect : d * (R(0.5) * w - bsum);
  const real area = LL_FMIN(LL_FMAX(contained, R(0.0)), LL_FMIN(LL_PI * d, rect));
  return ok ? area : R(0.0);
}
