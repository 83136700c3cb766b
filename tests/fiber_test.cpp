// Fiber scattering (kernels/models/fiber.h, SPEC.md section 5): i0e, the furnace test of the physically based
// model for every theta_i, the ambient tables against direct quadrature, and float32 (host build and OpenCL
// kernel) against the double reference on random and hard cases (gamma_TT 0.5 degrees, theta_i near 90).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "server/models/registry.h"
#include "tests/testing.h"

namespace fb_double {
typedef double real;
#include "common/shim.h"
#include "models/fiber.h"
}  // namespace fb_double

namespace fb_float {
typedef float real;
#include "common/shim.h"
#include "models/fiber.h"
}  // namespace fb_float

namespace loomlight {
namespace {

using accuracy::Pairs;
constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180;

const models::Model& Fiber() { return *models::Registry::Global().FindModel("fiber"); }

models::PackedMaterial Material(const std::string& preset, const models::ParamValues& overrides = {}) {
  const models::PresetSpec* spec = nullptr;
  EXPECT_EQ(models::Registry::Global().FindPreset(preset, &spec), &Fiber());
  models::ParamValues v = Fiber().PresetValues(*spec);
  for (const auto& [name, value] : overrides) v[name] = value;
  EXPECT_EQ(Fiber().Validate(v), "");
  return Fiber().Pack(v);
}

std::vector<std::string> PresetNames() {
  std::vector<std::string> names;
  for (const models::PresetSpec& p : Fiber().presets()) names.push_back(p.name);
  return names;
}

// w from (theta, phi) in the packed fiber frame: sin(theta) t + cos(theta) (cos(phi) u + sin(phi) v).
std::array<double, 3> Direction(const models::PackedMaterial& m, double theta, double phi) {
  std::array<double, 3> w;
  for (int k = 0; k < 3; ++k)
    w[k] = std::sin(theta) * m.data[FB_T + k] +
           std::cos(theta) * (std::cos(phi) * m.data[FB_U + k] + std::sin(phi) * m.data[FB_V + k]);
  return w;
}

std::array<double, 3> EvalDouble(const models::PackedMaterial& m, const std::array<double, 3>& wi,
                                 const std::array<double, 3>& wo) {
  std::array<double, 3> f;
  fb_double::fb_eval(m.data.data(), m.uniform, wi[0], wi[1], wi[2], wo[0], wo[1], wo[2], f.data());
  return f;
}

// Simpson nodes and weights on [-pi/2, pi/2], `per_width` nodes per width of the narrowest lobe.
struct Simpson {
  Simpson(double narrowest, double per_width) {
    n = std::max(64, 2 * int(std::ceil(kPi / (narrowest / per_width) / 2)));
    h = kPi / n;
  }
  double node(int j) const { return -kPi / 2 + j * h; }
  double weight(int j) const { return h / 3 * (j == 0 || j == n ? 1 : (j % 2 ? 4 : 2)); }
  int n;
  double h;
};

double NarrowestLobe(const models::PackedMaterial& m) {
  return std::min(1 / m.data[FB_LOBE_R], 1 / m.data[FB_LOBE_TT]);
}

// int int g(theta, phi) cos^2(theta) dtheta dphi over theta in [-pi/2, pi/2] (Simpson) and phi (trapezoid,
// exact to rounding for the smooth periodic lobes once the nodes resolve them).
template <class F>
std::array<double, 3> SphereIntegral(const Simpson& theta, int n_phi, F&& g) {
  std::array<double, 3> sum = {0, 0, 0};
  for (int j = 0; j <= theta.n; ++j) {
    const double th = theta.node(j), w = theta.weight(j) * std::cos(th) * std::cos(th) * (2 * kPi / n_phi);
    for (int k = 0; k < n_phi; ++k) {
      const std::array<double, 3> f = g(th, 2 * kPi * k / n_phi);
      for (int c = 0; c < 3; ++c) sum[c] += w * f[c];
    }
  }
  return sum;
}

TEST(FiberI0e, MatchesBesselAndAsymptotics) {
  for (double k : {1e-3, 0.4, 1.0, 5.0, 19.9, 20.0, 20.1, 50.0, 200.0, 700.0}) {
    const double want = std::cyl_bessel_i(0.0, k) * std::exp(-k);
    EXPECT_NEAR(fb_double::fb_i0e(k), want, 1e-13 * want) << "kappa " << k;
  }
  // gamma_TT = 0.5 degrees: kappa = 13131, where I0 itself is ~1e5700; three asymptotic terms suffice.
  const double k = 1 / (0.5 * kDeg * 0.5 * kDeg);
  const double want = (1 + 1 / (8 * k) + 9 / (128 * k * k)) / std::sqrt(2 * kPi * k);
  EXPECT_NEAR(fb_double::fb_i0e(k), want, 1e-12 * want);
}

// SPEC.md section 5: with C_TT = 1, int f cos^2(theta_o) dtheta_o dphi_o = Fs + (1 - Fs) = 1 for every theta_i,
// including theta_i within 0.01 degrees of 90 and gamma_TT = 0.5 degrees (kappa = 13131).
TEST(FiberFurnace, IntegratesToOneForEveryThetaI) {
  struct Case {
    std::string preset;
    double gamma_tt;  // degrees; 0 keeps the preset's
    int n_phi;
  };
  std::vector<Case> cases;
  for (const std::string& name : PresetNames()) cases.push_back({name, 0, 128});
  cases.push_back({"fleece", 0.5, 4096});
  double worst = 0;
  for (const Case& c : cases) {
    models::ParamValues over = {{"c_tt", {1, 1, 1}}};
    if (c.gamma_tt > 0) over["gamma_tt"] = {c.gamma_tt};
    const models::PackedMaterial m = Material(c.preset, over);
    const Simpson theta(NarrowestLobe(m), 16);
    const std::vector<double> thetas_i =
        c.gamma_tt > 0 ? std::vector<double>{0, 60, 89.99} : std::vector<double>{-89.99, -60, 0, 30, 85, 89.9, 89.99};
    for (double theta_i : thetas_i) {
      const auto wi = Direction(m, theta_i * kDeg, 0.7);
      const std::array<double, 3> e =
          SphereIntegral(theta, c.n_phi, [&](double th, double ph) { return EvalDouble(m, wi, Direction(m, th, ph)); });
      double dev = 0;
      for (double v : e) dev = std::max(dev, std::fabs(v - 1));
      std::printf("%-10s gamma_TT %-6g theta_i %7.2f: furnace %.9f %.9f %.9f\n", c.preset.c_str(),
                  c.gamma_tt > 0 ? c.gamma_tt : m.data[FB_KAPPA] > 0 ? 1 / std::sqrt(m.data[FB_KAPPA]) / kDeg : 0,
                  theta_i, e[0], e[1], e[2]);
      EXPECT_LE(dev, 2e-5) << c.preset << " theta_i " << theta_i;
      worst = std::max(worst, dev);
    }
  }
  std::printf("furnace: worst |integral - 1| = %.2e\n", worst);
}

// The packed ambient tables (Eqs. 7-10) against direct quadrature of int f(wi, wo) cos(theta_i) dw_i over
// the sphere, in both modes and with a Lambertian part; and the float build's lookup against the double's.
TEST(FiberAmbient, TablesMatchDirectQuadrature) {
  struct Case {
    std::string preset;
    models::ParamValues over;
  };
  std::vector<Case> cases;
  for (const std::string& name : PresetNames()) cases.push_back({name, {}});
  cases.push_back({"silk", {{"kd", {0.3, 0.2, 0.1}}}});
  cases.push_back({"fleece", {{"mode", {0}}, {"ks", {0.5, 0.3, 0.2}}, {"beta", {4}}, {"kd", {0.2, 0.2, 0.2}}}});
  double worst = 0, worst_float = 0;
  for (const Case& c : cases) {
    const models::PackedMaterial m = Material(c.preset, c.over);
    const std::vector<float> mf(m.data.begin(), m.data.end());
    const double narrowest = m.uniform == FB_MODE_SIMPLE ? 2 * std::sqrt(0.5 / m.data[FB_INV_2B2]) : NarrowestLobe(m);
    const Simpson theta(narrowest, 16);
    // Nodes and midpoints of the table and angles between them, up to 89.99 degrees.
    for (double theta_o : {0.0, 10.0, 33.3, 45.0, 60.0, 80.0, 87.0, 89.0, 89.9, 89.99, -45.0, -89.9}) {
      const auto wo = Direction(m, theta_o * kDeg, 0.4);
      const std::array<double, 3> direct =
          SphereIntegral(theta, 128, [&](double th, double ph) { return EvalDouble(m, Direction(m, th, ph), wo); });
      std::array<double, 3> table;
      fb_double::fb_ambient(m.data.data(), wo[0], wo[1], wo[2], table.data());
      float table_f[3];
      fb_float::fb_ambient(mf.data(), float(wo[0]), float(wo[1]), float(wo[2]), table_f);
      for (int ch = 0; ch < 3; ++ch) {
        if (direct[ch] < 1e-6) continue;  // polyester's green C_TT = 0 with a dark R lobe at grazing angles
        const double e = std::fabs(table[ch] - direct[ch]) / direct[ch];
        const double ef = std::fabs(table_f[ch] - table[ch]) / table[ch];
        EXPECT_LE(e, 2e-3) << c.preset << " theta_o " << theta_o << " channel " << ch;
        EXPECT_LE(ef, 1e-5) << c.preset << " theta_o " << theta_o << " channel " << ch;
        worst = std::max(worst, e);
        worst_float = std::max(worst_float, ef);
      }
      if (theta_o == 45.0)
        std::printf("%-10s mode %d ambient at theta_o 45: table %.6f %.6f %.6f, quadrature %.6f %.6f %.6f\n",
                    c.preset.c_str(), m.uniform, table[0], table[1], table[2], direct[0], direct[1], direct[2]);
    }
  }
  std::printf("ambient tables: worst relative error against quadrature %.2e; float lookup against double %.2e\n",
              worst, worst_float);
}

void Push(Pairs& p, const std::array<double, 3>& wi, const std::array<double, 3>& wo) {
  for (int k = 0; k < 3; ++k) {
    p.wi.push_back(float(wi[k]));
    p.wo.push_back(float(wo[k]));
  }
}

std::vector<double> Reference(const models::PackedMaterial& m, const Pairs& p) {
  std::vector<double> f(3 * p.size());
  Fiber().ReferenceEval(m, p.wi.data(), p.wo.data(), nullptr, p.size(), f.data());
  return f;
}

std::vector<double> HostFloat(const models::PackedMaterial& m, const Pairs& p) {
  const std::vector<float> mat(m.data.begin(), m.data.end());
  std::vector<double> f(3 * p.size());
  for (size_t q = 0; q < p.size(); ++q) {
    float out[3];
    const float* a = &p.wi[3 * q];
    const float* b = &p.wo[3 * q];
    fb_float::fb_eval(mat.data(), m.uniform, a[0], a[1], a[2], b[0], b[1], b[2], out);
    for (int c = 0; c < 3; ++c) f[3 * q + c] = out[c];
  }
  return f;
}

void ExpectFiniteNonNegative(const std::vector<double>& f, const std::string& what) {
  for (size_t i = 0; i < f.size(); ++i)
    ASSERT_TRUE(std::isfinite(f[i]) && f[i] >= 0) << what << " query " << i / 3 << " f " << f[i];
}

// Relative errors over the values above floor_fraction x the largest reference value.
accuracy::Accuracy Errors(const std::vector<double>& got, const std::vector<double>& ref, double floor_fraction) {
  const double peak = *std::max_element(ref.begin(), ref.end());
  return accuracy::Compare(got, ref, floor_fraction * peak);
}

// SPEC.md section 5 hard cases around both lobes' peaks: theta_i up to 0.001 degrees from 90, wo on the
// specular cone (theta_o = -theta_i) and near the forward direction -wi (the TT peak), offset by fractions of
// the lobe widths.
Pairs HardCases(const models::PackedMaterial& m, double width) {
  Pairs p;
  std::mt19937 rng(3);
  std::normal_distribution<double> N(0, 1);
  std::uniform_real_distribution<double> U(0, 2 * kPi);
  for (double theta_i : {0.0, 30.0, -60.0, 85.0, 89.0, 89.9, 89.99, 89.999, -89.99})
    for (int k = 0; k < 60; ++k) {
      const double phi_i = U(rng), t = theta_i * kDeg;
      const auto wi = Direction(m, t, phi_i);
      Push(p, wi, Direction(m, -t + width * N(rng), phi_i + kPi + width * N(rng)));  // TT peak
      Push(p, wi, Direction(m, -t + width * N(rng), U(rng)));                        // R cone
      Push(p, wi, Direction(m, -t, phi_i + kPi));                                    // exactly forward
      Push(p, wi, Direction(m, -t, phi_i));                                          // exactly backward
      Push(p, Direction(m, -t, phi_i + kPi + width * N(rng)), wi);                   // swapped
    }
  return p;
}

// float32 against double: random pairs over the sphere for every preset and the simple model, and the hard
// cases with the presets' gamma_TT and with gamma_TT = 0.5 degrees. In a Gaussian tail exp(-E) amplifies the
// rounding of its argument E times, so the bound depends on how far out a value sits: 1e-5 down to 1e-3 of the
// material's peak everywhere (E < 7) and on the hard cases down to 1e-6 (E < 14); 5e-5 down to 1e-6 on random
// pairs. The packed frame is float-representable, so a tilted axis is the same axis in both precisions, but
// the projections onto it are rounded (along x they are exact), which the lobe peaks amplify: 3x for it.
TEST(FiberAccuracy, Float32MatchesDoubleOnRandomAndHardCases) {
  struct Case {
    std::string preset;
    models::ParamValues over;
  };
  std::vector<Case> cases;
  for (const std::string& name : PresetNames()) cases.push_back({name, {}});
  cases.push_back({"silk", {{"gamma_tt", {0.5}}}});
  cases.push_back({"fleece", {{"gamma_tt", {0.5}}, {"beta_r", {0.5}}, {"beta_tt", {0.5}}}});
  cases.push_back({"fleece", {{"mode", {0}}, {"kd", {0.3, 0.2, 0.1}}}});
  cases.push_back({"cotton", {{"axis", {0.3, -0.5, 0.8}}, {"kd", {0.1, 0.1, 0.1}}}});
  Pairs random = accuracy::RandomPairs(50000, 99);
  std::mt19937 rng(4);
  for (size_t q = 0; q < random.size(); ++q) {
    if (rng() & 1) random.wi[3 * q + 2] = -random.wi[3 * q + 2];
    if (rng() & 1) random.wo[3 * q + 2] = -random.wo[3 * q + 2];
  }
  for (const Case& c : cases) {
    const models::PackedMaterial m = Material(c.preset, c.over);
    const double gamma = 1 / std::sqrt(m.data[FB_KAPPA]);
    std::string name = c.preset + (c.over.count("gamma_tt") ? " gamma_TT 0.5" : "") +
                       (c.over.count("beta_r") ? " beta 0.5" : "") + (m.uniform == 0 ? " simple" : "") +
                       (c.over.count("axis") ? " tilted axis" : "");
    for (bool hard : {false, true}) {
      const Pairs p = hard ? HardCases(m, std::min({gamma, 1 / m.data[FB_LOBE_R], 1 / m.data[FB_LOBE_TT]})) : random;
      const std::vector<double> ref = Reference(m, p);
      ExpectFiniteNonNegative(ref, name + " reference");
      const std::vector<double> f32 = testing::RunKernel(Fiber(), m, false, p.wi, p.wo);
      const std::vector<double> host = HostFloat(m, p);
      ExpectFiniteNonNegative(f32, name + " fp32 kernel");
      ExpectFiniteNonNegative(host, name + " host float");
      const accuracy::Accuracy e32 = Errors(f32, ref, 1e-6), eh = Errors(host, ref, 1e-6);
      const accuracy::Accuracy e32_core = Errors(f32, ref, 1e-3), eh_core = Errors(host, ref, 1e-3);
      std::printf("%-30s %s fp32 %s | above 1e-3 peak: fp32 max %.2e | host float max %.2e, %.2e\n", name.c_str(),
                  hard ? "hard  " : "random", e32.ToString().c_str(), e32_core.max, eh.max, eh_core.max);
      const double tilt = c.over.count("axis") ? 3.0 : 1.0;
      EXPECT_LE(e32_core.max, 1e-5 * tilt) << name << (hard ? " hard" : " random");
      EXPECT_LE(eh_core.max, 1e-5 * tilt) << name << (hard ? " hard" : " random");
      EXPECT_LE(e32.max, (hard ? 1e-5 : 5e-5) * tilt) << name << (hard ? " hard" : " random");
      EXPECT_LE(eh.max, (hard ? 1e-5 : 5e-5) * tilt) << name << (hard ? " hard" : " random");
      if (!hard) {
        const std::vector<double> f64 = testing::RunKernel(Fiber(), m, true, p.wi, p.wo);
        EXPECT_LE(Errors(f64, ref, 0.0).max, 1e-9) << name;
      }
    }
  }
}

// A direction exactly along the axis (theta = 90 degrees, phi undefined) and the ends of every range stay
// finite: gamma_TT = 0.5 degrees, beta = 0.5 degrees, theta_i = 90 exactly.
TEST(FiberAccuracy, AxisDirectionsAndNarrowestLobesAreFinite) {
  const models::PackedMaterial m =
      Material("fleece", {{"gamma_tt", {0.5}}, {"beta_r", {0.5}}, {"beta_tt", {0.5}}, {"kd", {1, 1, 1}}});
  Pairs p;
  const std::array<double, 3> t = {1, 0, 0}, mt = {-1, 0, 0};
  for (const auto& w : {Direction(m, 0.3, 1.0), Direction(m, -1.2, 4.0), t, mt}) {
    Push(p, t, w);
    Push(p, w, t);
    Push(p, mt, w);
  }
  for (bool fp64 : {false, true}) ExpectFiniteNonNegative(testing::RunKernel(Fiber(), m, fp64, p.wi, p.wo), "kernel");
  ExpectFiniteNonNegative(Reference(m, p), "reference");
  ExpectFiniteNonNegative(HostFloat(m, p), "host float");
}

}  // namespace
}  // namespace loomlight
