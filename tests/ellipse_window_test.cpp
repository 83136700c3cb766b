// The analytic ellipse-window area of the woven-cotton BRDF (kernels/common/ellipse_window.h, SPEC.md
// section 3), compiled as C++ with real = double and real = float, against an independent reference:
// adaptive Gauss-Legendre integration over x of the ellipse's vertical chord clipped to [y0, y1].
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <queue>
#include <random>
#include <vector>

namespace ew_double {
typedef double real;
#include "common/shim.h"
#include "common/ellipse_window.h"
}  // namespace ew_double

namespace ew_float {
typedef float real;
#include "common/shim.h"
#include "common/ellipse_window.h"
}  // namespace ew_float

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kEpsD = std::numeric_limits<double>::epsilon();  // 2.2e-16
constexpr double kEpsF = std::numeric_limits<float>::epsilon();   // 1.2e-7

struct Ellipse {
  double cx, cy, ax, ay, bx, by;
  double Area() const { return kPi * std::fabs(ax * by - ay * bx); }
};
struct Box {
  double x0, y0, x1, y1;
  double Area() const { return (x1 - x0) * (y1 - y0); }
};

double AreaD(const Ellipse& e, const Box& r) {
  return ew_double::ll_ellipse_rect_area(e.cx, e.cy, e.ax, e.ay, e.bx, e.by, r.x0, r.y0, r.x1, r.y1);
}
float AreaF(const Ellipse& e, const Box& r) {
  auto f = [](double v) { return static_cast<float>(v); };
  return ew_float::ll_ellipse_rect_area(f(e.cx), f(e.cy), f(e.ax), f(e.ay), f(e.bx), f(e.by), f(r.x0), f(r.y0),
                                        f(r.x1), f(r.y1));
}
// The inputs the float path actually sees, as doubles: the reference for float is taken on these, so that
// the comparison measures the evaluation and not the rounding of the inputs.
Ellipse ToFloat(const Ellipse& e) {
  auto f = [](double v) { return static_cast<double>(static_cast<float>(v)); };
  return {f(e.cx), f(e.cy), f(e.ax), f(e.ay), f(e.bx), f(e.by)};
}
Box ToFloat(const Box& r) {
  auto f = [](double v) { return static_cast<double>(static_cast<float>(v)); };
  return {f(r.x0), f(r.y0), f(r.x1), f(r.y1)};
}

// ---------------------------------------------------------------------------------------------------------
// Independent reference. The ellipse is parametrised as c + a cos t + b sin t (no quadratic form, no Green's
// theorem): x(t) = cx + ex cos(t - psi) with ex = |(ax, bx)|, psi = atan2(bx, ax), so the vertical line at
// x = cx +- ex cos w meets it at t = psi +- v (v = w right of the centre, pi - w left of it), at heights
// ymid +- half with ymid = cy + cos v (ay cos psi + by sin psi), half = sin v |by cos psi - ay sin psi|.
// Area = integral over w in [0, pi/2] (each half) of clip(chord) * ex sin w dw, smooth between the w where the
// boundary crosses y0 or y1 (t = psy +- acos((Y - cy)/ey), found exactly) and the window's x0, x1; each
// piece gets adaptive 20-point Gauss-Legendre. The substitution removes the square-root endpoint behaviour
// at the ellipse's extreme x, and angles are found as atan2(sqrt((e - d)(e + d)), d), accurate near
// tangency. Integrating over y instead (RefAreaY, the same code on the transposed problem) is accurate for
// segments cut by horizontal edges, where the chord clipped at y0 cancels.

struct GaussLegendre {
  static constexpr int N = 20;
  std::array<double, N> x{}, w{};
  GaussLegendre() {
    for (int i = 0; i < N; ++i) {
      double z = std::cos(kPi * (i + 0.75) / (N + 0.5)), dp = 0;
      for (int it = 0; it < 100; ++it) {
        double p0 = 1, p1 = z;  // P_0, P_1 -> P_N by the three-term recurrence
        for (int k = 2; k <= N; ++k) {
          const double p2 = ((2 * k - 1) * z * p1 - (k - 1) * p0) / k;
          p0 = p1;
          p1 = p2;
        }
        dp = N * (z * p1 - p0) / (z * z - 1);
        const double dz = p1 / dp;
        z -= dz;
        if (std::fabs(dz) < 1e-17) break;
      }
      x[i] = z;
      w[i] = 2 / ((1 - z * z) * dp * dp);
    }
  }
  template <class F>
  double Integrate(const F& f, double a, double b) const {
    const double m = 0.5 * (a + b), h = 0.5 * (b - a);
    double s = 0;
    for (int i = 0; i < N; ++i) s += w[i] * f(m + h * x[i]);
    return s * h;
  }
};
const GaussLegendre& GL() {
  static const GaussLegendre gl;
  return gl;
}

// Globally adaptive: the piece with the largest error estimate |GL(a, m) + GL(m, b) - GL(a, b)| is halved
// until the estimates sum below 1e-16 of the total (a per-piece relative test would chase rounding noise
// where the integrand vanishes at a breakpoint), with a cap on the number of pieces.
constexpr int kMaxSplits = 200;

