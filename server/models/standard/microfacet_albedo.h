// Directional albedos of the standard lobes' microfacet terms (kernels/models/gltf_sheen.h, openpbr.h), by
// quadrature in double: the tables their packing interpolates, built once per process.
#pragma once

#include <functional>
#include <vector>

namespace loomlight::models::standard {

// The integral of f(l, o) cos(theta_l) over the hemisphere of l for a microfacet lobe f = D(h) G(l, o) / ... seen
// from the cosine mu_o > 0, written over half vectors h: f cos(theta_l) dw_l = f mu_l 4 (o.h) dw_h, and h is drawn
// from D(h) cos(theta_h) dw_h = du dphi / (2 pi), so that a lobe however narrow is integrated where it lies.
// `sin_theta_h(u)` inverts D's cumulative distribution in u in [0, 1); `f_over_d(mu_l, o_dot_h)` is f / D (D's
// own factor cancels). Gauss-Legendre with `nodes` points in u and in phi over [0, pi] (f is even in phi).
double MicrofacetAlbedo(double mu_o, const std::function<double(double)>& sin_theta_h,
                        const std::function<double(double, double)>& f_over_d, int nodes);

// The cosines of a table uniform in sqrt(mu) with `count` nodes; the first is `first` instead of 0 (the lobes
// are 0 at mu = 0, so their tables hold the smallest cosine they evaluate).
std::vector<double> SqrtSpacedCosines(int count, double first);

// out[i * inner + k] = value(i, k) for i < outer, k < inner: a table's rows computed on all cores.
std::vector<double> ParallelTable(int outer, int inner, const std::function<double(int, int)>& value);

// Linear interpolation of rows of `row_size` values in a table of rows at ascending `nodes`, at `x` (clamped to
// the nodes' range): the row at x.
std::vector<double> InterpolateRow(const std::vector<double>& table, const std::vector<double>& nodes, int row_size,
                                   double x);

}  // namespace loomlight::models::standard
