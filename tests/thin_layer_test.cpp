// The thin semi-transparent layer (kernels/models/thin_layer.h, SPEC.md section 4): float32 (host build and
// OpenCL kernel) against the double reference on random and hard cases, the naive formulas failing those,
// reciprocity, non-negativity, and the single-scattering formulas against a Monte Carlo slab.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "server/models/registry.h"
#include "tests/naive_formulas.h"
#include "tests/slab_monte_carlo.h"
#include "tests/testing.h"

namespace tl_double {
typedef double real;
#include "common/shim.h"
#include "models/thin_layer.h"
}  // namespace tl_double

namespace tl_float {
typedef float real;
#include "common/shim.h"
#include "models/thin_layer.h"
}  // namespace tl_float

namespace loomlight {
namespace {

using accuracy::Pairs;
constexpr double kPi = 3.14159265358979323846;

const models::Model& ThinLayer() { return *models::Registry::Global().FindModel("thin_layer"); }

models::PackedMaterial Material(double tau, std::array<double, 3> albedo = {0.9, 0.6, 0.3}) {
  models::ParamValues v = ThinLayer().DefaultValues();
  v["tau"] = {tau};
  v["albedo"] = {albedo[0], albedo[1], albedo[2]};
  return ThinLayer().Pack(v);
}

std::vector<double> Reference(const models::PackedMaterial& m, const Pairs& p) {
  std::vector<double> f(3 * p.size());
  ThinLayer().ReferenceEval(m, p.wi.data(), p.wo.data(), nullptr, p.size(), f.data());
  return f;
}

// The host float build of the same source (what the native baseline runs, one thread).
std::vector<double> HostFloat(const models::PackedMaterial& m, const Pairs& p) {
  const std::vector<float> mat(m.data.begin(), m.data.end());
  std::vector<double> f(3 * p.size());
  for (size_t q = 0; q < p.size(); ++q) {
    float out[3];
    const float* a = &p.wi[3 * q];
    const float* b = &p.wo[3 * q];
    tl_float::tl_eval(mat.data(), a[0], a[1], a[2], b[0], b[1], b[2], out);
    for (int c = 0; c < 3; ++c) f[3 * q + c] = out[c];
  }
  return f;
}

// Largest relative error over the values whose reference exceeds `floor`; non-finite values count as 1e30.
double MaxRelError(const std::vector<double>& got, const std::vector<double>& ref, double floor, size_t* counted) {
  double worst = 0;
  *counted = 0;
  for (size_t i = 0; i < ref.size(); ++i) {
    if (!std::isfinite(got[i])) return 1e30;
    if (ref[i] <= floor) continue;
    ++*counted;
    worst = std::max(worst, std::fabs(got[i] - ref[i]) / ref[i]);
  }
  return worst;
}

void ExpectFiniteNonNegative(const std::vector<double>& f, const std::string& what) {
  for (size_t i = 0; i < f.size(); ++i)
    ASSERT_TRUE(std::isfinite(f[i]) && f[i] >= 0) << what << " query " << i / 3 << " f " << f[i];
}

// A float direction with z = z_signed and azimuth phi (z rounded first, so |z| is exactly what is asked).
void PushDirection(std::vector<float>& w, float z, double phi) {
  const double r = std::sqrt(std::max(0.0, 1.0 - double(z) * z));
  w.insert(w.end(), {float(r * std::cos(phi)), float(r * std::sin(phi)), z});
}
void PushPair(Pairs& p, float zi, double phi_i, float zo, double phi_o) {
  PushDirection(p.wi, zi, phi_i);
  PushDirection(p.wo, zo, phi_o);
}

// SPEC.md section 4 hard cases: mu = mu0 exactly (mirror and straight-through pairs) and within 1e-7 (one and
// two float ulps apart, and mu0 (1 +- 1e-7) rounded), mu down to 1e-6, on both sides.
Pairs HardCases() {
  Pairs p;
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> U(0, 2 * kPi);
  const float mus[] = {1e-6f, 1e-5f, 1e-4f, 1e-3f, 0.01f, 0.05f, 0.1f, 0.2f, 0.3f, 0.5f, 0.7f, 0.9f, 0.99f, 1.0f};
  for (float mu0 : mus)
    for (int k = 0; k < 4; ++k) {
      const double phi = U(rng);
      for (float side : {1.0f, -1.0f}) {
        PushPair(p, mu0, phi, side * mu0, phi + kPi);  // mirror (side 1) and straight through (side -1)
        PushPair(p, mu0, phi, side * mu0, U(rng));     // equal mu, another azimuth
        float up = mu0, down = mu0;
        for (int ulp = 1; ulp <= 2; ++ulp) {
          up = std::nextafter(up, 2.0f);
          down = std::nextafter(down, 0.0f);
          if (up <= 1.0f) PushPair(p, mu0, phi, side * up, U(rng));
          PushPair(p, mu0, phi, side * down, U(rng));
        }
        PushPair(p, mu0, phi, side * float(std::min(1.0, mu0 * (1 + 1e-7))), U(rng));
        PushPair(p, mu0, phi, side * float(mu0 * (1 - 1e-7)), U(rng));
        for (float other : {1e-6f, 0.5f, 1.0f}) {  // grazing against everything
          PushPair(p, mu0, phi, side * other, U(rng));
          PushPair(p, other, phi, side * mu0, U(rng));
        }
      }
    }
  return p;
}

// Random pairs over the whole sphere (either side for wi and wo).
Pairs SpherePairs(size_t n, unsigned seed) {
  Pairs p = accuracy::RandomPairs(n, seed);
  std::mt19937 rng(seed + 1);
  for (size_t q = 0; q < n; ++q) {
    if (rng() & 1) p.wi[3 * q + 2] = -p.wi[3 * q + 2];
    if (rng() & 1) p.wo[3 * q + 2] = -p.wo[3 * q + 2];
  }
  return p;
}

const double kHardTaus[] = {0.0, 1e-9, 1e-6, 1e-3, 0.05, 0.2, 1.0, 5.0, 50.0};

// float32 within 1e-5 of double on SPEC's hard cases, for every tau of SPEC's range (0, 1e-9 .. 50). Values
// below 1e-30 are left out: float cannot hold them (exp(-tau/mu) underflows at tau/mu > 87), and a layer
// passing 1e-30 of the light is opaque to any renderer.
TEST(ThinLayer, Float32MatchesDoubleOnHardCases) {
  const Pairs p = HardCases();
  double worst_host = 0, worst_kernel = 0;
  for (double tau : kHardTaus) {
    const models::PackedMaterial m = Material(tau);
    const std::vector<double> ref = Reference(m, p);
    ExpectFiniteNonNegative(ref, "reference");
    const std::vector<double> host = HostFloat(m, p);
    const std::vector<double> kernel = testing::RunKernel(ThinLayer(), m, false, p.wi, p.wo);
    ExpectFiniteNonNegative(host, "host float");
    ExpectFiniteNonNegative(kernel, "fp32 kernel");
    size_t n_host = 0, n_kernel = 0;
    const double e_host = MaxRelError(host, ref, 1e-30, &n_host);
    const double e_kernel = MaxRelError(kernel, ref, 1e-30, &n_kernel);
    std::printf("tau %-6g hard cases (%zu values): host float max rel %.2e, fp32 kernel max rel %.2e\n", tau,
                n_kernel, e_host, e_kernel);
    if (tau == 0.0) {
      for (size_t i = 0; i < ref.size(); ++i) ASSERT_TRUE(ref[i] == 0 && host[i] == 0 && kernel[i] == 0);
    } else {
      EXPECT_GT(n_kernel, ref.size() / 3) << "tau " << tau;  // most values are representable in float
    }
    EXPECT_LE(e_host, 1e-5) << "tau " << tau;
    EXPECT_LE(e_kernel, 1e-5) << "tau " << tau;
    worst_host = std::max(worst_host, e_host);
    worst_kernel = std::max(worst_kernel, e_kernel);
  }
  std::printf("hard cases overall: host float %.2e, fp32 kernel %.2e\n", worst_host, worst_kernel);
}

// The printed formulas in float fail exactly there: 0/0 at mu = mu0 and 1 - exp(-x) = 0 for tiny tau.
TEST(ThinLayer, NaiveFormulasFailTheHardCases) {
  const Pairs p = HardCases();
  for (double tau : {1e-9, 1e-6, 0.05, 1.0}) {
    const models::PackedMaterial m = Material(tau);
    const std::vector<double> ref = Reference(m, p);
    const std::vector<double> naive = naive::ThinLayerFloat(m, p);
    size_t bad = 0, nonfinite = 0;
    double worst_finite = 0;
    for (size_t i = 0; i < ref.size(); ++i) {
      if (!std::isfinite(naive[i])) {
        ++nonfinite;
        continue;
      }
      if (ref[i] <= 1e-30) continue;
      const double e = std::fabs(naive[i] - ref[i]) / ref[i];
      worst_finite = std::max(worst_finite, e);
      bad += e > 1e-5;
    }
    std::printf("tau %-6g naive float: %zu of %zu values NaN/Inf, %zu off by > 1e-5, worst finite rel %.2e\n", tau,
                nonfinite, ref.size(), bad, worst_finite);
    EXPECT_GT(nonfinite, 0u) << "tau " << tau;  // mu = mu0 exactly in transmission: 0/0
    EXPECT_GT(worst_finite, 1e-3) << "tau " << tau;
  }
}

// Random pairs over the sphere for each preset and across tau: fp32 kernel, host float and fp64 kernel.
// float's relative error is set by exp(-tau/mu)'s conditioning, ~(tau/mu) x 1e-7 (mu itself carries half an
// ulp, and tau/mu another): within 1e-5 wherever f > 1e-12 (tau/mu < ~25), within 3e-5 down to 1e-30.
TEST(ThinLayer, KernelsMatchDoubleOnRandomPairs) {
  const Pairs p = SpherePairs(50000, 31);
  std::vector<models::PackedMaterial> mats;
  std::vector<std::string> names;
  for (const models::PresetSpec& preset : ThinLayer().presets()) {
    mats.push_back(ThinLayer().Pack(ThinLayer().PresetValues(preset)));
    names.push_back(preset.name);
  }
  for (double tau : {1e-9, 0.05, 10.0, 100.0}) {
    mats.push_back(Material(tau));
    names.push_back("tau " + std::to_string(tau));
  }
  for (size_t k = 0; k < mats.size(); ++k) {
    const std::vector<double> ref = Reference(mats[k], p);
    ExpectFiniteNonNegative(ref, names[k]);
    const std::vector<double> f32 = testing::RunKernel(ThinLayer(), mats[k], false, p.wi, p.wo);
    const std::vector<double> host = HostFloat(mats[k], p);
    const std::vector<double> f64 = testing::RunKernel(ThinLayer(), mats[k], true, p.wi, p.wo);
    ExpectFiniteNonNegative(f32, names[k]);
    size_t n32 = 0, nh = 0, n64 = 0;
    const double e32 = MaxRelError(f32, ref, 1e-12, &n32), eh = MaxRelError(host, ref, 1e-12, &nh),
                 e64 = MaxRelError(f64, ref, 0.0, &n64);
    size_t n_tiny = 0;
    const double e32_tiny = MaxRelError(f32, ref, 1e-30, &n_tiny);
    const accuracy::Accuracy a32 = accuracy::Compare(f32, ref, 1e-30);
    std::printf("%-22s fp32 %s | above 1e-12: fp32 max %.2e, host float max %.2e | fp64 max %.2e\n",
                names[k].c_str(), a32.ToString().c_str(), e32, eh, e64);
    EXPECT_LE(e32, 1e-5) << names[k];
    EXPECT_LE(e32_tiny, 3e-5) << names[k];
    EXPECT_LE(eh, 1e-5) << names[k];
    EXPECT_LE(e64, 1e-12) << names[k];
  }
}

// f(wi, wo) = f(wo, wi) (both formulas are symmetric in mu, mu0 and evaluated symmetrically: bit-exact),
// in double and in the fp32 kernel; non-negative and finite over the whole sphere and the hard cases.
TEST(ThinLayer, ReciprocalNonNegativeAndFinite) {
  Pairs p = SpherePairs(20000, 8);
  const Pairs hard = HardCases();
  p.wi.insert(p.wi.end(), hard.wi.begin(), hard.wi.end());
  p.wo.insert(p.wo.end(), hard.wo.begin(), hard.wo.end());
  const Pairs swapped{p.wo, p.wi};
  for (double tau : {0.0, 1e-9, 0.3, 2.5, 100.0}) {
    const models::PackedMaterial m = Material(tau, {1, 1, 1});
    const std::vector<double> f = Reference(m, p), g = Reference(m, swapped);
    ExpectFiniteNonNegative(f, "reference");
    for (size_t i = 0; i < f.size(); ++i) ASSERT_EQ(f[i], g[i]) << "tau " << tau << " query " << i / 3;
    const std::vector<double> k = testing::RunKernel(ThinLayer(), m, false, p.wi, p.wo);
    const std::vector<double> ks = testing::RunKernel(ThinLayer(), m, false, swapped.wi, swapped.wo);
    ExpectFiniteNonNegative(k, "fp32 kernel");
    for (size_t i = 0; i < k.size(); ++i) ASSERT_EQ(k[i], ks[i]) << "tau " << tau << " query " << i / 3;
  }
  // Directions in the plane of the layer give 0.
  Pairs flat;
  PushPair(flat, 0.0f, 0.3, 0.5f, 1.0);
  PushPair(flat, 0.5f, 0.3, -0.0f, 1.0);
  PushPair(flat, 5e-8f, 0.3, -0.5f, 1.0);
  for (double v : Reference(Material(0.5), flat)) EXPECT_EQ(v, 0.0);
}

// The once-scattered fraction of incident photons leaving through |mu| in [lo, hi]: 2 pi int f mu dmu
// (f with respect to E_perp, SPEC.md section 1), by Simpson's rule.
double SingleScatteringFraction(double tau, double albedo, double mu0, double lo, double hi, bool reflected) {
  const int n = 2000;
  const double h = (hi - lo) / n;
  double sum = 0;
  for (int j = 0; j <= n; ++j) {
    const double mu = std::max(lo + j * h, 1e-12);
    const double f = albedo / (4 * kPi) * tl_double::tl_single_scattering(tau, mu0, mu, reflected);
    sum += (j == 0 || j == n ? 1 : (j % 2 ? 4 : 2)) * f * mu;
  }
  return 2 * kPi * sum * h / 3;
}

// Every bin of the once-scattered photons' exit cosines, in reflection and transmission, against the
// formulas: within 4 standard errors, with the standard errors themselves well under 1%.
TEST(ThinLayerSlab, OnceScatteredPhotonsMatchSingleScattering) {
  struct Case {
    double tau, albedo, mu0;
  };
  const int bins = 10;
  for (const Case& c : {Case{0.5, 0.8, 0.6}, Case{0.1, 1.0, 0.25}}) {
    const testing::SlabResult mc = testing::SimulateSlab(c.tau, c.albedo, c.mu0, bins, 30000000, 2024);
    double worst_sigmas = 0, worst_rel = 0, worst_noise = 0;
    for (bool reflected : {true, false}) {
      const testing::SlabTallies& t = reflected ? mc.reflected_once : mc.transmitted_once;
      double expected_total = 0;
      for (int b = 0; b < bins; ++b) {
        const double expected =
            SingleScatteringFraction(c.tau, c.albedo, c.mu0, double(b) / bins, double(b + 1) / bins, reflected);
        expected_total += expected;
        const double dev = std::fabs(t.mean[b] - expected);
        worst_sigmas = std::max(worst_sigmas, dev / t.sigma[b]);
        worst_rel = std::max(worst_rel, dev / expected);
        worst_noise = std::max(worst_noise, t.sigma[b] / expected);
        EXPECT_LE(dev, 4 * t.sigma[b]) << (reflected ? "R" : "T") << " bin " << b << " tau " << c.tau;
      }
      std::printf("tau %.2f albedo %.1f mu0 %.2f %s once: MC %.6f +- %.6f, formula %.6f (%+.3f%%)\n", c.tau, c.albedo,
                  c.mu0, reflected ? "reflected  " : "transmitted", t.total, t.total_sigma, expected_total,
                  100 * (t.total / expected_total - 1));
      EXPECT_LE(std::fabs(t.total - expected_total), 4 * t.total_sigma);
      EXPECT_LE(t.total_sigma / expected_total, 2e-3);
    }
    std::printf("  bins: worst deviation %.2f sigma, %.3f%%; worst bin noise %.3f%%\n", worst_sigmas, 100 * worst_rel,
                100 * worst_noise);
    EXPECT_LE(worst_noise, 0.005);  // every bin's standard error well under 1%
  }
}

// The all-orders excess over single scattering (SPEC.md section 4's figures: reflection +10% at tau 0.05 and
// +35% at 0.2 for albedo 1; +2.5% and +9% for albedo 0.3), as reflected fractions for light at normal
// incidence. Asserted roughly: within a third of each figure.
TEST(ThinLayerSlab, AllOrdersExcessMatchesSpec) {
  struct Case {
    double tau, albedo, spec_excess;
  };
  for (const Case& c : {Case{0.05, 1.0, 0.10}, Case{0.2, 1.0, 0.35}, Case{0.05, 0.3, 0.025}, Case{0.2, 0.3, 0.09}}) {
    const testing::SlabResult mc = testing::SimulateSlab(c.tau, c.albedo, 1.0, 1, 2000000, 77);
    const double r = mc.reflected_all.total / mc.reflected_once.total;
    const double t = mc.transmitted_all.total / mc.transmitted_once.total;
    std::printf("tau %.2f albedo %.1f: all orders / single scattering = %.4f in reflection, %.4f in transmission "
                "(SPEC: %+.1f%%)\n",
                c.tau, c.albedo, r, t, 100 * c.spec_excess);
    EXPECT_NEAR(r - 1, c.spec_excess, c.spec_excess / 3) << "tau " << c.tau << " albedo " << c.albedo;
  }
}

}  // namespace
}  // namespace loomlight