template <class F>
double Adaptive(const F& f, const std::vector<double>& breaks) {
  struct Piece {
    double a, b, value, err;
    bool operator<(const Piece& o) const { return err < o.err; }
  };
  auto make = [&](double a, double b) {
    const double m = 0.5 * (a + b);
    const double whole = GL().Integrate(f, a, b), halves = GL().Integrate(f, a, m) + GL().Integrate(f, m, b);
    return Piece{a, b, halves, std::fabs(halves - whole)};
  };
  std::priority_queue<Piece> heap;
  double total = 0, err = 0;  // running sums over the heap
  for (size_t i = 0; i + 1 < breaks.size(); ++i) {
    if (!(breaks[i + 1] > breaks[i])) continue;
    heap.push(make(breaks[i], breaks[i + 1]));
  }
  {
    std::priority_queue<Piece> copy = heap;
    for (; !copy.empty(); copy.pop()) total += copy.top().value, err += copy.top().err;
  }
  for (int splits = 0; splits < kMaxSplits && !heap.empty(); ++splits) {
    if (err <= 1e-15 * total) break;
    const Piece worst = heap.top();
    heap.pop();
    const double m = 0.5 * (worst.a + worst.b);
    if (!(m > worst.a && m < worst.b)) break;
    const Piece l = make(worst.a, m), r = make(m, worst.b);
    total += l.value + r.value - worst.value;
    err += l.err + r.err - worst.err;
    heap.push(l);
    heap.push(r);
  }
  double sum = 0;  // re-summed: the running total is only a stopping guide
  for (; !heap.empty(); heap.pop()) sum += heap.top().value;
  return sum;
}

// acos(d / e) for |d| <= e, accurate for d near +-e.
double AcosRatio(double d, double e) {
  return std::atan2(std::sqrt(std::max(0.0, (e - std::fabs(d)) * (e + std::fabs(d)))), d);
}

double RefAreaX(const Ellipse& e, const Box& r) {
  if (!(r.x1 > r.x0 && r.y1 > r.y0) || e.Area() == 0) return 0;
  const double ex = std::hypot(e.ax, e.bx), psi = std::atan2(e.bx, e.ax);
  const double ey = std::hypot(e.ay, e.by), psy = std::atan2(e.by, e.ay);
  const double pm = e.ay * std::cos(psi) + e.by * std::sin(psi);
  const double ph = std::fabs(e.by * std::cos(psi) - e.ay * std::sin(psi));

  // Breakpoints in w for each half (index 0: right, x >= cx; 1: left).
  std::vector<double> cuts[2];
  for (double yy : {r.y0, r.y1}) {
    const double dy = yy - e.cy;
    if (std::fabs(dy) >= ey) continue;
    const double ac = AcosRatio(dy, ey);
    for (double t : {psy + ac, psy - ac}) {
      const double v = std::fabs(std::remainder(t - psi, 2 * kPi));
      if (v <= kPi / 2) cuts[0].push_back(v);
      if (v >= kPi / 2) cuts[1].push_back(kPi - v);
    }
  }
  double total = 0;
  for (int side = 0; side < 2; ++side) {
    const double sgn = side == 0 ? 1 : -1;
    // Offsets from cx (outward positive) of the window's part of this half: [dlo, dhi] within [0, ex].
    const double dlo = side == 0 ? std::max(0.0, r.x0 - e.cx) : std::max(0.0, e.cx - r.x1);
    const double dhi_raw = side == 0 ? r.x1 - e.cx : e.cx - r.x0;
    if (dhi_raw <= dlo || dlo >= ex) continue;
    // x = cx + sgn ex cos w: the outer limit is w = 0 when the window reaches past the ellipse.
    const double wa = dhi_raw >= ex ? 0.0 : AcosRatio(dhi_raw, ex);
    const double wb = AcosRatio(dlo, ex);
    auto f = [&](double w) {
      const double ymid = e.cy + sgn * std::cos(w) * pm, half = std::sin(w) * ph;
      const double len = std::min(r.y1 - ymid, half) + std::min(ymid - r.y0, half);
      return std::max(0.0, len) * ex * std::sin(w);
    };
    std::vector<double> pts = {wa, wb};
    for (double c : cuts[side])
      if (c > wa && c < wb) pts.push_back(c);
    std::sort(pts.begin(), pts.end());
    total += Adaptive(f, pts);
  }
  return total;
}
double RefAreaY(const Ellipse& e, const Box& r) {
  return RefAreaX({e.cy, e.cx, e.ay, e.ax, e.by, e.bx}, {r.y0, r.x0, r.y1, r.x1});
}

// ---------------------------------------------------------------------------------------------------------
// Conditioning. Moving a coordinate X by eps |X| moves the area by at most (chord length) eps |X| <=
// 2 sigma1 eps |X|, i.e. by (2/pi) eps |X| / sigma2 of the ellipse area (sigma1 >= sigma2 the semi-axes);
// perturbing a, b relatively by eps moves it by ~ eps sigma1 / sigma2. So kappa = (max |X| + sigma1) / sigma2
// is the size of the absolute error (as a fraction of the ellipse area) in units of eps that any evaluation
// from rounded data can be expected to have, and the bounds below are small multiples of eps kappa.
double Kappa(const Ellipse& e, const Box& r) {
  const double s = e.ax * e.ax + e.ay * e.ay + e.bx * e.bx + e.by * e.by;
  const double d = std::fabs(e.ax * e.by - e.ay * e.bx);
  const double s1 = std::sqrt(0.5 * (s + std::sqrt(std::max(0.0, (s - 2 * d) * (s + 2 * d)))));
  const double s2 = d / s1;
  const double xmax = std::max({std::fabs(e.cx), std::fabs(e.cy), std::fabs(r.x0), std::fabs(r.x1),
                                std::fabs(r.y0), std::fabs(r.y1)});
  return (xmax + s1) / s2;
}

