// The woven-cotton model of Irawan and Marschner (kernels/models/woven.h, SPEC.md section 3), compiled as
// C++ with real = double and real = float: BRDF = mean of the BTF over a repeat (dense quadrature), exact
// reciprocity, non-negative and finite results on random and hard cases, and float against double.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "server/models/registry.h"
#include "server/models/weave/pattern.h"

namespace wv_double {
typedef double real;
#include "common/shim.h"
#include "common/ellipse_window.h"
#include "models/woven.h"
}  // namespace wv_double

namespace wv_float {
typedef float real;
#include "common/shim.h"
#include "common/ellipse_window.h"
#include "models/woven.h"
}  // namespace wv_float

namespace {

namespace weave = loomlight::models::weave;
constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180;

struct Thread {
  double kd[3], ks[3], sx, sy, alpha, ecc, phi_deg, kx, ky;
};

// The paper's twill thread parameters (Sec. 4, the cotton_twill preset of SPEC.md section 3); kd, ks are
// chosen here: a dark dye with a brighter, differently tinted highlight per thread type so that a mixed-up
// channel or thread shows.
const Thread kWarp = {{0.05, 0.04, 0.03}, {0.70, 0.65, 0.60}, 1.0, 6.0, 3.0, 0.995, 95.0, 1.5, 3.1};
const Thread kWeft = {{0.03, 0.04, 0.06}, {0.50, 0.55, 0.62}, 1.0, 2.0, 1.0, 0.9, 80.0, 3.7, 1.6};

std::vector<double> Pack(double eta, double warp_fraction, const Thread& warp, const Thread& weft) {
  std::vector<double> m = {eta, warp_fraction};
  for (const Thread* t : {&warp, &weft}) {
    for (double v : t->kd) m.push_back(v);
    for (double v : t->ks) m.push_back(v);
    for (double v : {t->sx, t->sy, t->alpha, t->ecc, std::cos(t->phi_deg * kDeg), std::sin(t->phi_deg * kDeg),
                     t->kx, t->ky})
      m.push_back(v);
  }
  return m;
}

weave::WeavePattern Twill31() {
  weave::WeavePattern p;
  EXPECT_EQ(weave::MakeTwill(3, 1, weave::TwillDirection::kRightward, &p), "");
  return p;
}

std::vector<double> TwillMaterial(const weave::WeavePattern& p) {
  return Pack(1.5, weave::ComputeAreaFractions(p).warp, kWarp, kWeft);
}

std::vector<float> ToFloat(const std::vector<double>& m) { return std::vector<float>(m.begin(), m.end()); }

using Vec = std::array<double, 3>;
Vec Normalize(Vec v) {
  const double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  return {v[0] / l, v[1] / l, v[2] / l};
}
double Dot(const Vec& a, const Vec& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
Vec Reflect(const Vec& w, const Vec& h) {
  const double d = 2 * Dot(w, h);
  return {d * h[0] - w[0], d * h[1] - w[1], d * h[2] - w[2]};
}
// Uniform on the upper hemisphere, rounded to float (the API's input type), so double and float see the
// same input.
Vec RandomUpper(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> U(0, 1);
  const double z = U(rng), phi = 2 * kPi * U(rng), r = std::sqrt(std::max(0.0, 1 - z * z));
  return {double(float(r * std::cos(phi))), double(float(r * std::sin(phi))), double(float(z))};
}

std::array<double, 3> BrdfD(const std::vector<double>& m, const Vec& wi, const Vec& wo) {
  std::array<double, 3> f;
  wv_double::wv_brdf(m.data(), wi[0], wi[1], wi[2], wo[0], wo[1], wo[2], f.data());
  return f;
}
std::array<float, 3> BrdfF(const std::vector<float>& m, const Vec& wi, const Vec& wo) {
  std::array<float, 3> f;
  wv_float::wv_brdf(m.data(), float(wi[0]), float(wi[1]), float(wi[2]), float(wo[0]), float(wo[1]),
                    float(wo[2]), f.data());
  return f;
}
std::array<double, 3> BtfD(const std::vector<double>& m, int t, double x, double y, const Vec& wi, const Vec& wo) {
  std::array<double, 3> f;
  wv_double::wv_btf_local(m.data(), t, x, y, wi[0], wi[1], wi[2], wo[0], wo[1], wo[2], f.data());
  return f;
}
std::array<float, 3> BtfF(const std::vector<float>& m, int t, float x, float y, const Vec& wi, const Vec& wo) {
  std::array<float, 3> f;
  wv_float::wv_btf_local(m.data(), t, x, y, float(wi[0]), float(wi[1]), float(wi[2]), float(wo[0]),
                         float(wo[1]), float(wo[2]), f.data());
  return f;
}

// wv_locate against weave::ExtractFloats: every cell of every float, at an interior point, maps to that
// float's type and to the local coordinates of the documented layout.
void CheckLocate(const weave::WeavePattern& p, const std::vector<double>& m) {
  const int W = p.warps, P = p.picks;
  for (const weave::Float& f : weave::ExtractFloats(p)) {
    const Thread& th = f.warp ? kWarp : kWeft;
    for (int k = 0; k < f.length; ++k) {
      const int w = f.warp ? f.start_warp : (f.start_warp + k) % W;
      const int pk = f.warp ? (f.start_pick + k) % P : f.start_pick;
      const double fu = 0.3, fv = 0.8;
      int t;
      double lx, ly;
      wv_double::wv_locate(p.cells.data(), W, P, (w + fu) / W, (pk + fv) / P, &t, &lx, &ly, m.data());
      SCOPED_TRACE(weave::ToString(f) + " cell " + std::to_string(k));
      EXPECT_EQ(t, f.warp ? 0 : 1);
      const double want_x = f.warp ? th.sx * fu : th.sx * (1 - fv);
      const double want_y = th.sy * ((k + (f.warp ? fv : fu)) / f.length);
      EXPECT_NEAR(lx, want_x, 1e-12);
      EXPECT_NEAR(ly, want_y, 1e-12);
    }
  }
}

TEST(WovenModel, LocateMatchesExtractFloats) {
  const weave::WeavePattern twill = Twill31();
  CheckLocate(twill, TwillMaterial(twill));
  CheckLocate(weave::PlainWeave(), TwillMaterial(weave::PlainWeave()));
  weave::WeavePattern satin;
  ASSERT_EQ(weave::MakeSatin(5, 2, weave::SatinFace::kWarpFaced, &satin), "");
  CheckLocate(satin, TwillMaterial(satin));
  // A thread on top over the whole repeat (one self-joining float) and a wrapping float.
  const weave::WeavePattern odd = {3, 2, {1, 0, 0, 1, 0, 1}};
  CheckLocate(odd, TwillMaterial(odd));
}

// The kernel's BTF (wv_btf: float lookup in the packed cell table, both thread types selected per lane)
// against the independent host walk (wv_locate over the cells, then wv_btf_local), on materials packed by the
// registered model: the same value, to the bit, at random and boundary texture positions, for standard
// weaves, a pattern with non-interlacing threads and wrapping floats, and a random one.
TEST(WovenModel, PackedCellTableBtfEqualsLocatedBtf) {
  const loomlight::models::Model& model = *loomlight::models::Registry::Global().FindModel("woven");
  weave::WeavePattern satin, random_pattern{7, 5, {}};
  ASSERT_EQ(weave::MakeSatin(5, 2, weave::SatinFace::kWeftFaced, &satin), "");
  std::mt19937_64 rng(11);
  for (int i = 0; i < 35; ++i) random_pattern.cells.push_back(rng() % 2);
  const std::vector<weave::WeavePattern> patterns = {Twill31(), weave::PlainWeave(), satin,
                                                     weave::WeavePattern{3, 2, {1, 0, 0, 1, 0, 1}}, random_pattern};
  std::uniform_real_distribution<double> U(0, 1);
  for (const weave::WeavePattern& pat : patterns) {
    SCOPED_TRACE(weave::ToString(pat));
    loomlight::models::ParamValues v = model.PresetValues(model.presets()[0]);
    v["pattern.warps"] = {double(pat.warps)};
    v["pattern.cells"] = std::vector<double>(pat.cells.begin(), pat.cells.end());
    ASSERT_EQ(model.Validate(v), "");
    const std::vector<double> m = model.Pack(v).data;
    int lit = 0;
    for (int q = 0; q < 20000; ++q) {
      // Half vectors near the normal so that the highlights cover part of their windows.
      const double tilt = 0.3 * U(rng), az = 2 * kPi * U(rng);
      const Vec h = {std::sin(tilt) * std::cos(az), std::sin(tilt) * std::sin(az), std::cos(tilt)};
      const Vec wi = Normalize({h[0] + 0.3 * (U(rng) - 0.5), h[1] + 0.3 * (U(rng) - 0.5), h[2]});
      const Vec wo = Reflect(wi, h);
      if (wo[2] <= 0.01) continue;
      // Every third position on a cell corner (k / W, l / P), where the cell choice matters most.
      const bool corner = q % 3 == 0;
      const double u = corner ? double(rng() % (3 * pat.warps)) / pat.warps - 1 : 6 * U(rng) - 3;
      const double vv = corner ? double(rng() % (3 * pat.picks)) / pat.picks - 1 : 6 * U(rng) - 3;
      int t;
      double lx, ly;
      wv_double::wv_locate(pat.cells.data(), pat.warps, pat.picks, u, vv, &t, &lx, &ly, m.data());
      const auto want = BtfD(m, t, lx, ly, wi, wo);
      std::array<double, 3> got;
      wv_double::wv_btf(m.data(), wi[0], wi[1], wi[2], wo[0], wo[1], wo[2], u, vv, got.data());
      for (int c = 0; c < 3; ++c) ASSERT_EQ(got[c], want[c]) << "u " << u << " v " << vv << " channel " << c;
      lit += want[0] > m[2 + 14 * t];  // inside a highlight: the kd of its thread type is exceeded
    }
    EXPECT_GT(lit, 1000) << "too few samples inside highlights to test the lookup";
  }
}

// BRDF = mean of the BTF over one repeat, by N x N midpoint quadrature in uv.
//
// Tolerance: only the highlight indicator I varies over a window, and the window edges lie on grid lines
// (N is a multiple of the repeat), so the quadrature is exact on every grid cell that the ellipse boundary
// does not cross; a crossed cell errs by at most its own area. A convex curve whose bounding box spans
// Bx x By crosses at most 2 (Bx/dx + By/dy) + 8 cells of a dx x dy grid (four monotone arcs, each crossing
// at most columns + rows + 1 cells, plus the ends). Per float of type t and length L the local grid steps
// are (dx, dy) = (s_x W/N, s_y P/(L N)) for warp, (s_x P/N, s_y W/(L N)) for weft, and the error of the mean
// of I over that window is at most (2 (Bx/dx + By/dy) + 8) dx dy / (s_x s_y), with B the ellipse's bounding
// box clipped to the window. Weighted by the float's area fraction and by ks_t Fr G / (n.wi n.wo), and
// summed, this bounds |BRDF - quadrature| (~ perimeter / N, as expected for an indicator).
// That worst case needs every crossed cell to err by its whole area in the same direction; the errors of
// the crossed cells along a smooth boundary are signed and vary from cell to cell (the boundary's offset
// relative to the cell midpoints drifts along the curve), so their sum behaves like a random walk: a second,
// statistical tolerance of 4 sqrt(cut) cell areas per float (each |error| <= 1 cell, so a standard deviation
// <= sqrt(cut) cells; 4 sigma) is also asserted. It is ~25x tighter at N = 1000, which is what gives the
// test its power: mapping the weft half vector with the wrong rotation in wv_brdf only (a mutation tried
// while writing this) exceeds the rigorous bound by 2x and the statistical one by far more.
TEST(WovenModel, BrdfIsMeanOfBtf) {
  const weave::WeavePattern pat = Twill31();
  const std::vector<double> m = TwillMaterial(pat);
  const int W = pat.warps, P = pat.picks;
  const int N = 1000;
  ASSERT_EQ(N % W, 0);
  ASSERT_EQ(N % P, 0);
  const std::vector<weave::Float> floats = weave::ExtractFloats(pat);

  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> U(0, 1);
  int queries = 0, partial = 0;
  double worst_ratio = 0, worst_stat = 0, worst_abs = 0;
  while (queries < 24) {
    // Half vectors near the normal (where the highlights sit in their windows, partly clipped) and a
    // few farther out; wi spread around h, wo its mirror image.
    const double tilt = (queries < 18 ? 0.35 : 0.9) * U(rng), az = 2 * kPi * U(rng);
    const Vec h = {std::sin(tilt) * std::cos(az), std::sin(tilt) * std::sin(az), std::cos(tilt)};
    const double td = 1.2 * U(rng), az2 = 2 * kPi * U(rng);
    // wi = h rotated by td about an axis perpendicular to h.
    Vec t1 = Normalize({-h[1], h[0], 0.0});
    if (tilt < 1e-9) t1 = {1, 0, 0};
    const Vec t2 = {h[1] * t1[2] - h[2] * t1[1], h[2] * t1[0] - h[0] * t1[2], h[0] * t1[1] - h[1] * t1[0]};
    Vec wi;
    for (int c = 0; c < 3; ++c)
      wi[c] = std::cos(td) * h[c] + std::sin(td) * (std::cos(az2) * t1[c] + std::sin(az2) * t2[c]);
    const Vec wo = Reflect(wi, h);
    if (wi[2] < 0.05 || wo[2] < 0.05) continue;
    ++queries;

    const auto brdf = BrdfD(m, wi, wo);
    std::array<double, 3> sum = {0, 0, 0};
    for (int j = 0; j < N; ++j)
      for (int i = 0; i < N; ++i) {
        int t;
        double lx, ly;
        wv_double::wv_locate(pat.cells.data(), W, P, (i + 0.5) / N, (j + 0.5) / N, &t, &lx, &ly, m.data());
        const auto f = BtfD(m, t, lx, ly, wi, wo);
        for (int c = 0; c < 3; ++c) sum[c] += f[c];
      }

    // Direction factors and ellipses, recomputed here for the bound.
    const Vec hh = Normalize({wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]});
    const double cd = Dot(wi, hh), nh = hh[2];
    const double g = std::min({1.0, 2 * nh * wo[2] / cd, 2 * nh * wi[2] / cd});
    const double eta = 1.5, g2 = eta * eta - 1 + cd * cd, gg = std::sqrt(g2);
    const double rs = (cd - gg) / (cd + gg), rp = (eta * eta * cd - gg) / (eta * eta * cd + gg);
    const double spec = 0.5 * (rs * rs + rp * rp) * g / (wi[2] * wo[2]);
    std::array<double, 3> tol = {1e-12, 1e-12, 1e-12}, tol_stat = {1e-12, 1e-12, 1e-12};
    bool any_partial = false;
    for (const weave::Float& f : floats) {
      const Thread& th = f.warp ? kWarp : kWeft;
      const double lhx = f.warp ? hh[0] : -hh[1], lhy = f.warp ? hh[1] : hh[0];
      const double cx = 0.5 * th.sx * (th.kx * lhx + 1), cy = 0.5 * th.sy * (th.ky * lhy + 1);
      const double ph = th.phi_deg * kDeg, minor = th.alpha * std::sqrt(1 - th.ecc * th.ecc);
      const double ex = std::hypot(th.alpha * std::cos(ph), minor * std::sin(ph));
      const double ey = std::hypot(th.alpha * std::sin(ph), minor * std::cos(ph));
      const double bx = std::max(0.0, std::min(cx + ex, th.sx) - std::max(cx - ex, 0.0));
      const double by = std::max(0.0, std::min(cy + ey, th.sy) - std::max(cy - ey, 0.0));
      if (bx > 0 && by > 0) any_partial = true;
      const double dx = f.warp ? th.sx * W / N : th.sx * P / N;
      const double dy = f.warp ? th.sy * P / (double(f.length) * N) : th.sy * W / (double(f.length) * N);
      const double cut = (bx > 0 && by > 0) ? 2 * (bx / dx + by / dy) + 8 : 0;
      const double ibar_err = cut * dx * dy / (th.sx * th.sy);
      const double area_frac = double(f.length) / (W * P);
      const double ibar_stat = 4 * std::sqrt(cut) * dx * dy / (th.sx * th.sy);
      for (int c = 0; c < 3; ++c) {
        tol[c] += area_frac * th.ks[c] * spec * ibar_err;
        tol_stat[c] += area_frac * th.ks[c] * spec * ibar_stat;  // added linearly over floats: conservative
      }
    }
    partial += any_partial;
    for (int c = 0; c < 3; ++c) {
      const double quad = sum[c] / (double(N) * N);
      const double err = std::fabs(quad - brdf[c]);
      EXPECT_LE(err, tol[c]) << "query " << queries << " channel " << c << " brdf " << brdf[c] << " quad "
                             << quad;
      EXPECT_LE(err, tol_stat[c]) << "query " << queries << " channel " << c << " (statistical bound)";
      worst_ratio = std::max(worst_ratio, err / tol[c]);
      worst_stat = std::max(worst_stat, err / tol_stat[c]);
      worst_abs = std::max(worst_abs, err / brdf[c]);
    }
  }
  std::printf("BRDF vs %dx%d BTF quadrature: %d queries (%d with a highlight in a window), max |err| / bound "
              "%.3g, / statistical bound %.3g, max relative error %.3g\n",
              N, N, queries, partial, worst_ratio, worst_stat, worst_abs);
  EXPECT_GE(partial, 12);  // the test must exercise the highlight, not only kd
}

TEST(WovenModel, Reciprocity) {
  const weave::WeavePattern pat = Twill31();
  const std::vector<double> md = TwillMaterial(pat);
  const std::vector<float> mf = ToFloat(md);
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> U(0, 1);
  for (int q = 0; q < 20000; ++q) {
    const Vec wi = RandomUpper(rng), wo = RandomUpper(rng);
    EXPECT_EQ(BrdfD(md, wi, wo), BrdfD(md, wo, wi));
    EXPECT_EQ(BrdfF(mf, wi, wo), BrdfF(mf, wo, wi));
    const int t = q % 2;
    const Thread& th = t == 0 ? kWarp : kWeft;
    const double x = th.sx * U(rng), y = th.sy * U(rng);
    EXPECT_EQ(BtfD(md, t, x, y, wi, wo), BtfD(md, t, x, y, wo, wi));
    EXPECT_EQ(BtfF(mf, t, float(x), float(y), wi, wo), BtfF(mf, t, float(x), float(y), wo, wi));
  }
}

// Pairs (wi, wo) with the given half vector: wi = h rotated by td, wo = its mirror image.
Vec WithHalf(const Vec& h, double td, double az) {
  Vec t1 = Normalize(std::fabs(h[2]) < 0.9 ? Vec{-h[1], h[0], 0.0} : Vec{1.0, 0.0, -h[0] / h[2]});
  t1 = Normalize({t1[0] - Dot(t1, h) * h[0], t1[1] - Dot(t1, h) * h[1], t1[2] - Dot(t1, h) * h[2]});
  const Vec t2 = {h[1] * t1[2] - h[2] * t1[1], h[2] * t1[0] - h[0] * t1[2], h[0] * t1[1] - h[1] * t1[0]};
  Vec wi;
  for (int c = 0; c < 3; ++c) wi[c] = std::cos(td) * h[c] + std::sin(td) * (std::cos(az) * t1[c] + std::sin(az) * t2[c]);
  return wi;
}

TEST(WovenModel, FiniteAndNonNegative) {
  const weave::WeavePattern pat = Twill31();
  const std::vector<double> md = TwillMaterial(pat);
  const std::vector<float> mf = ToFloat(md);
  std::vector<std::pair<Vec, Vec>> cases;
  const double e = 1e-6;
  const double ge = std::sqrt(1 - e * e);
  // h = n.
  cases.push_back({{0, 0, 1}, {0, 0, 1}});
  for (double th : {0.3, 1.0, 1.5, 1.5707})
    cases.push_back({{std::sin(th), 0, std::cos(th)}, {-std::sin(th), 0, std::cos(th)}});
  // Grazing n.wi = 1e-6 (and both, and just above / at the horizon epsilon, and below).
  for (double az : {0.0, 0.7, 1.6, 3.1}) {
    cases.push_back({{ge * std::cos(az), ge * std::sin(az), e}, {0, 0, 1}});
    cases.push_back({{ge * std::cos(az), ge * std::sin(az), e}, {-ge * std::cos(az), -ge * std::sin(az), e}});
    cases.push_back({{ge * std::cos(az), ge * std::sin(az), e}, {ge * std::cos(az), ge * std::sin(az), e}});
    cases.push_back({{std::cos(az), std::sin(az), 1e-7}, {0.6, 0, 0.8}});
    cases.push_back({{std::cos(az), std::sin(az), 0}, {0.6, 0, 0.8}});
    cases.push_back({{0.6, 0, -0.8}, {std::cos(az), std::sin(az), 0.5}});
  }
  // Ellipse centre on each window corner, and ellipse tangent to each window edge from inside and outside,
  // for both thread types: solve c for the local half vector, map back to global.
  for (int t = 0; t < 2; ++t) {
    const Thread& th = t == 0 ? kWarp : kWeft;
    const double ph = th.phi_deg * kDeg, minor = th.alpha * std::sqrt(1 - th.ecc * th.ecc);
    const double ex = std::hypot(th.alpha * std::cos(ph), minor * std::sin(ph));
    const double ey = std::hypot(th.alpha * std::sin(ph), minor * std::cos(ph));
    std::vector<std::array<double, 2>> centres;
    for (double cx : {0.0, th.sx})
      for (double cy : {0.0, th.sy}) centres.push_back({cx, cy});
    for (double cx : {ex, -ex, th.sx - ex, th.sx + ex}) centres.push_back({cx, 0.5 * th.sy});
    for (double cy : {ey, -ey, th.sy - ey, th.sy + ey}) centres.push_back({0.5 * th.sx, cy});
    for (const auto& c : centres) {
      const double lhx = (2 * c[0] / th.sx - 1) / th.kx, lhy = (2 * c[1] / th.sy - 1) / th.ky;
      const double gx = t == 0 ? lhx : lhy, gy = t == 0 ? lhy : -lhx;  // inverse of (x, y) -> (-y, x)
      const double r2 = gx * gx + gy * gy;
      if (r2 >= 1) continue;
      const Vec h = {gx, gy, std::sqrt(1 - r2)};
      cases.push_back({h, h});
      for (double td : {0.2, 0.6})
        for (double az : {0.0, 2.0}) {
          const Vec wi = WithHalf(h, td, az), wo = Reflect(wi, h);
          if (wi[2] > 0 && wo[2] > 0) cases.push_back({wi, wo});
        }
    }
  }
  std::mt19937_64 rng(3);
  for (int q = 0; q < 20000; ++q) cases.push_back({RandomUpper(rng), RandomUpper(rng)});

  std::uniform_real_distribution<double> U(0, 1);
  for (const auto& [a, b] : cases) {
    for (int swap = 0; swap < 2; ++swap) {
      const Vec& wi = swap ? b : a;
      const Vec& wo = swap ? a : b;
      const bool lit = wi[2] > 1e-7 && wo[2] > 1e-7;
      // n.w within a float rounding of the horizon threshold (after renormalisation) may go either way.
      const double zmin = std::min(wi[2], wo[2]);
      const bool at_threshold = zmin > 0.5e-7 && zmin < 2e-7;
      const auto fd = BrdfD(md, wi, wo);
      const auto ff = BrdfF(mf, wi, wo);
      std::vector<double> vals(fd.begin(), fd.end());
      vals.insert(vals.end(), ff.begin(), ff.end());
      for (int t = 0; t < 2; ++t) {
        const Thread& th = t == 0 ? kWarp : kWeft;
        for (auto [x, y] : {std::pair<double, double>{0, 0}, {th.sx, th.sy}, {th.sx * U(rng), th.sy * U(rng)},
                            {0.5 * th.sx, 0.5 * th.sy}}) {
          const auto bd = BtfD(md, t, x, y, wi, wo);
          const auto bf = BtfF(mf, t, float(x), float(y), wi, wo);
          vals.insert(vals.end(), bd.begin(), bd.end());
          vals.insert(vals.end(), bf.begin(), bf.end());
        }
      }
      for (double v : vals) {
        ASSERT_TRUE(std::isfinite(v)) << wi[0] << " " << wi[1] << " " << wi[2] << " / " << wo[0] << " " << wo[1]
                                      << " " << wo[2];
        ASSERT_GE(v, 0.0);
        if (at_threshold) {
          // either 0 or lit; finite and non-negative checked above
        } else if (!lit) {
          ASSERT_EQ(v, 0.0) << wi[0] << " " << wi[1] << " " << wi[2] << " / " << wo[0] << " " << wo[1] << " " << wo[2];
        } else {
          ASSERT_GE(v, 0.029);  // at least the diffuse part (no kd is below 0.03)
        }
      }
    }
  }
}

double Quantile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, size_t(q * (v.size() - 1) + 0.5))];
}

