// The standard lobes for export (kernels/models/gltf_sheen.h, openpbr.h; docs/models.md "Standard lobes for
// export"): their distributions' normalisation, the albedo tables against this test's own quadrature, Zeltner et
// al.'s fits against their published table, f against the specifications' formulas written naively here, f at
// hard cases, and the glTF material's energy.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <vector>

#include "server/models/accuracy.h"
#include "server/models/registry.h"
#include "server/models/slab/adding_doubling.h"
#include "tests/testing.h"

namespace sl_double {
typedef double real;
#include "common/shim.h"
#include "common/ggx.h"
#include "models/gltf_sheen.h"
#include "models/openpbr.h"
}  // namespace sl_double

namespace sl_float {
typedef float real;
#include "common/shim.h"
#include "common/ggx.h"
#include "models/gltf_sheen.h"
#include "models/openpbr.h"
}  // namespace sl_float

namespace loomlight {
namespace {

constexpr double kPi = 3.14159265358979323846;
using Vec = std::array<double, 3>;

const models::Model& Model(const char* name) { return *models::Registry::Global().FindModel(name); }

models::ParamValues Values(const char* model, const models::ParamValues& overrides) {
  models::ParamValues v = Model(model).DefaultValues();
  for (const auto& [name, value] : overrides) v[name] = value;
  return v;
}

// The integral of f over [lo, hi] by 48-point Gauss-Legendre on pieces that grow 4 times from `first` at lo:
// resolves a function that varies on the scale `first` near lo and slowly further away.
double Integrate(const std::function<double(double)>& f, double lo, double hi, double first) {
  static const auto rule = [] {
    std::pair<std::vector<double>, std::vector<double>> r;
    slab::GaussLegendre(48, &r.first, &r.second);
    return r;
  }();
  double sum = 0, a = lo, width = first;
  while (a < hi) {
    const double b = std::min(hi, a + width);
    for (size_t k = 0; k < rule.first.size(); ++k) sum += rule.second[k] * (b - a) * f(a + (b - a) * rule.first[k]);
    a = b;
    width *= 4;
  }
  return sum;
}

// The integral over the upper hemisphere of g(w) dw, in (mu, phi): mu by pieces from the horizon (lobes here
// crowd toward grazing), phi by 96-point Gauss-Legendre on each of `phi_pieces` equal arcs.
double Hemisphere(const std::function<double(const Vec&)>& g, double first, int phi_pieces = 4) {
  static const auto rule = [] {
    std::pair<std::vector<double>, std::vector<double>> r;
    slab::GaussLegendre(96, &r.first, &r.second);
    return r;
  }();
  return Integrate(
      [&](double mu) {
        const double s = std::sqrt(std::max(0.0, 1 - mu * mu));
        double ring = 0;
        for (int p = 0; p < phi_pieces; ++p)
          for (size_t k = 0; k < rule.first.size(); ++k) {
            const double phi = 2 * kPi * (p + rule.first[k]) / phi_pieces;
            ring += rule.second[k] * (2 * kPi / phi_pieces) * g({s * std::cos(phi), s * std::sin(phi), mu});
          }
        return ring;
      },
      0, 1, first);
}

Vec Normalized(Vec v) {
  const double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  return {v[0] / l, v[1] / l, v[2] / l};
}
double Dot(const Vec& a, const Vec& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
Vec Half(const Vec& l, const Vec& v) { return Normalized({l[0] + v[0], l[1] + v[1], l[2] + v[2]}); }

// ---- The specifications' formulas, naively (double) ----

// KHR_materials_sheen README, "Sheen distribution" (alphaG the Charlie alpha).
double CharlieD(double alpha, double n_dot_h) {
  const double inv_r = 1 / alpha, sin2h = 1 - n_dot_h * n_dot_h;
  return (2 + inv_r) * std::pow(sin2h, inv_r * 0.5) / (2 * kPi);
}
// README, "Sheen visibility".
double SheenL(double x, double alpha) {
  const double t = (1 - alpha) * (1 - alpha);
  const double a = 21.5473 + t * (25.3245 - 21.5473), b = 3.82987 + t * (3.32435 - 3.82987);
  const double c = 0.19823 + t * (0.16801 - 0.19823), d = -1.97760 + t * (-1.27393 + 1.97760);
  const double e = -4.32054 + t * (-4.85967 + 4.32054);
  return a / (1 + b * std::pow(x, c)) + d * x + e;
}
double LambdaSheen(double cos_theta, double alpha) {
  return std::fabs(cos_theta) < 0.5 ? std::exp(SheenL(cos_theta, alpha))
                                    : std::exp(2 * SheenL(0.5, alpha) - SheenL(1 - cos_theta, alpha));
}
double CharlieV(double alpha, double n_dot_l, double n_dot_v) {
  return 1 / ((1 + LambdaSheen(n_dot_v, alpha) + LambdaSheen(n_dot_l, alpha)) * (4 * n_dot_v * n_dot_l));
}
// The Charlie lobe f_sheen / sheen_color.
double CharlieLobe(double alpha, const Vec& l, const Vec& v) {
  return CharlieD(alpha, Half(l, v)[2]) * CharlieV(alpha, l[2], v[2]);
}

// GGX D as printed (glTF 2.0 Appendix B, OpenPBR).
double GgxD(double alpha, double n_dot_h) {
  const double a2 = alpha * alpha, c2 = n_dot_h * n_dot_h;
  return a2 / (kPi * std::pow(c2 * (a2 - 1) + 1, 2));
}
// Height-correlated Smith G2 from GGX's Lambda(theta) = (sqrt(1 + alpha^2 tan^2 theta) - 1) / 2.
double GgxG2(double alpha, double mu_l, double mu_v) {
  const auto lambda = [&](double mu) { return (std::sqrt(1 + alpha * alpha * (1 - mu * mu) / (mu * mu)) - 1) / 2; };
  return 1 / (1 + lambda(mu_l) + lambda(mu_v));
}
// Fresnel's equations with Snell's law (unpolarised, from outside into eta).
double FresnelDielectric(double eta, double cos_i) {
  cos_i = std::min(cos_i, 1.0);  // a unit vector's dot with itself may round above 1
  const double sin_t = std::sqrt(1 - cos_i * cos_i) / eta, cos_t = std::sqrt(1 - sin_t * sin_t);
  const double rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t), rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
  return (rs * rs + rp * rp) / 2;
}
double SpecularLobe(double alpha, double eta, const Vec& l, const Vec& v) {
  const Vec h = Half(l, v);
  return FresnelDielectric(eta, Dot(v, h)) * GgxD(alpha, h[2]) * GgxG2(alpha, l[2], v[2]) / (4 * l[2] * v[2]);
}

// MaterialX's mx_zeltner_sheen_dir_albedo, _ltc_aInv, _ltc_bInv (x = N.V, y = roughness) and mx_zeltner_sheen_brdf.
double ZeltnerAlbedo(double x, double y) {
  const double s = y * (0.0206607 + 1.58491 * y) / (0.0379424 + y * (1.32227 + y));
  const double m = y * (-0.193854 + y * (-1.14885 + y * (1.7932 - 0.95943 * y * y))) / (0.046391 + y);
  const double o = y * (0.000654023 + (-0.0207818 + 0.119681 * y) * y) / (1.26264 + y * (-1.92021 + y));
  return std::exp(-0.5 * std::pow((x - m) / s, 2)) / (s * std::sqrt(2 * kPi)) + o;
}
double ZeltnerAInv(double x, double y) { return (2.58126 * x + 0.813703 * y) * y / (1 + 0.310327 * x * x + 2.60994 * x * y); }
double ZeltnerBInv(double x, double y) {
  return std::sqrt(1 - x) * (y - 1) * y * y * y / (0.0000254053 + 1.71228 * x - 1.71506 * x * y + 1.34174 * y * y);
}
double ZeltnerD(double y, const Vec& l, const Vec& v) {
  const double len = std::hypot(v[0], v[1]);
  const Vec x_axis = len > 0 ? Vec{v[0] / len, v[1] / len, 0} : Vec{1, 0, 0};
  const Vec y_axis = {-x_axis[1], x_axis[0], 0};  // n x X
  const Vec w = {Dot(l, x_axis), Dot(l, y_axis), l[2]};
  const double a = ZeltnerAInv(v[2], y), b = ZeltnerBInv(v[2], y);
  const Vec wo = {a * w[0] + b * w[2], a * w[1], w[2]};
  const double len2 = Dot(wo, wo);
  return std::max(wo[2], 0.0) / kPi * std::pow(a / len2, 2);
}

// Directional albedos by this test's quadrature over the light's hemisphere (not the plugins' half-vector rule).
double CharlieAlbedoByQuadrature(double alpha, double mu_v) {
  const Vec v = {std::sqrt(1 - mu_v * mu_v), 0, mu_v};
  return Hemisphere([&](const Vec& l) { return l[2] > 0 ? CharlieLobe(alpha, l, v) * l[2] : 0.0; }, 1e-6);
}
double SpecularAlbedoByQuadrature(double alpha, double eta, double mu_v) {
  const Vec v = {std::sqrt(1 - mu_v * mu_v), 0, mu_v};
  return Hemisphere([&](const Vec& l) { return l[2] > 0 ? SpecularLobe(alpha, eta, l, v) * l[2] : 0.0; }, 1e-4, 16);
}

std::vector<double> ReferenceF(const models::Model& model, const models::PackedMaterial& m, const std::vector<float>& wi,
                               const std::vector<float>& wo) {
  std::vector<double> f(wi.size());
  model.ReferenceEval(m, wi.data(), wo.data(), nullptr, wi.size() / 3, f.data());
  return f;
}

// Every pair of `n` seeded random directions of the upper hemisphere (n^2 pairs, n distinct cosines: the tests'
// albedo quadratures run once per direction, not per pair).
struct DirectionGrid {
  std::vector<Vec> directions;
  accuracy::Pairs pairs;  // pair a * n + b: (directions[a], directions[b])
};
DirectionGrid Grid(size_t n, unsigned seed) {
  DirectionGrid g;
  const accuracy::Pairs random = accuracy::RandomPairs(n, seed);
  for (size_t k = 0; k < n; ++k)
    g.directions.push_back(Normalized({random.wi[3 * k], random.wi[3 * k + 1], random.wi[3 * k + 2]}));
  for (size_t a = 0; a < n; ++a)
    for (size_t b = 0; b < n; ++b) {
      g.pairs.wi.insert(g.pairs.wi.end(), &random.wi[3 * a], &random.wi[3 * a] + 3);
      g.pairs.wo.insert(g.pairs.wo.end(), &random.wi[3 * b], &random.wi[3 * b] + 3);
    }
  return g;
}

// ---- Distributions ----

// Charlie's D (the kernel's, through its own log and exp, in double and float) is normalised: the integral of
// D(h) cos(theta_h) over the hemisphere is 1, for alphas from the floor to 1; and it is the README's D.
TEST(StandardLobes, CharlieDistributionIsNormalised) {
  for (double alpha : {GS_SHEEN_ALPHA_MIN, 0.02, 0.1, 0.3, 0.6, 1.0}) {
    // Over t = pi/2 - theta_h (cos theta_h = sin t), from the horizon where the lobe lies: sin^2 theta_h = cos^2 t
    // makes the integrand smooth where it is a power of sin theta_h.
    const auto integral = [&](const std::function<double(double)>& d) {
      return Integrate([&](double t) { return 2 * kPi * d(std::sin(t)) * std::sin(t) * std::cos(t); }, 0, kPi / 2, 1e-3);
    };
    const double naive = integral([&](double c) { return CharlieD(alpha, c); });
    const double ours = integral([&](double c) { return sl_double::gs_charlie_d(1 / alpha, 1 - c * c); });
    const double ours_float = integral([&](double c) {
      return double(sl_float::gs_charlie_d(float(1 / alpha), float(1 - c * c)));
    });
    std::printf("Charlie alpha %.3f: integral of D cos - 1: README %.2e, kernel double %.2e, float %.2e\n", alpha,
                naive - 1, ours - 1, ours_float - 1);
    EXPECT_NEAR(naive, 1, 1e-9);
    EXPECT_NEAR(ours, 1, 1e-9);
    EXPECT_NEAR(ours_float, 1, 2e-6);  // float's log and exp, a few ulp at each of up to 500 powers
    for (double c : {0.0, 0.1, 0.5, 0.9, 0.999})
      EXPECT_NEAR(sl_double::gs_charlie_d(1 / alpha, 1 - c * c), CharlieD(alpha, c), 1e-12 * CharlieD(alpha, 0));
  }
}

TEST(StandardLobes, GgxDistributionIsNormalised) {
  for (double alpha : {LL_GGX_ALPHA_MIN, 0.01, 0.1, 0.5, 1.0}) {
    // In the angle theta_h (D cos sin dtheta), pieces from the normal where the peak, width alpha, lies.
    const double ours = Integrate([&](double t) {
      const double c = std::cos(t), s = std::sin(t);
      return 2 * kPi * sl_double::ll_ggx_d(alpha * alpha, c * c, s * s) * c * s;
    }, 0, kPi / 2, alpha / 8);
    const double naive = Integrate([&](double t) { return 2 * kPi * GgxD(alpha, std::cos(t)) * std::cos(t) * std::sin(t); },
                                   0, kPi / 2, alpha / 8);
    std::printf("GGX alpha %.4f: integral of D cos - 1: printed %.2e, kernel %.2e\n", alpha, naive - 1, ours - 1);
    EXPECT_NEAR(ours, 1, 1e-9);
    EXPECT_NEAR(naive, 1, 1e-7);  // the printed c^2 (alpha^2 - 1) + 1 cancels at alpha 1e-4 (why the kernel's form differs)
  }
}

// The LTC density integrates to 1 over the hemisphere of the light for every view and roughness (its matrix
// keeps z, so the clamped cosine's hemisphere maps onto the light's).
TEST(StandardLobes, LtcDensityIsNormalised) {
  for (double y : {0.05, 0.1, 0.3, 0.6, 1.0})
    for (double mu_v : {0.02, 0.3, 0.7, 1.0}) {
      const double s = std::sqrt(1 - mu_v * mu_v);
      const double ours = Hemisphere([&](const Vec& l) {
        return sl_double::op_fuzz_lobe(y, l[0], l[1], l[2], s, 0, mu_v) * l[2];
      }, 1e-5, 16);
      const double naive = Hemisphere([&](const Vec& l) { return ZeltnerD(y, l, {s, 0, mu_v}); }, 1e-5, 16);
      std::printf("LTC roughness %.2f, N.V %.2f: integral - 1: kernel %.2e, MaterialX's form %.2e\n", y, mu_v,
                  ours - 1, naive - 1);
      EXPECT_NEAR(ours, 1, 1e-6);
      EXPECT_NEAR(naive, 1, 1e-6);
    }
}

// Zeltner et al.'s fits (as MaterialX evaluates them) against the table they were fitted to
// (tizian/ltc-sheen fitting/python/data/ltc_table_sheen_volume.cpp: [roughness i / 31][N.V j / 31] = aInv, bInv,
// albedo). The albedo fit is within 0.01 everywhere sampled here; the matrix fits are looser (aInv 0.09, bInv
// 0.02 at most, measured), which the albedo, not the shape, carries into energy.
TEST(StandardLobes, ZeltnerFitsMatchTheirTable) {
  struct Entry {
    int i, j;
    double a_inv, b_inv, albedo;
  };
  const Entry published[] = {
      {31, 0, 0.72363, 0.00000, 0.74973},  {30, 0, 0.69740, -0.01972, 0.74339}, {30, 31, 0.86677, 0.00002, 0.31508},
      {25, 15, 0.74188, -0.06976, 0.39410}, {22, 20, 0.68809, -0.06521, 0.23828}, {20, 8, 0.54234, -0.11418, 0.45520},
      {20, 31, 0.68186, 0.00002, 0.07179},  {10, 0, 0.11173, -0.17686, 0.69840}, {10, 8, 0.26884, -0.02412, 0.18345},
      {7, 2, 0.11306, -0.04959, 0.45689},   {5, 4, 0.08654, -0.00582, 0.13300},
  };
  double worst_albedo = 0, worst_a = 0, worst_b = 0;
  for (const Entry& e : published) {
    const double y = e.i / 31.0, x = e.j / 31.0;
    const models::PackedMaterial m = Model("openpbr").Pack(Values("openpbr", {{"fuzz_roughness", {y}}}));
    const double albedo = sl_double::op_fuzz_albedo(m.data.data(), x);
    worst_albedo = std::max(worst_albedo, std::fabs(albedo - e.albedo));
    worst_a = std::max(worst_a, std::fabs(sl_double::op_ltc_a_inv(y, x) - e.a_inv));
    worst_b = std::max(worst_b, std::fabs(sl_double::op_ltc_b_inv(y, x) - e.b_inv));
    EXPECT_NEAR(albedo, ZeltnerAlbedo(x, y), 1e-12);
    EXPECT_NEAR(sl_double::op_ltc_a_inv(y, x), ZeltnerAInv(x, y), 1e-12);
    EXPECT_NEAR(sl_double::op_ltc_b_inv(y, x), ZeltnerBInv(x, y), 1e-12);
  }
  std::printf("Zeltner fits against the published table: albedo within %.4f, aInv %.4f, bInv %.4f\n", worst_albedo,
              worst_a, worst_b);
  EXPECT_LT(worst_albedo, 0.012);
  EXPECT_LT(worst_a, 0.1);
  EXPECT_LT(worst_b, 0.025);
}

// ---- Albedo tables ----

// How far the packed albedo slices may lie from the exact E at the kernel's nodes (measured: Charlie 2.1e-3, the
// specular 1.7e-3, both at rows or iors between the tables' nodes).
constexpr double kAlbedoTolerance = 2.5e-3;

// The packed Charlie albedo slice (the plugin's half-vector quadrature, interpolated in sheen_roughness) against
// this test's quadrature of the README's D and V over the light's hemisphere, clamped to 1 as the plugin pins it.
TEST(StandardLobes, CharlieAlbedoMatchesQuadrature) {
  double worst = 0;
  for (double roughness : {0.1, 0.3, 0.5, 0.77, 1.0}) {  // 0.77 lies between the table's rows
    const models::PackedMaterial m =
        Model("gltf_sheen").Pack(Values("gltf_sheen", {{"sheen_roughness", {roughness}}, {"sheen_color", {1, 1, 1}}}));
    const double alpha = std::max(roughness * roughness, GS_SHEEN_ALPHA_MIN);
    double row_worst = 0;
    for (int k = 1; k < GS_ALBEDO_NODES; ++k) {
      const double mu = std::pow(double(k) / (GS_ALBEDO_NODES - 1), 2);
      const double expected = std::min(1.0, CharlieAlbedoByQuadrature(alpha, mu));
      row_worst = std::max(row_worst, std::fabs(m.data[GS_ALBEDO_AT + k] - expected));
    }
    std::printf("Charlie E, sheen_roughness %.2f: packed slice within %.2e of the quadrature\n", roughness, row_worst);
    worst = std::max(worst, row_worst);
  }
  EXPECT_LT(worst, kAlbedoTolerance);
}

// The packed specular albedo slice (interpolated in roughness and F0) against this test's quadrature of GGX with
// Fresnel's equations and G2 from Lambda.
TEST(StandardLobes, SpecularAlbedoMatchesQuadrature) {
  double worst = 0;
  for (auto [roughness, eta] : {std::pair{0.3, 1.5}, {0.55, 1.33}, {0.8, 2.4}, {1.0, 3.0}, {0.45, 1.0}}) {
    const models::PackedMaterial m = Model("openpbr").Pack(
        Values("openpbr", {{"specular_roughness", {roughness}}, {"specular_ior", {eta}}}));
    double row_worst = 0;
    for (int k = 1; k < OP_ALBEDO_NODES; ++k) {
      const double mu = std::pow(double(k) / (OP_ALBEDO_NODES - 1), 2);
      const double expected = SpecularAlbedoByQuadrature(roughness * roughness, eta, mu);
      row_worst = std::max(row_worst, std::fabs(m.data[OP_ALBEDO_AT + k] - expected));
    }
    std::printf("E_spec, roughness %.2f, ior %.2f: packed slice within %.2e of the quadrature\n", roughness, eta,
                row_worst);
    worst = std::max(worst, row_worst);
  }
  EXPECT_LT(worst, kAlbedoTolerance);
}

// ---- f against the formulas ----

// f differs from the formulas only through E: the slices' error at the nodes (kAlbedoTolerance) plus the kernel's
// linear lookup between them, bounded by as much again (measured in all: 1.2e-3 of the base lobe).
constexpr double kLookupTolerance = 2.5e-3;

TEST(StandardLobes, GltfSheenMatchesTheSpecification) {
  const std::vector<models::ParamValues> materials = {
      Model("gltf_sheen").PresetValues(Model("gltf_sheen").presets()[0]),
      Model("gltf_sheen").PresetValues(Model("gltf_sheen").presets()[1]),
      Values("gltf_sheen", {{"base_color", {0.9, 0.5, 0.1}}, {"roughness", {0.3}}, {"sheen_color", {0.2, 1.0, 0.6}},
                            {"sheen_roughness", {0.65}}}),
  };
  const DirectionGrid grid = Grid(12, 48);
  const size_t n = grid.directions.size();
  double worst = 0;
  for (const models::ParamValues& v : materials) {
    const models::PackedMaterial m = Model("gltf_sheen").Pack(v);
    const std::vector<double> f = ReferenceF(Model("gltf_sheen"), m, grid.pairs.wi, grid.pairs.wo);
    const double alpha_b = v.at("roughness")[0] * v.at("roughness")[0];
    const double alpha_s = std::max(std::pow(v.at("sheen_roughness")[0], 2), GS_SHEEN_ALPHA_MIN);
    const std::vector<double>& base = v.at("base_color");
    const std::vector<double>& sheen = v.at("sheen_color");
    const double max3 = *std::max_element(sheen.begin(), sheen.end());
    std::vector<double> e;
    for (const Vec& d : grid.directions) e.push_back(std::min(1.0, CharlieAlbedoByQuadrature(alpha_s, d[2])));
    for (size_t q = 0; q < n * n; ++q) {
      const Vec& l = grid.directions[q / n];
      const Vec& vv = grid.directions[q % n];
      const Vec h = Half(l, vv);
      const double fresnel = 0.04 + 0.96 * std::pow(1 - std::fabs(Dot(vv, h)), 5);
      const double specular = GgxD(alpha_b, h[2]) * GgxG2(alpha_b, l[2], vv[2]) / (4 * l[2] * vv[2]);
      const double scaling = std::min(1 - max3 * e[q % n], 1 - max3 * e[q / n]);
      for (int c = 0; c < 3; ++c) {
        const double base_f = (1 - fresnel) * base[c] / kPi + fresnel * specular;
        const double expected = sheen[c] * CharlieLobe(alpha_s, l, vv) + scaling * base_f;
        const double allowed = max3 * (kAlbedoTolerance + kLookupTolerance) * base_f + 1e-12 * expected;
        const double error = std::fabs(f[3 * q + c] - expected);
        worst = std::max(worst, error / std::max(base_f, 1e-300));
        ASSERT_LE(error, allowed) << "pair " << q << " channel " << c << ": " << f[3 * q + c] << " vs " << expected;
      }
    }
  }
  std::printf("gltf_sheen against the specification: largest error %.2e of the base lobe\n", worst);
}

TEST(StandardLobes, OpenPbrMatchesTheSpecification) {
  const std::vector<models::ParamValues> materials = {
      Model("openpbr").PresetValues(Model("openpbr").presets()[0]),
      Model("openpbr").PresetValues(Model("openpbr").presets()[1]),
      Values("openpbr", {{"base_color", {0.2, 0.6, 0.9}}, {"specular_roughness", {0.45}}, {"specular_ior", {1.8}},
                         {"fuzz_weight", {0.7}}, {"fuzz_color", {1.0, 0.3, 0.5}}, {"fuzz_roughness", {0.25}}}),
  };
  const DirectionGrid grid = Grid(12, 49);
  const size_t n = grid.directions.size();
  double worst = 0;
  for (const models::ParamValues& v : materials) {
    const models::PackedMaterial m = Model("openpbr").Pack(v);
    const std::vector<double> f = ReferenceF(Model("openpbr"), m, grid.pairs.wi, grid.pairs.wo);
    const double roughness = v.at("specular_roughness")[0], eta = v.at("specular_ior")[0];
    const double weight = v.at("fuzz_weight")[0], y = v.at("fuzz_roughness")[0];
    const std::vector<double>& base = v.at("base_color");
    const std::vector<double>& fuzz = v.at("fuzz_color");
    std::vector<double> e_spec;
    for (const Vec& d : grid.directions) e_spec.push_back(SpecularAlbedoByQuadrature(roughness * roughness, eta, d[2]));
    for (size_t q = 0; q < n * n; ++q) {
      const Vec& l = grid.directions[q / n];
      const Vec& vv = grid.directions[q % n];
      const double specular = SpecularLobe(roughness * roughness, eta, l, vv);
      const double albedo = std::clamp(ZeltnerAlbedo(vv[2], y), 0.0, 1.0);
      const double lobe = ZeltnerD(y, l, vv) / l[2];
      for (int c = 0; c < 3; ++c) {
        const double diffuse = base[c] / kPi;
        const double expected =
            weight * fuzz[c] * albedo * lobe + (1 - weight * albedo) * (specular + (1 - e_spec[q % n]) * diffuse);
        const double allowed = (1 - weight * albedo) * (kAlbedoTolerance + kLookupTolerance) * diffuse + 1e-12 * expected;
        const double error = std::fabs(f[3 * q + c] - expected);
        worst = std::max(worst, error / diffuse);
        ASSERT_LE(error, allowed) << "pair " << q << " channel " << c << ": " << f[3 * q + c] << " vs " << expected;
      }
    }
  }
  std::printf("openpbr against the specification: largest error %.2e of the diffuse lobe\n", worst);
}

// ---- Hard cases ----

// f is finite and >= 0 (and 0 below the horizon) at grazing cosines, at the parameters' ends (mirror-smooth and
// fully rough bases, sheen_roughness 0, fuzz_roughness 0, ior 1 and 3), in the double reference, the float host
// build and the OpenCL kernels.
TEST(StandardLobes, HardCasesAreFiniteAndNonNegative) {
  std::vector<float> wi, wo;
  const std::vector<Vec> directions = {{0, 0, 1},      {1, 0, 1e-6},   {-1, 0, 1e-6}, {0, 1, 1e-6},    {0.6, 0, 0.8},
                                       {-0.6, 0, 0.8}, {1, 0, 1e-7},   {1, 0, 0},     {0.3, 0.4, -0.5}, {1, 1e-7, 1e-3},
                                       {1e-7, 0, 1},   {0.999, 0, 0.0447}};
  for (const Vec& a : directions)
    for (const Vec& b : directions) {
      const Vec na = Normalized(a), nb = Normalized(b);
      wi.insert(wi.end(), {float(na[0]), float(na[1]), float(na[2])});
      wo.insert(wo.end(), {float(nb[0]), float(nb[1]), float(nb[2])});
    }
  const size_t n = wi.size() / 3;
  const std::vector<std::pair<const char*, models::ParamValues>> materials = {
      {"gltf_sheen", Values("gltf_sheen", {{"roughness", {0.0}}, {"sheen_roughness", {0.0}}, {"sheen_color", {1, 1, 1}}})},
      {"gltf_sheen", Values("gltf_sheen", {{"roughness", {1.0}}, {"sheen_roughness", {1.0}}, {"sheen_color", {1, 1, 1}},
                                           {"base_color", {1, 1, 1}}})},
      {"gltf_sheen", Values("gltf_sheen", {{"roughness", {0.0}}, {"sheen_roughness", {1.0}}, {"base_color", {0, 0, 0}}})},
      {"openpbr", Values("openpbr", {{"specular_roughness", {0.0}}, {"specular_ior", {3.0}}, {"fuzz_weight", {1.0}},
                                     {"fuzz_roughness", {0.0}}})},
      {"openpbr", Values("openpbr", {{"specular_roughness", {1.0}}, {"specular_ior", {1.0}}, {"fuzz_weight", {1.0}},
                                     {"fuzz_roughness", {1.0}}, {"base_color", {1, 1, 1}}})},
      {"openpbr", Values("openpbr", {{"specular_roughness", {0.0}}, {"specular_ior", {1.5}}, {"fuzz_weight", {0.0}}})},
  };
  for (const auto& [name, v] : materials) {
    const models::Model& model = Model(name);
    const models::PackedMaterial m = model.Pack(v);
    std::vector<double> reference(3 * n);
    std::vector<float> native(3 * n);
    model.ReferenceEval(m, wi.data(), wo.data(), nullptr, n, reference.data());
    model.NativeEval(m, wi.data(), wo.data(), nullptr, n, native.data());
    const std::vector<double> kernel = testing::RunKernel(model, m, false, wi, wo);
    for (size_t q = 0; q < n; ++q)
      for (int c = 0; c < 3; ++c) {
        const size_t i = 3 * q + c;
        for (double value : {reference[i], double(native[i]), kernel[i]}) {
          ASSERT_TRUE(std::isfinite(value) && value >= 0) << name << " pair " << q << ": " << value;
          if (wi[3 * q + 2] <= 0 || wo[3 * q + 2] <= 0) {
            ASSERT_EQ(value, 0) << name << " pair " << q;
          }
        }
      }
  }
}

// ---- Energy ----

// The directional albedo of gltf_sheen with a white base and a white sheen, the integral of f cos over the light's
// hemisphere (the double reference), stays within 1 wherever the Charlie lobe's own albedo does: the albedo
// scaling takes back from the base what the sheen reflects. Near grazing the README's fitted visibility lets the
// Charlie lobe alone exceed 1 (why the model does not declare energy conservation); the second half shows it.
TEST(StandardLobes, GltfSheenConservesEnergyWhereItsSheenDoes) {
  double worst = 0, worst_base = 0;
  for (double roughness : {0.3, 0.6, 1.0})
    for (double sheen_roughness : {0.3, 0.5, 1.0}) {
      const models::PackedMaterial m = Model("gltf_sheen").Pack(
          Values("gltf_sheen", {{"base_color", {1, 1, 1}}, {"roughness", {roughness}}, {"sheen_color", {1, 1, 1}},
                                {"sheen_roughness", {sheen_roughness}}}));
      const models::PackedMaterial base_only = Model("gltf_sheen").Pack(
          Values("gltf_sheen", {{"base_color", {1, 1, 1}}, {"roughness", {roughness}}, {"sheen_color", {0, 0, 0}}}));
      for (double mu_v : {0.05, 0.2, 0.5, 0.8, 1.0}) {
        if (CharlieAlbedoByQuadrature(sheen_roughness * sheen_roughness, mu_v) > 1) continue;
        const Vec v = {std::sqrt(1 - mu_v * mu_v), 0, mu_v};
        // The integrand through the reference in one batch: gather the quadrature's directions first.
        std::vector<float> wi, wo;
        std::vector<Vec> ls;
        Hemisphere([&](const Vec& l) { ls.push_back(l); return 0.0; }, 1e-4, 8);
        for (const Vec& l : ls) {
          wi.insert(wi.end(), {float(l[0]), float(l[1]), float(l[2])});
          wo.insert(wo.end(), {float(v[0]), float(v[1]), float(v[2])});
        }
        const auto albedo_of = [&](const models::PackedMaterial& material) {
          const std::vector<double> f = ReferenceF(Model("gltf_sheen"), material, wi, wo);
          size_t next = 0;
          return Hemisphere([&](const Vec& l) { return f[3 * next++] * l[2]; }, 1e-4, 8);
        };
        const double albedo = albedo_of(m), base_albedo = albedo_of(base_only);
        const double e = CharlieAlbedoByQuadrature(sheen_roughness * sheen_roughness, mu_v);
        worst = std::max(worst, albedo);
        worst_base = std::max(worst_base, base_albedo);
        std::printf("  roughness %.1f, sheen_roughness %.1f, N.V %.2f: albedo %.4f, base alone %.4f, sheen E %.4f\n",
                    roughness, sheen_roughness, mu_v, albedo, base_albedo, e);
        EXPECT_LE(albedo, e + (1 - e) * base_albedo + kAlbedoTolerance)
            << "roughness " << roughness << ", sheen_roughness " << sheen_roughness << ", N.V " << mu_v;
      }
    }
  std::printf("gltf_sheen, white base and sheen: largest directional albedo %.4f (the base alone: %.4f)\n", worst,
              worst_base);
  const double grazing = CharlieAlbedoByQuadrature(0.1 * 0.1, 0.02);
  std::printf("Charlie lobe alone at sheen_roughness 0.1, N.V 0.02: E = %.3f\n", grazing);
  EXPECT_GT(grazing, 1.0);
}

}  // namespace
}  // namespace loomlight