struct Stats {
  double median = 0, p99 = 0, max = 0;
  size_t count = 0;
};
Stats Summarise(std::vector<double> v) {
  Stats s;
  s.count = v.size();
  if (v.empty()) return s;
  std::sort(v.begin(), v.end());
  s.median = v[v.size() / 2];
  s.p99 = v[std::min(v.size() - 1, static_cast<size_t>(0.99 * v.size()))];
  s.max = v.back();
  return s;
}
void Print(const char* what, const Stats& s) {
  std::printf("  %-58s median %.2e  p99 %.2e  max %.2e  (n = %zu)\n", what, s.median, s.p99, s.max, s.count);
}

// Random configuration: semi-axes 0.1..3 with minor/major ratio log-uniform in 1e-3..1, or the paper's
// eccentricities 0.995 (warp) and 0.9 (weft); random rotation and handedness; a fifth with non-orthogonal
// conjugate semi-diameters; a window of half-sizes 0.03..3 times the major semi-axis around a point within
// 1.5 major semi-axes of the centre.
struct Config {
  Ellipse e;
  Box r;
};
Config RandomConfig(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0, 1);
  const double A = 0.1 + 2.9 * u(rng);
  const double pick = u(rng);
  const double ratio = pick < 0.15   ? std::sqrt(1 - 0.995 * 0.995)
                       : pick < 0.25 ? std::sqrt(1 - 0.9 * 0.9)
                                     : std::pow(10.0, -3 * u(rng));
  const double phi = 2 * kPi * u(rng), hand = u(rng) < 0.5 ? 1 : -1;
  Ellipse e{8 * u(rng) - 4, 8 * u(rng) - 4, A * std::cos(phi), A * std::sin(phi),
            -hand * A * ratio * std::sin(phi), hand * A * ratio * std::cos(phi)};
  if (u(rng) < 0.2) {
    const double t = 2 * u(rng) - 1;
    e.bx += t * e.ax;
    e.by += t * e.ay;
  }
  const double mx = e.cx + A * (3 * u(rng) - 1.5), my = e.cy + A * (3 * u(rng) - 1.5);
  const double hx = A * std::pow(10.0, 2 * u(rng) - 1.5), hy = A * std::pow(10.0, 2 * u(rng) - 1.5);
  return {e, {mx - hx, my - hy, mx + hx, my + hy}};
}

// The paper's warp ellipse (semi-major 3, eccentricity 0.995, rotated 95 degrees), centred at c.
Ellipse PaperWarp(double cx, double cy) {
  const double A = 3, B = 3 * std::sqrt(1 - 0.995 * 0.995), phi = 95 * kPi / 180;
  return {cx, cy, A * std::cos(phi), A * std::sin(phi), -B * std::sin(phi), B * std::cos(phi)};
}

// ---------------------------------------------------------------------------------------------------------

TEST(EllipseWindowReference, ClosedForms) {
  // Unit circle: quarter, half, and the segment beyond x = 1/2 (pi/3 - sqrt(3)/4).
  const Ellipse circle{0, 0, 1, 0, 0, 1};
  EXPECT_NEAR(RefAreaX(circle, {0, 0, 2, 2}), kPi / 4, 1e-15);
  EXPECT_NEAR(RefAreaX(circle, {-2, 0, 2, 2}), kPi / 2, 1e-15);
  EXPECT_NEAR(RefAreaX(circle, {0.5, -2, 2, 2}), kPi / 3 - std::sqrt(3.0) / 4, 1e-15);
  EXPECT_NEAR(RefAreaX(circle, {-2, 0.5, 2, 2}), kPi / 3 - std::sqrt(3.0) / 4, 1e-15);
  // Unit circle and the square [0, 1]^2 shifted by (-0.5, -0.5): the whole square, as it lies inside.
  EXPECT_NEAR(RefAreaX(circle, {-0.5, -0.5, 0.5, 0.5}), 1.0, 1e-15);
  // A rotated thin ellipse: whole, and halves through the centre in x and in y.
  const Ellipse warp = PaperWarp(0.3, -0.2);
  EXPECT_NEAR(RefAreaX(warp, {-9, -9, 9, 9}) / warp.Area(), 1, 1e-14);
  EXPECT_NEAR(RefAreaX(warp, {0.3, -9, 9, 9}) / warp.Area(), 0.5, 1e-14);
  EXPECT_NEAR(RefAreaX(warp, {-9, -0.2, 9, 9}) / warp.Area(), 0.5, 1e-14);
  // Integrating over x and over y agree on random configurations, to the conditioning of the data.
  std::mt19937_64 rng(7);
  double worst = 0, worst_kappa = 0;
  for (int i = 0; i < 5000; ++i) {
    const Config c = RandomConfig(rng);
    const double d = std::fabs(RefAreaX(c.e, c.r) - RefAreaY(c.e, c.r)) / c.e.Area();
    worst = std::max(worst, d);
    worst_kappa = std::max(worst_kappa, d / (kEpsD * Kappa(c.e, c.r)));
  }
  std::printf("  reference: |x-integration - y-integration| / ellipse area over 5000: max %.2e = %.2f eps kappa\n",
              worst, worst_kappa);
  EXPECT_LT(worst_kappa, 1.0);
}