// Float BRDF against double on the same float inputs and the same float-rounded material.
//
// Bound: every lit result is at least kd (>= 0.03 here), so a relative error of the whole is at most the
// absolute error of the specular part over kd. The specular part is ks (A / (s_x s_y)) Fr G / (n.wi n.wo);
// Fr G / (n.wi n.wo) and the direction factors carry a few float ulps relative (~1e-6), and A is
// conditioned as documented in ellipse_window.h: a centre known to ~ eps |c| (c up to ~ 15 local units
// here: k s / 2 = 9.3 for the warp) moves A by ~ (2/pi) eps |c| / minor-axis x ellipse area, i.e. ~ 2e-5
// of the ellipse area for the warp ellipse (minor semi-axis 0.3), less for the weft. The specular term
// times that is largest near grazing where 1 / (n.wi n.wo) grows, but there the total grows by the same
// factor, so the relative error of the total stays ~ the relative error of A. Asserted: max < 1e-4,
// p99 < 1e-5 (measured values are printed).
TEST(WovenModel, FloatMatchesDouble) {
  const weave::WeavePattern pat = Twill31();
  const std::vector<double> md0 = TwillMaterial(pat);
  const std::vector<float> mf = ToFloat(md0);
  const std::vector<double> md(mf.begin(), mf.end());  // the material the float path sees, exactly
  std::mt19937_64 rng(5);
  std::vector<double> rel;
  rel.reserve(300000);
  for (int q = 0; q < 100000; ++q) {
    const Vec wi = RandomUpper(rng), wo = RandomUpper(rng);
    if (!(wi[2] > 1e-7 && wo[2] > 1e-7)) continue;
    const auto fd = BrdfD(md, wi, wo);
    const auto ff = BrdfF(mf, wi, wo);
    for (int c = 0; c < 3; ++c) rel.push_back(std::fabs(double(ff[c]) - fd[c]) / fd[c]);
  }
  const double med = Quantile(rel, 0.5), p99 = Quantile(rel, 0.99), mx = Quantile(rel, 1.0);
  std::printf("float vs double BRDF relative error over %zu values: median %.3g p99 %.3g max %.3g\n",
              rel.size(), med, p99, mx);
  EXPECT_LT(p99, 1e-5);
  EXPECT_LT(mx, 1e-4);
}

}  // namespace
