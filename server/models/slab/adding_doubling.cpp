#include "server/models/slab/adding_doubling.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstddef>
#include <utility>

namespace loomlight::slab {
namespace {

constexpr double kFourPi = 4.0 * M_PI;

// psi(d) = (1 - exp(-d)) / d with psi(0) = 1, as tl_psi in kernels/models/thin_layer.h.
double Psi(double d) { return d < 1e-3 ? 1.0 - d * (0.5 - d / 6.0) : -std::expm1(-d) / d; }

// Row-major K x K matrices of f values over all cosines of a solve: the N quadrature nodes first, then the
// requested cosines, which take part in no integral (their quadrature weight is 0), so the integrals are
// those of the N-node discrete-ordinate problem and the requested rows and columns are its exact responses.
struct Grid {
  size_t K = 0, N = 0;
  std::vector<double> mu;
  std::vector<double> weight;  // 2 pi mu_j w_j for j < N: the radiance-to-irradiance factor of a node
};
using Matrix = std::vector<double>;

// out(i, k) (+)= sum over nodes j of A(i, j) weight_j B(j, k) for rows [row_begin, K): light through B, then A.
void Compose(const Grid& g, const Matrix& a, const Matrix& b, Matrix* out, bool accumulate, size_t row_begin = 0) {
  const size_t K = g.K;
  for (size_t i = row_begin; i < K; ++i) {
    double* row = out->data() + i * K;
    if (!accumulate) std::fill(row, row + K, 0.0);
    for (size_t j = 0; j < g.N; ++j) {
      const double s = a[i * K + j] * g.weight[j];
      const double* b_row = b.data() + j * K;
      for (size_t k = 0; k < K; ++k) row[k] += s * b_row[k];
    }
  }
}

// Q = P + P o Q, i.e. the sum of (R o R)^n over n >= 1, the light bouncing between the two halves: a linear
// system on the node rows (I - P_nodes weight) Q_nodes = P_nodes by LU with partial pivoting, then the
// requested rows directly from Q's node rows.
void InterreflectionSeries(const Grid& g, const Matrix& p, Matrix* q) {
  const size_t K = g.K, N = g.N;
  std::vector<double> lu(N * N);
  for (size_t i = 0; i < N; ++i)
    for (size_t j = 0; j < N; ++j) lu[i * N + j] = (i == j ? 1.0 : 0.0) - p[i * K + j] * g.weight[j];
  std::copy(p.begin(), p.begin() + N * K, q->begin());
  for (size_t col = 0; col < N; ++col) {
    size_t pivot = col;
    for (size_t i = col + 1; i < N; ++i)
      if (std::fabs(lu[i * N + col]) > std::fabs(lu[pivot * N + col])) pivot = i;
    if (pivot != col) {
      std::swap_ranges(lu.begin() + col * N, lu.begin() + (col + 1) * N, lu.begin() + pivot * N);
      std::swap_ranges(q->begin() + col * K, q->begin() + (col + 1) * K, q->begin() + pivot * K);
    }
    for (size_t i = col + 1; i < N; ++i) {
      const double m = lu[i * N + col] / lu[col * N + col];
      if (m == 0.0) continue;
      for (size_t j = col + 1; j < N; ++j) lu[i * N + j] -= m * lu[col * N + j];
      for (size_t k = 0; k < K; ++k) (*q)[i * K + k] -= m * (*q)[col * K + k];
    }
  }
  for (size_t i = N; i-- > 0;) {
    double* row = q->data() + i * K;
    for (size_t j = i + 1; j < N; ++j) {
      const double m = lu[i * N + j];
      for (size_t k = 0; k < K; ++k) row[k] -= m * (*q)[j * K + k];
    }
    const double inv = 1.0 / lu[i * N + i];
    for (size_t k = 0; k < K; ++k) row[k] *= inv;
  }
  std::copy(p.begin() + N * K, p.end(), q->begin() + N * K);
  Compose(g, p, *q, q, true, N);
}

// Column k of m times d_k (light passing straight through a layer before m), or row i times d_i (after it).
void ScaleColumns(const Grid& g, const std::vector<double>& d, Matrix* m) {
  for (size_t i = 0; i < g.K; ++i)
    for (size_t k = 0; k < g.K; ++k) (*m)[i * g.K + k] *= d[k];
}

}  // namespace

void GaussLegendre(int n, std::vector<double>* nodes, std::vector<double>* weights) {
  nodes->assign(n, 0.0);
  weights->assign(n, 0.0);
  for (int i = 0; i < (n + 1) / 2; ++i) {
    double x = std::cos(M_PI * (i + 0.75) / (n + 0.5)), dp = 1.0;  // Tricomi's estimate, then Newton
    for (int it = 0; it < 100; ++it) {
      double p0 = 1.0, p1 = x;
      for (int k = 2; k <= n; ++k) {
        const double p2 = ((2 * k - 1) * x * p1 - (k - 1) * p0) / k;
        p0 = p1;
        p1 = p2;
      }
      dp = n * (x * p1 - p0) / (x * x - 1.0);
      const double dx = p1 / dp;
      x -= dx;
      if (std::fabs(dx) < 1e-16) break;
    }
    // x is the i-th largest root on [-1, 1]; map both it and its mirror image to [0, 1].
    const double w = 1.0 / ((1.0 - x * x) * dp * dp);
    (*nodes)[n - 1 - i] = 0.5 * (1.0 + x);
    (*nodes)[i] = 0.5 * (1.0 - x);
    (*weights)[n - 1 - i] = (*weights)[i] = w;
  }
}

double SingleScatteringReflection(double tau, double albedo, double mu, double mu0) {
  const double sum = mu + mu0;
  if (sum == 0.0) return tau > 0.0 && albedo > 0.0 ? DBL_MAX : 0.0;
  if (tau == 0.0) return 0.0;
  // tau (1/mu + 1/mu0) is +inf for a zero cosine, where 1 - exp(-x) = 1: the limit, with no special case.
  const double x = mu * mu0 > 0.0 ? tau * (sum / (mu * mu0)) : INFINITY;
  return albedo / kFourPi * -std::expm1(-x) / sum;
}

double SingleScatteringTransmission(double tau, double albedo, double mu, double mu0) {
  const double mx = std::max(mu, mu0), mn = std::min(mu, mu0);
  if (tau == 0.0 || mx == 0.0) return 0.0;
  const double attenuated = albedo / kFourPi * std::exp(-tau / mx);
  if (mn == 0.0) return attenuated / mx;  // exp(-tau / mn) = 0
  const double d = tau * ((mx - mn) / (mx * mn));
  return attenuated * (d <= 1.0 ? tau / (mx * mn) * Psi(d) : -std::expm1(-d) / (mx - mn));
}

SlabFunctions SolveSlab(double tau, double albedo, const std::vector<double>& mu,
                        const AddingDoublingOptions& options) {
  SlabFunctions out;
  out.mu = mu;
  const size_t n = mu.size();
  for (auto* f : {&out.reflection, &out.transmission, &out.reflection_multiple, &out.transmission_multiple})
    f->assign(n * n, 0.0);
  if (tau <= 0.0 || albedo <= 0.0 || n == 0) return out;

  Grid g;
  std::vector<double> nodes, weights;
  GaussLegendre(options.gauss_nodes, &nodes, &weights);
  g.N = nodes.size();
  g.K = g.N + n;
  g.mu = nodes;
  g.mu.insert(g.mu.end(), mu.begin(), mu.end());
  g.weight.resize(g.N);
  for (size_t j = 0; j < g.N; ++j) g.weight[j] = 2.0 * M_PI * nodes[j] * weights[j];

  const double thickest_start = options.max_initial_tau / std::max(1.0, tau * tau);
  int doublings = 0;
  while (std::ldexp(tau, -doublings) > thickest_start) ++doublings;
  const double dtau = std::ldexp(tau, -doublings);
  out.doublings = doublings;
  out.initial_tau = dtau;

  // The thin starting layer by single scattering. R(0, 0) (both cosines 0, infinite) starts at 0: it feeds
  // no other entry (its direct beam exp(-tau/0) is 0 and requested cosines take part in no integral), so it
  // ends as the multiply scattered part alone.
  const size_t K = g.K;
  Matrix r(K * K), t(K * K);
  std::vector<double> direct(K);
  // exp(-layer / mu) afresh for every layer: squaring exp(-dtau / mu) ~40 times would scale its rounding
  // error by 2^40 in the exponent.
  auto set_direct = [&](double layer) {
    for (size_t i = 0; i < K; ++i) direct[i] = g.mu[i] > 0.0 ? std::exp(-layer / g.mu[i]) : 0.0;
  };
  set_direct(dtau);
  for (size_t i = 0; i < K; ++i) {
    for (size_t k = 0; k < K; ++k) {
      const bool grazing_pair = g.mu[i] + g.mu[k] == 0.0;
      r[i * K + k] = grazing_pair ? 0.0 : SingleScatteringReflection(dtau, albedo, g.mu[i], g.mu[k]);
      t[i * K + k] = SingleScatteringTransmission(dtau, albedo, g.mu[i], g.mu[k]);
    }
  }

  // Doubling: two copies of the layer, E its direct transmission (diagonal), R, T its diffuse f. With
  // Q = sum over n >= 1 of (R R)^n the light bouncing between the halves, the diffuse light going down at
  // the interface is D = T + Q E + Q T, going up U = R E + R D, and the doubled layer has
  // R' = R + E U + T U and T' = E D + T E + T D (Hansen and Travis 1974, Sec. 3): only diffuse light is
  // carried, so the direct beam never has to be subtracted.
  Matrix p(K * K), q(K * K), d(K * K), u(K * K);
  for (int step = 0; step < doublings; ++step) {
    Compose(g, r, r, &p, false);
    InterreflectionSeries(g, p, &q);
    d = q;
    ScaleColumns(g, direct, &d);
    Compose(g, q, t, &d, true);
    for (size_t k = 0; k < K * K; ++k) d[k] += t[k];
    u = r;
    ScaleColumns(g, direct, &u);
    Compose(g, r, d, &u, true);
    // R' = R + E U + T U, T' = E D + T E + T D, the new T built in q (no longer needed).
    Compose(g, t, u, &r, true);
    q = t;
    ScaleColumns(g, direct, &q);
    Compose(g, t, d, &q, true);
    for (size_t i = 0; i < K; ++i)
      for (size_t k = 0; k < K; ++k) {
        r[i * K + k] += direct[i] * u[i * K + k];
        q[i * K + k] += direct[i] * d[i * K + k];
      }
    std::swap(t, q);
    set_direct(std::ldexp(dtau, step + 1));
  }

  for (size_t i = 0; i < n; ++i)
    for (size_t j = 0; j < n; ++j) {
      const size_t from = (g.N + i) * K + g.N + j, to = out.index(i, j);
      const bool grazing_pair = mu[i] + mu[j] == 0.0;
      out.reflection[to] = grazing_pair ? DBL_MAX : r[from];
      out.transmission[to] = t[from];
      out.reflection_multiple[to] =
          grazing_pair ? r[from] : r[from] - SingleScatteringReflection(tau, albedo, mu[i], mu[j]);
      out.transmission_multiple[to] = t[from] - SingleScatteringTransmission(tau, albedo, mu[i], mu[j]);
    }
  return out;
}

}  // namespace loomlight::slab