// (a) 100k random configurations.
TEST(EllipseWindow, RandomConfigurations) {
  std::mt19937_64 rng(20060617);
  const int n = 100000;
  std::vector<double> abs_d, abs_f, rel_d, rel_f, kap_d, kap_f;
  int empty = 0, full = 0;
  for (int i = 0; i < n; ++i) {
    const Config c = RandomConfig(rng);
    const double ref = RefAreaX(c.e, c.r), ell = c.e.Area();
    const double got = AreaD(c.e, c.r);
    ASSERT_TRUE(std::isfinite(got)) << i;
    const double ed = std::fabs(got - ref) / ell;
    abs_d.push_back(ed);
    kap_d.push_back(ed / (kEpsD * Kappa(c.e, c.r)));
    if (ref > 1e-3 * ell) rel_d.push_back(std::fabs(got - ref) / ref);
    empty += ref == 0;
    full += ref > (1 - 1e-12) * ell;

    const Ellipse ef = ToFloat(c.e);
    const Box rf = ToFloat(c.r);
    const double ref_f = RefAreaX(ef, rf), ell_f = ef.Area();
    const float got_f = AreaF(c.e, c.r);
    ASSERT_TRUE(std::isfinite(got_f)) << i;
    const double e_f = std::fabs(got_f - ref_f) / ell_f;
    abs_f.push_back(e_f);
    kap_f.push_back(e_f / (kEpsF * Kappa(ef, rf)));
    if (ref_f > 1e-3 * ell_f) rel_f.push_back(std::fabs(got_f - ref_f) / ref_f);
  }
  std::printf("  %d configurations: %d with no overlap, %d with the whole ellipse inside\n", n, empty, full);
  const Stats sd = Summarise(abs_d), sf = Summarise(abs_f), kd = Summarise(kap_d), kf = Summarise(kap_f);
  Print("double: |error| / ellipse area", sd);
  Print("double: |error| / ellipse area / (eps kappa)", kd);
  Print("double: relative error, true area > 1e-3 ellipse", Summarise(rel_d));
  Print("float:  |error| / ellipse area", sf);
  Print("float:  |error| / ellipse area / (eps kappa)", kf);
  Print("float:  relative error, true area > 1e-3 ellipse", Summarise(rel_f));
  // Bounds: a small multiple of the conditioning (see Kappa), and absolute ceilings for this distribution.
  EXPECT_LT(kd.max, 4.0);
  EXPECT_LT(kf.max, 4.0);
  EXPECT_LT(sd.max, 1e-11);
  EXPECT_LT(sd.p99, 1e-13);
}

// (b) Hard cases.
const Ellipse kAxis{0, 0, 3, 0, 0, 0.375};  // exact semi-axes: half-width 3, half-height 0.375
const double kAxisArea = kPi * 3 * 0.375;

TEST(EllipseWindow, InsideOutsideContaining) {
  for (const Ellipse& e : {kAxis, PaperWarp(0.5, 3), Ellipse{0.5, 3, 1.2, 0.7, -0.9, 0.6}}) {
    // Whole ellipse inside the window: exactly pi |det| (to its rounding).
    EXPECT_NEAR(AreaD(e, {-10, -10, 10, 10}) / e.Area(), 1, 2 * kEpsD);
    EXPECT_NEAR(AreaF(e, {-10, -10, 10, 10}) / ToFloat(e).Area(), 1, 4 * kEpsF);
    // Entirely outside, on each side: exactly 0.
    for (const Box& r : {Box{5, -10, 10, 10}, Box{-10, -10, -5, 10}, Box{-10, 8, 10, 10}, Box{-10, -10, 10, -5}}) {
      EXPECT_EQ(AreaD(e, r), 0.0);
      EXPECT_EQ(AreaF(e, r), 0.0f);
    }
    // Window inside the ellipse: its own area.
    const Box small{e.cx - 0.05, e.cy - 0.01, e.cx + 0.04, e.cy + 0.02};
    EXPECT_NEAR(AreaD(e, small) / small.Area(), 1, 2 * kEpsD);
    EXPECT_NEAR(AreaF(e, small) / ToFloat(small).Area(), 1, 4 * kEpsF);
  }
  // Containing: a tiny window far off-centre (the general formula would leave ~eps pi of the ellipse here).
  const Box tiny{2.5, 0.1, 2.5 + 1e-6, 0.1 + 1e-6};
  EXPECT_NEAR(AreaD(kAxis, tiny) / tiny.Area(), 1, 1e-9);  // 1e-9: the window's own width has rounding 1e-10
  EXPECT_NEAR(AreaD(kAxis, tiny) / RefAreaX(kAxis, tiny), 1, 1e-9);
}

