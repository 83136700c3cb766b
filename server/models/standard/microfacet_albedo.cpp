#include "server/models/standard/microfacet_albedo.h"

#include <algorithm>
#include <cmath>
#include <thread>

#include "server/models/slab/adding_doubling.h"
#include "server/runtime/parallel_for.h"

namespace loomlight::models::standard {

double MicrofacetAlbedo(double mu_o, const std::function<double(double)>& sin_theta_h,
                        const std::function<double(double, double)>& f_over_d, int nodes) {
  std::vector<double> x, w;
  slab::GaussLegendre(nodes, &x, &w);
  const double ox = std::sqrt(std::max(0.0, 1 - mu_o * mu_o)), oz = mu_o;
  double sum = 0;
  for (int a = 0; a < nodes; ++a) {
    const double s = sin_theta_h(x[a]), c = std::sqrt(std::max(0.0, 1 - s * s));
    if (c <= 0) continue;
    for (int b = 0; b < nodes; ++b) {
      const double phi = M_PI * x[b];
      const double o_dot_h = ox * s * std::cos(phi) + oz * c;
      const double mu_l = 2 * o_dot_h * c - oz;  // l = 2 (o.h) h - o
      if (o_dot_h <= 0 || mu_l <= 0) continue;
      sum += w[a] * w[b] * f_over_d(mu_l, o_dot_h) * mu_l * 4 * o_dot_h / c;
    }
  }
  return sum;  // phi's rule on [0, pi] weighs pi, doubled for [pi, 2 pi], over the 2 pi of dphi / (2 pi)
}

std::vector<double> SqrtSpacedCosines(int count, double first) {
  std::vector<double> mu(count);
  for (int k = 0; k < count; ++k) mu[k] = std::pow(double(k) / (count - 1), 2);
  mu[0] = first;
  return mu;
}

std::vector<double> ParallelTable(int outer, int inner, const std::function<double(int, int)>& value) {
  std::vector<double> table(size_t(outer) * inner);
  runtime::ParallelFor(size_t(outer), int(std::thread::hardware_concurrency()), {}, [&](size_t i) {
    for (int k = 0; k < inner; ++k) table[i * inner + k] = value(int(i), k);
  });
  return table;
}

std::vector<double> InterpolateRow(const std::vector<double>& table, const std::vector<double>& nodes, int row_size,
                                   double x) {
  const double xc = std::clamp(x, nodes.front(), nodes.back());
  const size_t i = std::min<size_t>(std::upper_bound(nodes.begin(), nodes.end(), xc) - nodes.begin(), nodes.size() - 1) - 1;
  const double t = (xc - nodes[i]) / (nodes[i + 1] - nodes[i]);
  std::vector<double> row(row_size);
  for (int k = 0; k < row_size; ++k)
    row[k] = (1 - t) * table[i * row_size + k] + t * table[(i + 1) * row_size + k];
  return row;
}

}  // namespace loomlight::models::standard
