// The thin layer's all-orders mode (issue 4 item 6): the adding-doubling slab solver
// (server/models/slab/adding_doubling.h) against the Monte Carlo slab counting every order, its limits
// (single scattering as tau or albedo -> 0), energy and reciprocity; the kernel's tables against the solver
// (fp32 and fp64, on and off the table's nodes); and the single-scattering error map for docs/models.md.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "server/models/registry.h"
#include "server/models/slab/adding_doubling.h"
#include "tests/slab_monte_carlo.h"
#include "tests/testing.h"

namespace ad_double {
typedef double real;
#include "common/shim.h"
#include "models/thin_layer.h"
}  // namespace ad_double

namespace loomlight {
namespace {

using accuracy::Pairs;
constexpr double kPi = 3.14159265358979323846;

const models::Model& ThinLayer() { return *models::Registry::Global().FindModel("thin_layer"); }

models::PackedMaterial Material(double tau, std::array<double, 3> albedo, int scattering) {
  models::ParamValues v = ThinLayer().DefaultValues();
  v["tau"] = {tau};
  v["albedo"] = {albedo[0], albedo[1], albedo[2]};
  v["scattering"] = {double(scattering)};
  return ThinLayer().Pack(v);
}

// A float direction with |n.w| = mu (z = side * mu) at azimuth phi.
void PushDirection(std::vector<float>& w, double mu, double side, double phi) {
  const double r = std::sqrt(std::max(0.0, 1.0 - mu * mu));
  w.insert(w.end(), {float(r * std::cos(phi)), float(r * std::sin(phi)), float(side * mu)});
}

// Once-per-bin Gauss-Legendre cosines: bin b of `bins` equal bins of (0, 1] gets nodes [b * per_bin, ...).
struct BinRule {
  std::vector<double> mu, weight;
  int per_bin;
};
BinRule BinQuadrature(int bins, int per_bin) {
  std::vector<double> x, w;
  slab::GaussLegendre(per_bin, &x, &w);
  BinRule rule{{}, {}, per_bin};
  for (int b = 0; b < bins; ++b)
    for (int k = 0; k < per_bin; ++k) {
      rule.mu.push_back((b + x[k]) / bins);
      rule.weight.push_back(w[k] / bins);
    }
  return rule;
}

// Every bin of the exit cosines of photons scattered any number of times, in reflection and transmission,
// against 2 pi int f mu dmu over the bin from the solver (6-point Gauss per bin): within 4 standard errors
// (plus 1e-3 of the value for the solver and the bin quadrature), for SPEC's thin and thick layers.
TEST(AddingDoubling, MatchesMonteCarloSlabAllOrders) {
  const int bins = 10;
  const double mu0 = 0.6;
  const BinRule rule = BinQuadrature(bins, 6);
  std::vector<double> cosines = rule.mu;
  cosines.push_back(mu0);
  const size_t incident = cosines.size() - 1;
  double worst_sigmas = 0;
  for (double albedo : {0.3, 1.0})
    for (double tau : {0.05, 0.2, 1.0, 5.0}) {
      const slab::SlabFunctions s = slab::SolveSlab(tau, albedo, cosines);
      const testing::SlabResult mc = testing::SimulateSlab(tau, albedo, mu0, bins, 1500000, 99);
      for (bool reflected : {true, false}) {
        const testing::SlabTallies& t = reflected ? mc.reflected_all : mc.transmitted_all;
        const std::vector<double>& f = reflected ? s.reflection : s.transmission;
        double expected_total = 0, case_sigmas = 0;
        for (int b = 0; b < bins; ++b) {
          double expected = 0;
          for (int k = b * rule.per_bin; k < (b + 1) * rule.per_bin; ++k)
            expected += 2 * kPi * f[s.index(k, incident)] * rule.mu[k] * rule.weight[k];
          expected_total += expected;
          const double dev = std::fabs(t.mean[b] - expected);
          case_sigmas = std::max(case_sigmas, dev / t.sigma[b]);
          EXPECT_LE(dev, 4 * t.sigma[b] + 1e-3 * expected)
              << (reflected ? "R" : "T") << " bin " << b << " tau " << tau << " albedo " << albedo;
        }
        std::printf("tau %-4g albedo %.1f %s all orders: MC %.6f +- %.6f, solver %.6f (%+.3f%%), worst bin %.2f "
                    "sigma\n", tau, albedo, reflected ? "reflected  " : "transmitted", t.total, t.total_sigma,
                    expected_total, 100 * (t.total / expected_total - 1), case_sigmas);
        EXPECT_LE(std::fabs(t.total - expected_total), 4 * t.total_sigma + 1e-3 * expected_total);
        worst_sigmas = std::max(worst_sigmas, case_sigmas);
      }
    }
  std::printf("worst bin deviation over all cases: %.2f sigma\n", worst_sigmas);
}

// Cosines for the limit tests: table nodes and a few in between, all at least 0.05 (closer to grazing the
// path through even a thin layer is optically thick, and multiple scattering dominates for any tau).
std::vector<double> TestCosines() {
  std::vector<double> mu;
  for (int k = 8; k <= 32; ++k) mu.push_back(k * k / 1024.0);
  for (double m : {0.0523, 0.377, 0.8001}) mu.push_back(m);
  return mu;
}

// Largest (f_all - f_single) / f_single over all pairs, and the largest relative difference between the
// solver's single scattering and the kernel's closed form (ad_double::tl_single_scattering).
double MaxExcessOverSingle(double tau, double albedo, const std::vector<double>& mu, double* worst_closed_form) {
  const slab::SlabFunctions s = slab::SolveSlab(tau, albedo, mu);
  double worst = 0;
  for (size_t i = 0; i < mu.size(); ++i)
    for (size_t j = 0; j < mu.size(); ++j)
      for (bool same_side : {true, false}) {
        const double single = albedo / (4 * kPi) * ad_double::tl_single_scattering(tau, mu[j], mu[i], same_side);
        const double solver_single = same_side ? slab::SingleScatteringReflection(tau, albedo, mu[i], mu[j])
                                               : slab::SingleScatteringTransmission(tau, albedo, mu[i], mu[j]);
        const size_t x = s.index(i, j);
        const double all = same_side ? s.reflection[x] : s.transmission[x];
        const double multiple = same_side ? s.reflection_multiple[x] : s.transmission_multiple[x];
        EXPECT_GE(multiple, -1e-12 * all) << "tau " << tau;  // more orders only add light
        worst = std::max(worst, (all - single) / single);
        *worst_closed_form = std::max(*worst_closed_form, std::fabs(solver_single - single) / single);
      }
  return worst;
}

// As tau -> 0 or albedo -> 0 all orders become single scattering: the excess falls like albedo * tau (times
// a log(1 / tau)), and the solver's single scattering is the kernel's closed form.
TEST(AddingDoubling, ConvergesToSingleScattering) {
  const std::vector<double> mu = TestCosines();
  double closed_form = 0, previous = 1;
  for (double tau : {1e-2, 1e-3, 1e-4, 1e-5}) {
    const double excess = MaxExcessOverSingle(tau, 1.0, mu, &closed_form);
    std::printf("albedo 1, tau %-6g: max (all orders - single) / single = %.3e\n", tau, excess);
    EXPECT_LE(excess, 10 * tau * std::log(1 / tau)) << "tau " << tau;
    EXPECT_LT(excess, previous / 5) << "tau " << tau;
    previous = excess;
  }
  for (double albedo : {1e-2, 1e-3}) {
    const double excess = MaxExcessOverSingle(0.2, albedo, mu, &closed_form);
    std::printf("tau 0.2, albedo %-6g: max (all orders - single) / single = %.3e\n", albedo, excess);
    EXPECT_LE(excess, albedo) << "albedo " << albedo;
  }
  std::printf("solver's single scattering vs the kernel's closed form: max rel %.2e\n", closed_form);
  EXPECT_LE(closed_form, 1e-13);
}

// Flux: R + T_diffuse + exp(-tau / mu0) = 1 for conservative scattering (the quadrature's own nodes integrate
// the exits; what remains is the starting layer's missing orders, ~1e-5), and < 1 with absorption.
TEST(AddingDoubling, ConservesEnergy) {
  std::vector<double> mu, w;
  slab::GaussLegendre(slab::AddingDoublingOptions{}.gauss_nodes, &mu, &w);
  const std::vector<double> incidences = {0.05, 0.3, 0.6, 1.0};
  const size_t n_exit = mu.size();
  mu.insert(mu.end(), incidences.begin(), incidences.end());
  for (double tau : {0.05, 0.2, 1.0, 5.0, 50.0})
    for (double albedo : {1.0, 0.9, 0.3}) {
      const slab::SlabFunctions s = slab::SolveSlab(tau, albedo, mu);
      double worst = 0, largest = 0;
      for (size_t j = n_exit; j < mu.size(); ++j) {
        double total = std::exp(-tau / mu[j]);
        for (size_t i = 0; i < n_exit; ++i)
          total += 2 * kPi * (s.reflection[s.index(i, j)] + s.transmission[s.index(i, j)]) * mu[i] * w[i];
        worst = std::max(worst, std::fabs(1 - total));
        largest = std::max(largest, total);
      }
      if (albedo == 1.0) {
        std::printf("tau %-4g conservative: max |1 - (R + T + direct)| = %.2e\n", tau, worst);
        EXPECT_LE(worst, 3e-5) << "tau " << tau;
      } else {
        EXPECT_LT(largest, 1 - 1e-4) << "tau " << tau << " albedo " << albedo;
      }
    }
}

// f(mu, mu0) = f(mu0, mu) for requested cosines on and off the quadrature's nodes.
TEST(AddingDoubling, Reciprocal) {
  const std::vector<double> mu = TestCosines();
  double worst = 0;
  for (double tau : {0.05, 1.0, 20.0}) {
    const slab::SlabFunctions s = slab::SolveSlab(tau, 0.8, mu);
    for (size_t i = 0; i < mu.size(); ++i)
      for (size_t j = 0; j < i; ++j)
        for (const std::vector<double>* f : {&s.reflection, &s.transmission})
          if ((*f)[s.index(i, j)] > 1e-300)
            worst = std::max(worst, std::fabs((*f)[s.index(i, j)] - (*f)[s.index(j, i)]) / (*f)[s.index(i, j)]);
  }
  std::printf("reciprocity: max |f(mu, mu0) - f(mu0, mu)| / f = %.2e\n", worst);
  EXPECT_LE(worst, 1e-11);
}

// Directions at the given cosines, wo on the same side as wi (reflection) or opposite (transmission); f from
// the solver for every (mu, mu0) pair of `cosines`, in the same order.
struct Queries {
  Pairs pairs;
  std::vector<double> expected;  // RGB
};
Queries SolverQueries(double tau, std::array<double, 3> albedo, const std::vector<double>& cosines) {
  Queries q;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> phi(0, 2 * kPi);
  std::array<slab::SlabFunctions, 3> s;
  for (int c = 0; c < 3; ++c) s[c] = slab::SolveSlab(tau, albedo[c], cosines);
  for (size_t i = 0; i < cosines.size(); ++i)
    for (size_t j = 0; j < cosines.size(); ++j)
      for (double side : {1.0, -1.0}) {
        PushDirection(q.pairs.wi, cosines[j], 1.0, phi(rng));
        PushDirection(q.pairs.wo, cosines[i], side, phi(rng));
        for (int c = 0; c < 3; ++c)
          q.expected.push_back((side > 0 ? s[c].reflection : s[c].transmission)[s[c].index(i, j)]);
      }
  return q;
}

// The fp32 and fp64 kernels in all-orders mode: on the table's nodes they return the solver's f (the
// lookup is exact there; the closed form supplies single scattering), between them the bilinear
// interpolation error, reported as SPEC section 8 asks; the host double path (ReferenceEval) agrees with
// the fp64 kernel.
TEST(AddingDoubling, KernelTablesMatchSolver) {
  std::vector<double> nodes, centres;
  for (int k = 1; k <= 32; ++k) nodes.push_back(k * k / 1024.0);
  for (int k = 0; k < 32; ++k) centres.push_back((k + 0.5) * (k + 0.5) / 1024.0);
  const std::array<double, 3> albedo = {1.0, 0.6, 0.3};
  for (double tau : {0.05, 0.2, 1.0, 5.0}) {
    const models::PackedMaterial m = Material(tau, albedo, TL_SCATTERING_ALL);
    for (bool on_nodes : {true, false}) {
      const Queries q = SolverQueries(tau, albedo, on_nodes ? nodes : centres);
      for (bool fp64 : {false, true}) {
        const std::vector<double> f = testing::RunKernel(ThinLayer(), m, fp64, q.pairs.wi, q.pairs.wo);
        for (double v : f) ASSERT_TRUE(std::isfinite(v) && v >= 0);
        const accuracy::Accuracy a = accuracy::Compare(f, q.expected, 1e-30);
        std::printf("tau %-4g %s %s vs solver: %s\n", tau, fp64 ? "fp64" : "fp32",
                    on_nodes ? "on nodes    " : "cell centres", a.ToString().c_str());
        if (on_nodes) {
          EXPECT_LE(a.max, fp64 ? 1e-5 : 3e-5) << "tau " << tau;  // float directions put mu ~1e-7 off a node
        } else {
          EXPECT_LE(a.p99, 5e-3) << "tau " << tau;
          EXPECT_LE(a.max, 2e-2) << "tau " << tau;
        }
      }
    }
    const Queries q = SolverQueries(tau, albedo, centres);
    std::vector<double> host(q.expected.size());
    ThinLayer().ReferenceEval(m, q.pairs.wi.data(), q.pairs.wo.data(), nullptr, q.pairs.size(), host.data());
    const std::vector<double> f64 = testing::RunKernel(ThinLayer(), m, true, q.pairs.wi, q.pairs.wo);
    EXPECT_LE(accuracy::Compare(f64, host, 0.0).max, 1e-12) << "tau " << tau;
  }
}

// Grazing (mu and mu0 down to 1e-6, and the horizon), mu = mu0, tau 0 and 100: finite, non-negative,
// reciprocal to the bit in both precisions; 0 in the plane of the layer as for single scattering.
TEST(AddingDoubling, KernelHardCasesFiniteAndReciprocal) {
  Pairs p;
  const double mus[] = {0.0, 5e-8, 1e-6, 1e-4, 1e-3, 0.01, 0.5, 1.0};
  for (double a : mus)
    for (double b : mus)
      for (double side : {1.0, -1.0}) {
        PushDirection(p.wi, a, 1.0, 0.3);
        PushDirection(p.wo, b, side, 2.0);
      }
  const Pairs swapped{p.wo, p.wi};
  for (double tau : {0.0, 1e-9, 0.3, 100.0}) {
    const models::PackedMaterial m = Material(tau, {1.0, 0.5, 0.0}, TL_SCATTERING_ALL);
    for (bool fp64 : {false, true}) {
      const std::vector<double> f = testing::RunKernel(ThinLayer(), m, fp64, p.wi, p.wo);
      const std::vector<double> g = testing::RunKernel(ThinLayer(), m, fp64, swapped.wi, swapped.wo);
      for (size_t k = 0; k < f.size(); ++k) {
        ASSERT_TRUE(std::isfinite(f[k]) && f[k] >= 0) << "tau " << tau << " query " << k / 3;
        ASSERT_EQ(f[k], g[k]) << "tau " << tau << " query " << k / 3;
        const size_t query = k / 3;
        const bool in_plane = std::fabs(p.wi[3 * query + 2]) < 1e-7 || std::fabs(p.wo[3 * query + 2]) < 1e-7;
        if (in_plane || tau == 0.0) {
          ASSERT_EQ(f[k], 0.0) << "tau " << tau << " query " << query;
        }
      }
    }
  }
}

// The single-scattering error map for docs/models.md "The thin layer: all scattering orders" (markdown rows): tau x
// albedo, (a) the maximum relative error of single scattering against all orders over the table's nodes with mu,
// mu0 >= 0.1 (the thin layer's KnobErrors()[0], here recomputed from a separate solve); (b) the deficit of the
// reflected and the diffusely transmitted fraction at normal incidence. Also Pack's time per preset.
TEST(AddingDoubling, SingleScatteringErrorMap) {
  const double taus[] = {0.01, 0.05, 0.2, 1.0, 5.0};
  const double albedos[] = {0.1, 0.3, 0.6, 0.9, 1.0};
  std::vector<double> nodes;  // the table's, off the horizon
  for (int k = 1; k <= 32; ++k) nodes.push_back(k * k / 1024.0);
  std::vector<double> mu, w;  // exit cosines for the fractions, then normal incidence
  slab::GaussLegendre(64, &mu, &w);
  mu.push_back(1.0);
  std::string grid_rows, fraction_rows;
  char cell[96];
  for (double tau : taus) {
    std::snprintf(cell, sizeof cell, "| %g |", tau);
    grid_rows += cell;
    fraction_rows += cell;
    for (double albedo : albedos) {
      const double grid = ThinLayer().KnobErrors({{"tau", {tau}}, {"albedo", {albedo, albedo, albedo}}})[0];
      const slab::SlabFunctions g = slab::SolveSlab(tau, albedo, nodes);
      double steep = 0;  // mu, mu0 >= 0.1
      for (size_t i = 0; i < nodes.size(); ++i)
        for (size_t j = 0; j < nodes.size(); ++j) {
          const size_t x = g.index(i, j);
          if (nodes[i] >= 0.1 && nodes[j] >= 0.1)
            steep = std::max({steep, g.reflection_multiple[x] / g.reflection[x],
                              g.transmission_multiple[x] / g.transmission[x]});
        }
      const slab::SlabFunctions s = slab::SolveSlab(tau, albedo, mu);
      double fraction[2][2] = {};  // [reflected?][all orders?]
      for (size_t i = 0; i + 1 < mu.size(); ++i) {
        const size_t x = s.index(i, mu.size() - 1);
        const double weight = 2 * kPi * mu[i] * w[i];
        fraction[1][1] += weight * s.reflection[x];
        fraction[1][0] += weight * (s.reflection[x] - s.reflection_multiple[x]);
        fraction[0][1] += weight * s.transmission[x];
        fraction[0][0] += weight * (s.transmission[x] - s.transmission_multiple[x]);
      }
      const double r = 1 - fraction[1][0] / fraction[1][1], t = 1 - fraction[0][0] / fraction[0][1];
      std::snprintf(cell, sizeof cell, " %.3g%% / %.3g%% |", 100 * grid, 100 * steep);
      grid_rows += cell;
      std::snprintf(cell, sizeof cell, " %.3g%% / %.3g%% |", 100 * r, 100 * t);
      fraction_rows += cell;
      EXPECT_GT(grid, 0.0);
      EXPECT_LE(grid, 1.0);
      EXPECT_NEAR(grid, steep, 1e-6 * steep);  // Pack's estimate covers the same nodes
      if (albedo == 1.0 && (tau == 0.05 || tau == 0.2)) {  // SPEC section 4: +10% and +35% in reflection
        EXPECT_NEAR(fraction[1][1] / fraction[1][0] - 1, tau == 0.05 ? 0.10 : 0.35, tau == 0.05 ? 0.03 : 0.1);
      }
    }
    grid_rows += "\n";
    fraction_rows += "\n";
  }
  std::printf("\nmax relative error of single scattering: Pack's estimate / recomputed, mu, mu0 >= 0.1 (albedo %g..%g):\n%s",
              albedos[0], albedos[4], grid_rows.c_str());
  std::printf("\nnormal incidence, reflected / transmitted fraction: single scattering's deficit:\n%s",
              fraction_rows.c_str());
  for (const models::PresetSpec& preset : ThinLayer().presets()) {
    const auto start = std::chrono::steady_clock::now();
    const models::PackedMaterial m = ThinLayer().Pack(ThinLayer().PresetValues(preset));
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    std::printf("Pack %-15s %.1f ms (%zu values), single-scattering error %.1f%%\n", preset.name.c_str(), ms,
                m.data.size(), 100 * ThinLayer().KnobErrors(ThinLayer().PresetValues(preset))[0]);
  }
}

}  // namespace
}  // namespace loomlight