TEST(EllipseWindow, Tangent) {
  // Axis-aligned ellipse with exactly representable extents: tangent from outside is exactly 0, from
  // inside exactly the whole ellipse.
  for (const Box& r : {Box{3, -1, 5, 1}, Box{-5, -1, -3, 1}, Box{-4, 0.375, 4, 1}, Box{-4, -1, 4, -0.375}}) {
    EXPECT_EQ(AreaD(kAxis, r), 0.0);
    EXPECT_EQ(AreaF(kAxis, r), 0.0f);
  }
  for (const Box& r : {Box{-3, -0.375, 3, 0.375}, Box{-3, -1, 5, 1}, Box{-5, -0.375, 5, 1}}) {
    EXPECT_NEAR(AreaD(kAxis, r) / kAxisArea, 1, 2 * kEpsD);
    EXPECT_NEAR(AreaF(kAxis, r) / kAxisArea, 1, 4 * kEpsF);
  }
  // Rotated ellipses with the window edges on the computed extents: the true configuration of the rounded
  // inputs is tangent to within an ulp, so outside is a sliver of depth ~eps (area ~eps^1.5 of the
  // ellipse) and inside misses at most that.
  for (const Ellipse& e : {PaperWarp(0.5, 3), Ellipse{0.5, 3, 1.2, 0.7, -0.9, 0.6}}) {
    const double ex = std::hypot(e.ax, e.bx), ey = std::hypot(e.ay, e.by);
    const Box outside[] = {{e.cx + ex, -10, 10, 10}, {-10, -10, e.cx - ex, 10}, {-10, e.cy + ey, 10, 10},
                           {-10, -10, 10, e.cy - ey}};
    for (const Box& r : outside) {
      EXPECT_LE(AreaD(e, r) / e.Area(), 1e-15);
      EXPECT_LE(AreaF(e, r) / ToFloat(e).Area(), 1e-6);  // float: a sliver of depth ~eps_f ~ 1e-10
    }
    const Box inside{e.cx - ex, e.cy - ey, e.cx + ex, e.cy + ey};
    EXPECT_NEAR(AreaD(e, inside) / e.Area(), 1, 1e-15);
    EXPECT_NEAR(AreaF(e, inside) / ToFloat(e).Area(), 1, 4 * kEpsF);
  }
}

TEST(EllipseWindow, CentreOnCornerAndEdge) {
  // Axis-aligned: exactly a quarter at each corner, a half on each edge.
  const double xs[2] = {0, -7}, ys[2] = {0, -5};
  for (int i = 0; i < 4; ++i) {
    const double x0 = xs[i & 1], y0 = ys[i >> 1];
    const Box r{x0, y0, x0 + 7, y0 + 5};  // c = 0 at corner (x0 or x1, y0 or y1)
    EXPECT_NEAR(AreaD(kAxis, r) / kAxisArea, 0.25, kEpsD) << i;
    EXPECT_NEAR(AreaF(kAxis, r) / kAxisArea, 0.25, kEpsF) << i;
  }
  for (const Box& r : {Box{0, -5, 7, 5}, Box{-7, -5, 0, 5}, Box{-7, 0, 7, 5}, Box{-7, -5, 7, 0}}) {
    EXPECT_NEAR(AreaD(kAxis, r) / kAxisArea, 0.5, kEpsD);
    EXPECT_NEAR(AreaF(kAxis, r) / kAxisArea, 0.5, kEpsF);
  }
  // Rotated and non-orthogonal ellipses, centre on every corner and edge of windows that also cut the
  // ellipse elsewhere (w = 0.4) or not (w = 10), against the reference.
  for (const Ellipse& e0 : {PaperWarp(0, 0), Ellipse{0, 0, 1.2, 0.7, -0.9, 0.6}, Ellipse{0, 0, 2, 0.1, 1.9, 0.2}}) {
    for (double w : {0.4, 10.0}) {
      for (int i = 0; i < 8; ++i) {
        Ellipse e = e0;
        const Box r{-0.3 * w, -0.8 * w, 0.5 * w, 2.0 * w};
        const double px[8] = {r.x0, r.x1, r.x1, r.x0, r.x0, r.x1, 0.1 * w, 0.1 * w};
        const double py[8] = {r.y0, r.y0, r.y1, r.y1, 0.2 * w, 0.2 * w, r.y0, r.y1};
        e.cx = px[i];
        e.cy = py[i];
        const double ref = RefAreaX(e, r), ell = e.Area();
        EXPECT_NEAR(AreaD(e, r) / ell, ref / ell, 1e-14) << i << " w " << w;
        const Ellipse ef = ToFloat(e);
        EXPECT_NEAR(AreaF(e, r) / ef.Area(), RefAreaX(ef, ToFloat(r)) / ef.Area(), 8 * kEpsF) << i << " w " << w;
      }
    }
  }
}

// Tiny circular segments: a window edge cuts delta (fraction of the ellipse's extent across the edge) off
// the ellipse, with the centre outside (area = the segment) and inside (area = ellipse - segment).
TEST(EllipseWindow, TinySegments) {
  struct Cut {
    Ellipse e;
    int edge;  // 0: x = x0 (segment to the right), 1: x = x1, 2: y = y0, 3: y = y1
    double delta;
  };
  auto window = [](const Ellipse& e, int edge, double delta, bool centre_inside) {
    const double ex = std::hypot(e.ax, e.bx), ey = std::hypot(e.ay, e.by), big = 20;
    const double at_x = ex * (1 - delta), at_y = ey * (1 - delta);
    Box r{-big, -big, big, big};
    switch (edge) {
      case 0: centre_inside ? (r.x1 = e.cx + at_x) : (r.x0 = e.cx + at_x); break;
      case 1: centre_inside ? (r.x0 = e.cx - at_x) : (r.x1 = e.cx - at_x); break;
      case 2: centre_inside ? (r.y1 = e.cy + at_y) : (r.y0 = e.cy + at_y); break;
      default: centre_inside ? (r.y0 = e.cy - at_y) : (r.y1 = e.cy - at_y); break;
    }
    return r;
  };
  // Double, axis-aligned with exact extents (3 and 0.375, c = 0) and delta = 2^-k: every input and the
  // line offset are exact, so the relative error of the segment is bounded by the evaluation alone.
  // Also float there: h and l come out exact, leaving the atan2 and series (a few ulps).
  double worst_d = 0, worst_f = 0;
  for (int k : {10, 14, 17, 20}) {
    const double delta = std::ldexp(1.0, -k);
    for (int edge = 0; edge < 4; ++edge) {
      const Box r = window(kAxis, edge, delta, false);
      const double ref = (edge < 2 ? RefAreaX : RefAreaY)(kAxis, r);
      // Closed form: ab (theta - sin theta)/2 with cos(theta/2) = 1 - delta (long double check).
      const long double ht = std::acos(1.0L - delta), th = 2 * ht;
      const long double closed = 3.0L * 0.375L * (th - std::sin(th)) / 2;
      EXPECT_NEAR(ref / static_cast<double>(closed), 1, 1e-12) << "reference, delta 2^-" << k;
      const double rd = std::fabs(AreaD(kAxis, r) - ref) / ref, rf = std::fabs(AreaF(kAxis, r) - ref) / ref;
      worst_d = std::max(worst_d, rd);
      worst_f = std::max(worst_f, rf);
      EXPECT_LT(rd, 1e-13) << "delta 2^-" << k << " edge " << edge;
      EXPECT_LT(rf, 2e-6) << "delta 2^-" << k << " edge " << edge;
      const Box r2 = window(kAxis, edge, delta, true);
      EXPECT_NEAR(AreaD(kAxis, r2) / (kAxisArea - ref), 1, 2 * kEpsD);
      EXPECT_NEAR(AreaF(kAxis, r2) / (kAxisArea - ref), 1, 4 * kEpsF);
    }
  }
  std::printf("  exact axis-aligned segments, delta 2^-10..2^-20: max relative error double %.2e, float %.2e\n",
              worst_d, worst_f);

  // Rotated thin and non-orthogonal ellipses, delta = 1e-3..1e-6: here the edge position and the extent e
  // carry rounding eps |X|, and the segment (area ~ delta^1.5) moves by ~1.5 eps |X| / (delta e) of itself:
  // bound 8 eps (1 + |c|/e) / delta.
  for (const Ellipse& e : {PaperWarp(0.5, 3), Ellipse{0.5, 3, 1.2, 0.7, -0.9, 0.6}, Ellipse{-0.3, 0.2, 2, 0.1, 1.9, 0.2}}) {
    double worst_rd = 0, worst_rf = 0, worst_scaled_f = 0;
    for (double delta : {1e-3, 1e-4, 1e-5, 1e-6}) {
      for (int edge = 0; edge < 4; ++edge) {
        const double ext = edge < 2 ? std::hypot(e.ax, e.bx) : std::hypot(e.ay, e.by);
        const double scale = (1 + std::hypot(e.cx, e.cy) / ext) / delta;
        auto ref_of = [&](const Ellipse& ee, const Box& rr) { return (edge < 2 ? RefAreaX : RefAreaY)(ee, rr); };
        const Box r = window(e, edge, delta, false);
        const double ref = ref_of(e, r);
        const double rd = std::fabs(AreaD(e, r) - ref) / ref;
        EXPECT_LT(rd, 1e-13 + 8 * kEpsD * scale) << delta << " edge " << edge;
        worst_rd = std::max(worst_rd, rd);
        const Ellipse ef = ToFloat(e);
        const Box rf = ToFloat(r);
        const double ref_f = ref_of(ef, rf);
        const double rel_f = std::fabs(AreaF(e, r) - ref_f) / ref_f;
        EXPECT_LT(rel_f, 1e-5 + 8 * kEpsF * scale) << delta << " edge " << edge;
        worst_rf = std::max(worst_rf, rel_f);
        worst_scaled_f = std::max(worst_scaled_f, rel_f / (kEpsF * scale));
        // Centre inside: the rest of the ellipse.
        const Box r2 = window(e, edge, delta, true);
        EXPECT_NEAR(AreaD(e, r2) / e.Area(), 1 - ref / e.Area(), 4 * kEpsD);
      }
    }
    std::printf("  rotated segments (a = %.2f,%.2f b = %.2f,%.2f): max relative error double %.2e, float %.2e "
                "(= %.2f eps_f (1 + |c|/e) / delta)\n",
                e.ax, e.ay, e.bx, e.by, worst_rd, worst_rf, worst_scaled_f);
  }
}

// The paper's warp ellipse in the 1 x 6 warp window with centres from Eq. 2 (k = (1.5, 3.1)) for half
// vectors over the hemisphere, and thinner ellipses (minor/major down to 1e-6), against the reference.
TEST(EllipseWindow, ThinEllipses) {
  std::mt19937_64 rng(95);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<double> ed, ef, kd, kf;
  for (int i = 0; i < 20000; ++i) {
    Ellipse e;
    if (i % 2 == 0) {
      const double z = u(rng), p = 2 * kPi * u(rng), s = std::sqrt(1 - z * z);
      e = PaperWarp(0.5 * (1.5 * s * std::cos(p) + 1), 3 * (3.1 * s * std::sin(p) + 1));
    } else {
      const double ratio = std::pow(10.0, -6 * u(rng)), A = 3, phi = 2 * kPi * u(rng);
      e = {6 * u(rng) - 2, 10 * u(rng) - 2, A * std::cos(phi), A * std::sin(phi), -A * ratio * std::sin(phi),
           A * ratio * std::cos(phi)};
    }
    const Box r{0, 0, 1, 6};
    const double ref = RefAreaX(e, r);
    const double d = std::fabs(AreaD(e, r) - ref) / e.Area();
    ed.push_back(d);
    kd.push_back(d / (kEpsD * Kappa(e, r)));
    const Ellipse e32 = ToFloat(e);
    const double ref32 = RefAreaX(e32, r);
    const double f = std::fabs(AreaF(e, r) - ref32) / e32.Area();
    ef.push_back(f);
    kf.push_back(f / (kEpsF * Kappa(e32, r)));
  }
  const Stats sd = Summarise(ed), sf = Summarise(ef), skd = Summarise(kd), skf = Summarise(kf);
  Print("thin: double |error| / ellipse area", sd);
  Print("thin: double, / (eps kappa)", skd);
  Print("thin: float |error| / ellipse area", sf);
  Print("thin: float, / (eps kappa)", skf);
  EXPECT_LT(skd.max, 4.0);
  EXPECT_LT(skf.max, 4.0);
}

TEST(EllipseWindow, CornersOnTheEllipse) {
  // (6, 4) lies exactly on x^2/100 + y^2/25 = 1.
  const Ellipse e{0, 0, 10, 0, 0, 5};
  // Touching at the corner only: 0.
  EXPECT_LE(AreaD(e, {6, 4, 20, 20}), 1e-14 * e.Area());
  EXPECT_LE(AreaF(e, {6, 4, 20, 20}), 1e-6 * e.Area());
  const Box boxes[] = {{0, 0, 6, 4},    {-20, -20, 6, 4}, {6, -20, 20, 4},  {-20, 4, 6, 20},
                       {-6, -4, 6, 4},  {-6, 0, 6, 4},    {3, 2, 6, 4},     {-6, -4, 6, 4.5}};
  for (const Box& r : boxes) {
    const double ref = RefAreaX(e, r);
    EXPECT_NEAR(AreaD(e, r) / e.Area(), ref / e.Area(), 4 * kEpsD);
    EXPECT_NEAR(AreaF(e, r) / e.Area(), ref / e.Area(), 8 * kEpsF);
  }
  // Rotated ellipse with a window corner placed on the boundary at parameter t (to rounding).
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(0, 1);
  for (const Ellipse& el : {PaperWarp(0.5, 3), Ellipse{0.5, 3, 1.2, 0.7, -0.9, 0.6}}) {
    for (int i = 0; i < 200; ++i) {
      const double t = 2 * kPi * u(rng);
      const double px = el.cx + el.ax * std::cos(t) + el.bx * std::sin(t);
      const double py = el.cy + el.ay * std::cos(t) + el.by * std::sin(t);
      const double wx = 0.01 + 4 * u(rng), wy = 0.01 + 4 * u(rng);
      const int corner = i % 4;
      const Box r{corner & 1 ? px - wx : px, corner & 2 ? py - wy : py, corner & 1 ? px : px + wx,
                  corner & 2 ? py : py + wy};
      const double ref = RefAreaX(el, r);
      EXPECT_NEAR(AreaD(el, r) / el.Area(), ref / el.Area(), 4 * kEpsD * Kappa(el, r)) << i;
      const Ellipse ef = ToFloat(el);
      const Box rf = ToFloat(r);
      EXPECT_NEAR(AreaF(el, r) / ef.Area(), RefAreaX(ef, rf) / ef.Area(), 4 * kEpsF * Kappa(ef, rf)) << i;
    }
  }
}

// (c) Properties.
TEST(EllipseWindow, RangeAdditivityInvariance) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<double> add_d, add_f;
  for (int i = 0; i < 20000; ++i) {
    const Config c = RandomConfig(rng);
    const Ellipse& e = c.e;
    const Box& r = c.r;
    const double a = AreaD(e, r);
    const float af = AreaF(e, r);
    ASSERT_GE(a, 0.0);
    ASSERT_LE(a, std::min(e.Area(), r.Area()));
    ASSERT_GE(af, 0.0f);
    ASSERT_LE(af, std::min(static_cast<float>(kPi) * std::fabs(static_cast<float>(e.ax) * static_cast<float>(e.by) -
                                                                 static_cast<float>(e.ay) * static_cast<float>(e.bx)),
                           (static_cast<float>(r.x1) - static_cast<float>(r.x0)) *
                               (static_cast<float>(r.y1) - static_cast<float>(r.y0))));
    // Additivity: split at a random x and at a random y.
    const double xm = r.x0 + (r.x1 - r.x0) * u(rng), ym = r.y0 + (r.y1 - r.y0) * u(rng);
    const double k = Kappa(e, r);
    const double sx = AreaD(e, {r.x0, r.y0, xm, r.y1}) + AreaD(e, {xm, r.y0, r.x1, r.y1});
    const double sy = AreaD(e, {r.x0, r.y0, r.x1, ym}) + AreaD(e, {r.x0, ym, r.x1, r.y1});
    add_d.push_back(std::max(std::fabs(sx - a), std::fabs(sy - a)) / e.Area() / (kEpsD * k));
    const float xmf = static_cast<float>(xm), ymf = static_cast<float>(ym);
    const float sxf = AreaF(e, {r.x0, r.y0, xmf, r.y1}) + AreaF(e, {xmf, r.y0, r.x1, r.y1});
    const float syf = AreaF(e, {r.x0, r.y0, r.x1, ymf}) + AreaF(e, {r.x0, ymf, r.x1, r.y1});
    const Ellipse ef = ToFloat(e);
    add_f.push_back(std::max(std::fabs(sxf - af), std::fabs(syf - af)) / ef.Area() / (kEpsF * Kappa(ef, r)));
    // Invariance: the same ellipse from (b, a), (-a, b), (a, -b), (-a, -b): bit-identical, since the
    // evaluation only sees the quadratic form and |det|.
    const Ellipse variants[] = {{e.cx, e.cy, e.bx, e.by, e.ax, e.ay},
                                {e.cx, e.cy, -e.ax, -e.ay, e.bx, e.by},
                                {e.cx, e.cy, e.ax, e.ay, -e.bx, -e.by},
                                {e.cx, e.cy, -e.bx, -e.by, -e.ax, -e.ay}};
    for (const Ellipse& v : variants) {
      ASSERT_EQ(AreaD(v, r), a);
      ASSERT_EQ(AreaF(v, r), af);
    }
  }
  const Stats sd = Summarise(add_d), sf = Summarise(add_f);
  Print("additivity: double |A1 + A2 - A| / ellipse / (eps kappa)", sd);
  Print("additivity: float  |A1 + A2 - A| / ellipse / (eps kappa)", sf);
  EXPECT_LT(sd.max, 8.0);
  EXPECT_LT(sf.max, 8.0);
}

// Nothing NaN or Inf for finite inputs: degenerate, extremely thin, tiny and huge ellipses, empty windows.
TEST(EllipseWindow, NeverNonFinite) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(0, 1);
  int checked = 0;
  for (int i = 0; i < 50000; ++i) {
    const double scale = std::pow(10.0, 8 * u(rng) - 4);  // float keeps its squares finite here
    const double ratio = i % 5 == 0 ? 0 : std::pow(10.0, -12 * u(rng));
    const double A = scale * (0.1 + u(rng)), phi = 2 * kPi * u(rng);
    const Ellipse e{scale * (2 * u(rng) - 1), scale * (2 * u(rng) - 1), A * std::cos(phi), A * std::sin(phi),
                    -A * ratio * std::sin(phi) + (i % 7 == 0 ? 2 * A * std::cos(phi) : 0),
                    A * ratio * std::cos(phi) + (i % 7 == 0 ? 2 * A * std::sin(phi) : 0)};
    // Windows snapped to the centre, to the extents, degenerate or inverted now and then.
    double x0 = scale * (2 * u(rng) - 1.5), x1 = x0 + scale * u(rng) * (i % 11 == 0 ? 0 : 2);
    double y0 = scale * (2 * u(rng) - 1.5), y1 = y0 + scale * u(rng) * 2;
    if (i % 3 == 0) x0 = e.cx;
    if (i % 4 == 0) y1 = e.cy;
    if (i % 13 == 0) x1 = e.cx + std::hypot(e.ax, e.bx);
    if (i % 17 == 0) std::swap(y0, y1);
    const Box r{x0, y0, x1, y1};
    const double a = AreaD(e, r);
    const float af = AreaF(e, r);
    ASSERT_TRUE(std::isfinite(a) && a >= 0) << i;
    ASSERT_TRUE(std::isfinite(af) && af >= 0) << i;
    if (!(x1 > x0 && y1 > y0) || e.Area() == 0) {
      ASSERT_EQ(a, 0.0);
    } else {
      ASSERT_LE(a, std::min(e.Area(), r.Area()) * (1 + 4 * kEpsD));
      ++checked;
    }
  }
  EXPECT_GT(checked, 10000);
}

}  // namespace
