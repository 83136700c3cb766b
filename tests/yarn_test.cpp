// Procedural yarn geometry (SPEC.md section 6): presets, the fiber cross-section density D(R) by a
// chi-square test (and a proof that the test can fail), twist and migration periods measured on the
// generated curves, flyaway counts against the densities, Eq. 4's level of detail, determinism, hostile
// parameters and limits, and the generic centre-curve input. The measurements recompute the ply frames from
// SPEC's formulas, not from the generator's code.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "server/yarn/curve.h"
#include "server/yarn/yarn.h"

namespace loomlight::yarn {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

YarnParams Preset(const std::string& name) {
  YarnParams p;
  EXPECT_EQ(YarnPreset(name, &p), "") << name;
  return p;
}

YarnGeometry Generate(const YarnParams& p, const DetailOptions& o = {}, const YarnLimits& limits = {}) {
  YarnGeometry g;
  const std::string err = GenerateStraightYarn(p, o, limits, &g);
  EXPECT_EQ(err, "");
  return g;
}

DetailOptions NoCore() {
  DetailOptions o;
  o.core = false;
  return o;
}

// A point of a straight yarn (along z from the origin, N_yarn = +x) in its ply's cross-section, from SPEC
// section 6 directly: the ply centre at R_ply / 2 at angle 2 pi j / K + 2 pi z / alpha_yarn, N_ply outwards,
// B_ply = z x N_ply; `radius` in ply radii (the ellipse undone) and `angle` in the ply frame.
struct PlyCoordinates {
  double radius;
  double angle;
};
PlyCoordinates InPly(const YarnParams& p, int ply, Vec3 point) {
  const double phi = 2 * kPi * ply / p.plies + 2 * kPi * point.z / p.alpha_yarn;
  const double nx = std::cos(phi), ny = std::sin(phi);
  const double dx = point.x - 0.5 * p.yarn_radius * nx, dy = point.y - 0.5 * p.yarn_radius * ny;
  const double u = (dx * nx + dy * ny) / p.ellipse_n, v = (-dx * ny + dy * nx) / p.ellipse_b;
  return {std::hypot(u, v), std::atan2(v, u)};
}

// Least-squares slope of y over x.
double Slope(const std::vector<double>& x, const std::vector<double>& y) {
  double mx = 0, my = 0;
  for (size_t i = 0; i < x.size(); ++i) mx += x[i], my += y[i];
  mx /= double(x.size()), my /= double(y.size());
  double sxy = 0, sxx = 0;
  for (size_t i = 0; i < x.size(); ++i) sxy += (x[i] - mx) * (y[i] - my), sxx += (x[i] - mx) * (x[i] - mx);
  return sxy / sxx;
}

// Angles made continuous (steps between neighbours in (-pi, pi]).
std::vector<double> Unwrap(std::vector<double> a) {
  for (size_t i = 1; i < a.size(); ++i) a[i] -= 2 * kPi * std::round((a[i] - a[i - 1]) / (2 * kPi));
  return a;
}

int Count(const YarnGeometry& g, FiberType type) {
  return int(std::count_if(g.fibers.begin(), g.fibers.end(), [&](const FiberCurve& c) { return c.type == type; }));
}

// ---- Presets ----

TEST(YarnPresets, AreSpecSectionSix) {
  const std::vector<std::string> names = {"cotton1", "cotton2", "polyester1", "rayon2", "silk1"};
  EXPECT_EQ(YarnPresetNames(), names);
  struct Row {
    int k, n;
    double radius, e_long, e_short, alpha, alpha_yarn, eps, beta, s, rho_min, hair, loop;
  };
  const Row rows[] = {{3, 75, .0378, .0257, .0200, .366, .453, 0, .201, 1.0, .85, 30.36, 19.10},
                      {3, 36, .0330, .0247, .0180, .435, .336, .0109, .417, 1.9, .95, 20.53, 15.39},
                      {2, 60, .0287, .0285, .0211, .380, .370, .339, .423, 1.1, .70, 31.49, 34.11},
                      {2, 79, .0287, .0283, .0209, .378, .372, .242, .389, 1.5, .80, 47.31, 36.51},
                      {3, 33, .0376, .0253, .0216, .460, .526, 0, .485, 0.1, .95, 24.87, 20.67}};
  for (size_t i = 0; i < names.size(); ++i) {
    SCOPED_TRACE(names[i]);
    const YarnParams p = Preset(names[i]);
    const Row& r = rows[i];
    EXPECT_EQ(p.plies, r.k);
    EXPECT_EQ(p.fibers_per_ply, r.n);
    EXPECT_EQ(p.yarn_radius, r.radius);
    EXPECT_EQ(p.ellipse_b, r.e_long);  // elongated across the ply's displacement (Sec. 3.1)
    EXPECT_EQ(p.ellipse_n, r.e_short);
    EXPECT_EQ(p.alpha, r.alpha);
    EXPECT_EQ(p.alpha_yarn, r.alpha_yarn);
    EXPECT_EQ(p.eps, r.eps);
    EXPECT_EQ(p.beta, r.beta);
    EXPECT_EQ(p.s, r.s);
    EXPECT_EQ(p.rho_min, r.rho_min);
    EXPECT_EQ(p.rho_max, 1.0);
    EXPECT_EQ(p.hair_density, r.hair);
    EXPECT_EQ(p.loop_density, r.loop);
    EXPECT_DOUBLE_EQ(p.fiber_width, 2 * std::sqrt(r.e_long * r.e_short / r.n));
    EXPECT_EQ(ValidateYarnParams(p), "");
  }
  EXPECT_EQ(Preset("cotton1"), YarnParams()) << "the defaults are cotton1";
  YarnParams p;
  const std::string err = YarnPreset("wool\n9", &p);
  EXPECT_EQ(err.rfind("preset: unknown yarn preset 'wool\\n9'", 0), 0u) << err;
}

TEST(YarnDensity, IsSpecFormula) {
  const double e = std::exp(1.0);
  for (double eps : {0.0, 0.2, 0.339, 0.7}) {
    for (double beta : {0.0, 0.201, 1.0, 5.0}) {
      EXPECT_NEAR(FiberDensity(0, eps, beta), 1 - eps, 1e-15);
      EXPECT_NEAR(FiberDensity(1, eps, beta), beta == 0 ? 1 - eps : eps, 1e-15);
      for (double r : {0.1, 0.5, 0.9})
        EXPECT_NEAR(FiberDensity(r, eps, beta), (1 - 2 * eps) * std::pow((e - std::exp(r)) / (e - 1), beta) + eps,
                    1e-15);
    }
  }
}

// ---- D(R): chi-square on the radial histogram ----
//
// 10 annuli of equal area in the ply's normalised cross-section; expected counts from D(R) integrated over
// each annulus (Simpson's rule on D(R) R dR, error ~1e-12); no parameter is fitted, so 9 degrees of freedom.
// We reject at p = 0.001: chi^2_9 critical value 27.877. The seeds are fixed, so the test is deterministic.
constexpr int kAnnuli = 10;
constexpr double kChiSquareCritical = 27.877;  // chi-square, 9 degrees of freedom, upper tail 0.001

double Simpson(const std::function<double(double)>& f, double a, double b, int n = 2000) {
  const double h = (b - a) / n;
  double sum = f(a) + f(b);
  for (int i = 1; i < n; ++i) sum += f(a + i * h) * (i % 2 ? 4 : 2);
  return sum * h / 3;
}

// Expected fraction of fibers per annulus for a density `density(R)` per unit area.
std::vector<double> AnnulusFractions(const std::function<double(double)>& density) {
  const auto weight = [&](double r) { return density(r) * r; };
  const double total = Simpson(weight, 0, 1);
  std::vector<double> fractions;
  for (int k = 0; k < kAnnuli; ++k)
    fractions.push_back(Simpson(weight, std::sqrt(double(k) / kAnnuli), std::sqrt(double(k + 1) / kAnnuli)) / total);
  return fractions;
}

double ChiSquare(const std::vector<int>& observed, const std::vector<double>& fractions) {
  double n = 0, chi = 0;
  for (int o : observed) n += o;
  for (size_t k = 0; k < observed.size(); ++k) chi += std::pow(observed[k] - n * fractions[k], 2) / (n * fractions[k]);
  return chi;
}

// The radial histogram of a preset's fibers at z = 0, several thousand fibers, no migration (rho_min =
// rho_max, so every control point sits at its fiber's R_i) and no core (every fiber is a curve).
std::vector<int> RadialHistogram(const std::string& preset, int fibers_per_ply, int* total) {
  YarnParams p = Preset(preset);
  p.fibers_per_ply = fibers_per_ply;
  p.rho_min = p.rho_max = 1;
  p.hair_density = p.loop_density = 0;
  p.length = 0.05;
  p.seed = 20240611;
  const YarnGeometry g = Generate(p, NoCore());
  std::vector<int> counts(kAnnuli, 0);
  *total = 0;
  for (const FiberCurve& c : g.fibers) {
    EXPECT_EQ(c.type, FiberType::kMigration);
    const double r = InPly(p, c.ply, c.points.front()).radius;
    EXPECT_LE(r, 1 + 1e-12);
    // Annulus k holds r^2 in [k/10, (k+1)/10).
    counts[std::min(kAnnuli - 1, int(r * r * kAnnuli))]++;
    ++*total;
  }
  EXPECT_EQ(*total, p.plies * fibers_per_ply);
  return counts;
}

TEST(YarnCrossSection, RadialDistributionMatchesDensity) {
  for (const std::string preset : {"cotton1", "polyester1", "silk1", "cotton2", "rayon2"}) {
    const YarnParams p = Preset(preset);
    int total = 0;
    const std::vector<int> counts = RadialHistogram(preset, 3000, &total);
    const double chi = ChiSquare(counts, AnnulusFractions([&](double r) { return FiberDensity(r, p.eps, p.beta); }));
    std::printf("  D(R) %-10s %5d fibers: chi^2 = %6.2f (9 dof, reject above %.3f)\n", preset.c_str(), total, chi,
                kChiSquareCritical);
    EXPECT_LT(chi, kChiSquareCritical) << preset;
  }
}

// The same statistic on the same fibers against wrong densities must reject: the test above can fail.
TEST(YarnCrossSection, ChiSquareRejectsWrongDensity) {
  int total = 0;
  const std::vector<int> counts = RadialHistogram("cotton1", 3000, &total);
  const YarnParams p = Preset("cotton1");
  const double uniform = ChiSquare(counts, AnnulusFractions([](double) { return 1.0; }));
  const double beta_doubled =
      ChiSquare(counts, AnnulusFractions([&](double r) { return FiberDensity(r, p.eps, 2 * p.beta); }));
  std::printf("  cotton1 against a uniform disk: chi^2 = %.1f; against beta x 2: chi^2 = %.1f\n", uniform,
              beta_doubled);
  EXPECT_GT(uniform, 3 * kChiSquareCritical);
  EXPECT_GT(beta_doubled, kChiSquareCritical);
}

// ---- Twist and migration ----

TEST(YarnTwist, PlyCentresTurnOncePerAlphaYarn) {
  for (const std::string preset : {"cotton1", "polyester1", "silk1"}) {
    YarnParams p = Preset(preset);
    p.length = 2.0;
    const YarnGeometry g = Generate(p);
    ASSERT_EQ(Count(g, FiberType::kCore), p.plies) << preset;
    for (const FiberCurve& c : g.fibers) {
      if (c.type != FiberType::kCore) continue;
      std::vector<double> z, angle;
      for (const Vec3& q : c.points) {
        z.push_back(q.z);
        angle.push_back(std::atan2(q.y, q.x));
        EXPECT_NEAR(std::hypot(q.x, q.y), p.yarn_radius / 2, 1e-15);  // ply centres at R_ply / 2
      }
      angle = Unwrap(angle);
      EXPECT_NEAR(angle.front(), 2 * kPi * c.ply / p.plies - (c.ply * 2 > p.plies ? 2 * kPi : 0), 1e-12);
      const double period = 2 * kPi / Slope(z, angle);
      EXPECT_NEAR(period, p.alpha_yarn, 1e-12 * p.alpha_yarn) << preset << " ply " << c.ply;
    }
  }
}

// The fiber's angle in its ply's frame (N_ply, B_ply), with the ellipse undone, advances by one turn per
// alpha: against the ply's turn by default (counter_twist), with it otherwise.
TEST(YarnTwist, FibersTurnOncePerAlphaAroundTheirPly) {
  for (bool counter : {true, false}) {
    for (const std::string preset : {"cotton1", "rayon2", "silk1"}) {
      YarnParams p = Preset(preset);
      p.counter_twist = counter;
      p.hair_density = p.loop_density = 0;
      p.length = 1.5;
      const YarnGeometry g = Generate(p, NoCore());
      ASSERT_EQ(int(g.fibers.size()), p.plies * p.fibers_per_ply);
      for (const FiberCurve& c : g.fibers) {
        std::vector<double> z, angle;
        for (const Vec3& q : c.points) z.push_back(q.z), angle.push_back(InPly(p, c.ply, q).angle);
        const double period = 2 * kPi / Slope(z, Unwrap(angle));
        ASSERT_NEAR(period, counter ? -p.alpha : p.alpha, 1e-9 * p.alpha) << preset << " fiber " << c.fiber;
      }
    }
  }
}

// Eq. 2: R(z) = R_i (rho_min + (rho_max - rho_min)(cos(s 2 pi z / alpha + theta_i^0) + 1) / 2), i.e.
// a + A cos(w z) + B sin(w z) with w = 2 pi s / alpha and (a - |(A, B)|) / (a + |(A, B)|) = rho_min / rho_max.
// Fitted by least squares on every fiber; the fit with w of s = 1 must not fit (cotton2 has s = 1.9).
TEST(YarnMigration, RadiusFollowsEquationTwo) {
  YarnParams p = Preset("cotton2");
  p.rho_min = 0.5;
  p.hair_density = p.loop_density = 0;
  p.length = 1.0;
  const YarnGeometry g = Generate(p, NoCore());
  const auto fit = [&](const FiberCurve& c, double w, double* ratio) {
    // Normal equations for (a, A, B).
    double m[3][4] = {};
    std::vector<double> rs;
    for (const Vec3& q : c.points) {
      const double f[3] = {1, std::cos(w * q.z), std::sin(w * q.z)}, r = InPly(p, c.ply, q).radius;
      rs.push_back(r);
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) m[i][j] += f[i] * f[j];
        m[i][3] += f[i] * r;
      }
    }
    for (int i = 0; i < 3; ++i)
      for (int k = i + 1; k < 3; ++k) {
        const double factor = m[k][i] / m[i][i];
        for (int j = i; j < 4; ++j) m[k][j] -= factor * m[i][j];
      }
    double x[3];
    for (int i = 2; i >= 0; --i) {
      x[i] = m[i][3];
      for (int j = i + 1; j < 3; ++j) x[i] -= m[i][j] * x[j];
      x[i] /= m[i][i];
    }
    const double amplitude = std::hypot(x[1], x[2]);
    *ratio = (x[0] - amplitude) / (x[0] + amplitude);
    double worst = 0;
    size_t i = 0;
    for (const Vec3& q : c.points) worst = std::max(worst, std::abs(x[0] + x[1] * std::cos(w * q.z) +
                                                                    x[2] * std::sin(w * q.z) - rs[i++]));
    return worst / x[0];
  };
  for (const FiberCurve& c : g.fibers) {
    double ratio = 0, wrong_ratio = 0;
    EXPECT_LT(fit(c, 2 * kPi * p.s / p.alpha, &ratio), 1e-9) << "fiber " << c.fiber;
    EXPECT_NEAR(ratio, p.rho_min / p.rho_max, 1e-9);
    EXPECT_GT(fit(c, 2 * kPi / p.alpha, &wrong_ratio), 0.05) << "fiber " << c.fiber;
  }
}

// ---- Flyaways ----

// Each full fiber twist is a loop with probability loop_density alpha / n and a hair with probability
// hair_density alpha / n; partial twists at the ends stay migration, so a yarn of length L has on average
// K density (L - alpha) of each. Counts are Poisson-like: we accept 4 standard deviations (sqrt(expected)).
TEST(YarnFlyaways, CountsMatchDensities) {
  for (const std::string& preset : YarnPresetNames()) {
    YarnParams p = Preset(preset);
    p.length = 6;
    p.seed = 7;
    const YarnGeometry g = Generate(p);
    const double hairs = p.plies * p.hair_density * (p.length - p.alpha);
    const double loops = p.plies * p.loop_density * (p.length - p.alpha);
    const int hair_count = Count(g, FiberType::kHair), loop_count = Count(g, FiberType::kLoop);
    std::printf("  %-10s hairs %4d (expected %6.1f), loops %4d (expected %6.1f)\n", preset.c_str(), hair_count, hairs,
                loop_count, loops);
    EXPECT_NEAR(hair_count, hairs, 4 * std::sqrt(hairs)) << preset;
    EXPECT_NEAR(loop_count, loops, 4 * std::sqrt(loops)) << preset;
    // The core stands for inner fibers' migration runs only: their flyaways are the same without it.
    const YarnGeometry all = Generate(p, NoCore());
    EXPECT_EQ(Count(all, FiberType::kHair), hair_count);
    EXPECT_EQ(Count(all, FiberType::kLoop), loop_count);
  }
  YarnParams bald = Preset("cotton1");
  bald.hair_density = bald.loop_density = 0;
  bald.length = 3;
  const YarnGeometry g = Generate(bald);
  EXPECT_EQ(Count(g, FiberType::kHair) + Count(g, FiberType::kLoop), 0);
}

// Loops leave the ply (peak reach in (1, 1.5] ply radii) over exactly one twist and join the fiber's
// neighbouring pieces; a hair's tip is 1.5 to 3 ply radii out and its root joins the fiber.
TEST(YarnFlyaways, LoopsAndHairsHaveTheirShapes) {
  YarnParams p = Preset("cotton1");
  p.length = 3;
  const YarnGeometry g = Generate(p, NoCore());
  const auto close = [](Vec3 a, Vec3 b) { return Norm(a - b) < 1e-12; };
  int loops = 0, hairs = 0;
  for (size_t i = 0; i < g.fibers.size(); ++i) {
    const FiberCurve& c = g.fibers[i];
    const bool has_prev = i > 0 && g.fibers[i - 1].fiber == c.fiber && g.fibers[i - 1].ply == c.ply;
    const bool has_next = i + 1 < g.fibers.size() && g.fibers[i + 1].fiber == c.fiber && g.fibers[i + 1].ply == c.ply;
    if (c.type == FiberType::kLoop) {
      ++loops;
      double peak = 0;
      for (const Vec3& q : c.points) peak = std::max(peak, InPly(p, c.ply, q).radius);
      EXPECT_GT(peak, 1.0);
      EXPECT_LE(peak, 1.5 + 1e-9);
      EXPECT_NEAR(c.points.back().z - c.points.front().z, p.alpha, 1e-12);
      // A loop joins what comes before and after it (a migration run, or another loop or hair root).
      if (has_prev && g.fibers[i - 1].type != FiberType::kHair) {
        EXPECT_TRUE(close(g.fibers[i - 1].points.back(), c.points.front()));
      }
      if (has_next) {
        EXPECT_TRUE(close(c.points.back(), g.fibers[i + 1].points.front()) ||
                    g.fibers[i + 1].type == FiberType::kHair);
      }
    } else if (c.type == FiberType::kHair) {
      ++hairs;
      const double first = InPly(p, c.ply, c.points.front()).radius, last = InPly(p, c.ply, c.points.back()).radius;
      const double tip = std::max(first, last), root = std::min(first, last);
      EXPECT_GE(tip, 1.5 - 1e-9);
      EXPECT_LE(tip, 3.0 + 1e-9);
      EXPECT_LE(root, 1.0 + 1e-9);
      const double span = c.points.back().z - c.points.front().z;
      EXPECT_GE(span, 0.25 * p.alpha - 1e-12);
      EXPECT_LE(span, 0.75 * p.alpha + 1e-12);
      // The root end joins the neighbouring piece when there is one on that side.
      if (last < first && has_next) {
        EXPECT_TRUE(close(c.points.back(), g.fibers[i + 1].points.front()) ||
                    g.fibers[i + 1].type == FiberType::kHair);
      }
      if (first < last && has_prev && g.fibers[i - 1].type != FiberType::kHair) {
        EXPECT_TRUE(close(g.fibers[i - 1].points.back(), c.points.front()));
      }
    } else {
      // Migration pieces stay inside the ply (rho_max = 1).
      for (const Vec3& q : c.points) ASSERT_LE(InPly(p, c.ply, q).radius, 1 + 1e-12);
    }
  }
  EXPECT_GT(loops, 50);
  EXPECT_GT(hairs, 100);
}

// ---- Level of detail, Eq. 4 ----

TEST(YarnLevelOfDetail, EquationFourByHand) {
  // cotton1: omega_fiber = 2 sqrt(.0257 * .0200 / 75) = 0.00523577, omega_ply = 2 * .0257 = 0.0514.
  const YarnParams p = Preset("cotton1");
  const double d = p.fiber_width, w = PlyWidth(p);
  EXPECT_NEAR(d, 0.005235774377619163, 1e-15);
  EXPECT_DOUBLE_EQ(w, 0.0514);
  struct Case {
    double footprint, lambda;
    int fibers;  // of n_max = 50
    double core_radius;  // from 0.012 at full detail to the ply's 0.0257
    int points;  // of 16 per twist
  };
  // lambda = (d / F)(w - F) / (w - d); fibers = round(lambda^2 50); core = lambda^2 .012 + (1 - lambda^2) .0257.
  const Case cases[] = {
      {0, 1, 50, 0.012, 16},
      {0.004, 1, 50, 0.012, 16},                                   // footprint below a fiber: full detail
      {d, 1, 50, 0.012, 16},
      {0.01, 0.4695433667760812, 11, 0.02267954766601718, 8},       // lambda^2 = 0.2205
      {0.02, 0.1780635473039728, 2, 0.025265619211764904, 8},       // lambda^2 = 0.0317
      {0.04, 0.03232363756791864, 0, 0.025685685999624976, 8},     // lambda^2 = 0.00104
      {0.0514, 0, 0, 0.0257, 8},                                    // the ply is under the footprint: core only
      {1.0, 0, 0, 0.0257, 8},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.footprint);
    EXPECT_NEAR(LodLambda(d, w, c.footprint), c.lambda, 1e-14);
    const LodChoice lod = ChooseLod(d, w, c.footprint, 50, 0.012, 16);
    EXPECT_NEAR(lod.lambda, c.lambda, 1e-14);
    EXPECT_NEAR(lod.scale, c.lambda * c.lambda, 1e-14);
    EXPECT_EQ(lod.fibers, c.fibers);
    EXPECT_NEAR(lod.core_radius, c.core_radius, 1e-15);
    EXPECT_EQ(lod.points_per_twist, c.points);
  }
  // Continuous at both ends and decreasing in between.
  EXPECT_NEAR(LodLambda(d, w, d * (1 + 1e-9)), 1, 1e-8);
  EXPECT_NEAR(LodLambda(d, w, w * (1 - 1e-9)), 0, 1e-8);
  double previous = 1;
  for (double f = d; f <= w; f += (w - d) / 100) {
    const double lambda = LodLambda(d, w, f);
    EXPECT_LE(lambda, previous + 1e-15);
    previous = lambda;
  }
}

TEST(YarnLevelOfDetail, GeneratorKeepsWhatEquationFourSays) {
  YarnParams p = Preset("cotton1");
  p.length = 1;
  const YarnGeometry full = Generate(p);
  ASSERT_EQ(int(full.plies.size()), p.plies);
  for (const double footprint : {0.0, 0.01, 0.02, 0.06}) {
    SCOPED_TRACE(footprint);
    DetailOptions o;
    o.footprint = footprint;
    const YarnGeometry g = Generate(p, o);
    int cores = 0;
    for (int j = 0; j < p.plies; ++j) {
      // n_max: the fibers outside the core at full detail; the core's full radius: the farthest of the others.
      const int n_max = full.plies[size_t(j)].regular_fibers;
      const LodChoice lod = ChooseLod(p.fiber_width, PlyWidth(p), footprint, n_max, full.plies[size_t(j)].core_radius,
                                      o.points_per_twist);
      EXPECT_EQ(g.plies[size_t(j)].regular_fibers, lod.fibers);
      EXPECT_EQ(g.plies[size_t(j)].core_fibers, p.fibers_per_ply - lod.fibers);
      EXPECT_DOUBLE_EQ(g.plies[size_t(j)].core_radius, lod.core_radius);
      EXPECT_EQ(g.points_per_twist, lod.points_per_twist);
      std::set<int> regular;
      for (const FiberCurve& c : g.fibers) {
        if (c.ply != j) continue;
        if (c.type == FiberType::kMigration) regular.insert(c.fiber);
        if (c.type == FiberType::kCore) {
          ++cores;
          EXPECT_DOUBLE_EQ(c.width, 2 * lod.core_radius);
        }
      }
      EXPECT_EQ(int(regular.size()), lod.fibers);
    }
    EXPECT_EQ(cores, p.plies);
    if (footprint >= PlyWidth(p)) {
      EXPECT_EQ(int(g.fibers.size()), p.plies) << "beyond the ply's width only the cores remain";
    }
  }
  // At full detail the core is the farthest of the fibers within core_radius (0.5 ply radii).
  EXPECT_GT(full.plies[0].core_radius, 0.45 * p.ellipse_b);
  EXPECT_LE(full.plies[0].core_radius, 0.5 * p.ellipse_b);
  EXPECT_GT(full.plies[0].core_fibers, 10);  // about 30% of 75
  EXPECT_LT(full.plies[0].core_fibers, 40);
}

// ---- Determinism, limits, hostile input ----

bool BitwiseEqual(const YarnGeometry& a, const YarnGeometry& b) {
  if (a.fibers.size() != b.fibers.size()) return false;
  for (size_t i = 0; i < a.fibers.size(); ++i) {
    const FiberCurve &x = a.fibers[i], &y = b.fibers[i];
    if (x.type != y.type || x.ply != y.ply || x.fiber != y.fiber || x.points.size() != y.points.size()) return false;
    if (std::memcmp(&x.width, &y.width, sizeof x.width) != 0) return false;
    if (std::memcmp(x.points.data(), y.points.data(), x.points.size() * sizeof(Vec3)) != 0) return false;
  }
  return true;
}

TEST(YarnDeterminism, SameSeedSameBitsDifferentSeedDifferent) {
  YarnParams p = Preset("polyester1");
  p.length = 2;
  p.seed = 42;
  const YarnGeometry a = Generate(p), b = Generate(p);
  EXPECT_TRUE(BitwiseEqual(a, b));
  DetailOptions threaded;
  threaded.threads = 5;
  EXPECT_TRUE(BitwiseEqual(a, Generate(p, threaded))) << "threads must not change the output";
  p.seed = 43;
  const YarnGeometry c = Generate(p);
  EXPECT_FALSE(BitwiseEqual(a, c));
  // Not just a little different: most fibers start elsewhere.
  std::map<std::pair<int, int>, Vec3> starts;
  for (const FiberCurve& f : a.fibers) starts.emplace(std::make_pair(f.ply, f.fiber), f.points.front());
  int moved = 0, compared = 0;
  for (const FiberCurve& f : c.fibers) {
    auto it = starts.find({f.ply, f.fiber});
    if (f.fiber < 0 || it == starts.end()) continue;
    ++compared;
    moved += Norm(it->second - f.points.front()) > 1e-9;
    starts.erase(it);
  }
  EXPECT_GT(moved, compared * 9 / 10);
}

TEST(YarnLimits, EnforcedAtTheExactBoundary) {
  YarnParams p = Preset("cotton1");
  p.length = 2;
  const YarnGeometry g = Generate(p);
  int64_t points = 0;
  for (const FiberCurve& c : g.fibers) points += int64_t(c.points.size());
  EXPECT_EQ(g.control_points, points);
  const int64_t curves = int64_t(g.fibers.size());

  YarnGeometry out;
  EXPECT_EQ(GenerateStraightYarn(p, {}, {curves, points}, &out), "");
  EXPECT_TRUE(BitwiseEqual(out, g));
  std::string err = GenerateStraightYarn(p, {}, {curves - 1, points}, &out);
  EXPECT_EQ(err.rfind("max_fibers: ", 0), 0u) << err;
  EXPECT_TRUE(out.fibers.empty());
  err = GenerateStraightYarn(p, {}, {curves, points - 1}, &out);
  EXPECT_EQ(err.rfind("max_control_points: ", 0), 0u) << err;
  EXPECT_TRUE(out.fibers.empty());
  // Fewer allowed fibers than the yarn has: refused before sampling any.
  err = GenerateStraightYarn(p, {}, {100, 1'000'000'000}, &out);
  EXPECT_EQ(err, "max_fibers: the yarn has 3 x 75 = 225 fibers, more than the limit 100");
  // A yarn far too long for the points: refused from the parameters alone (quickly).
  YarnParams huge = p;
  huge.length = kMaxLength;
  huge.alpha = huge.alpha_yarn = kMinLength;
  err = GenerateStraightYarn(huge, {}, {}, &out);
  EXPECT_EQ(err.rfind("max_control_points: the yarn needs at least ", 0), 0u) << err;
  err = GenerateStraightYarn(p, {}, {-1, 10}, &out);
  EXPECT_EQ(err.rfind("max_fibers: ", 0), 0u) << err;
  err = GenerateStraightYarn(p, {}, {10, -1}, &out);
  EXPECT_EQ(err.rfind("max_control_points: ", 0), 0u) << err;
}

TEST(YarnValidation, HostileParametersNameTheirField) {
  struct Case {
    const char* field;
    std::function<void(YarnParams&)> mutate;
  };
  const auto big = std::numeric_limits<int>::max();
  const std::vector<Case> cases = {
      {"plies", [](YarnParams& p) { p.plies = 0; }},
      {"plies", [](YarnParams& p) { p.plies = -3; }},
      {"plies", [&](YarnParams& p) { p.plies = big; }},
      {"fibers_per_ply", [](YarnParams& p) { p.fibers_per_ply = 0; }},
      {"fibers_per_ply", [&](YarnParams& p) { p.fibers_per_ply = big; }},
      {"yarn_radius", [](YarnParams& p) { p.yarn_radius = kNaN; }},
      {"yarn_radius", [](YarnParams& p) { p.yarn_radius = -0.03; }},
      {"yarn_radius", [](YarnParams& p) { p.yarn_radius = 0; }},
      {"yarn_radius", [](YarnParams& p) { p.yarn_radius = 1e300; }},
      {"ellipse_n", [](YarnParams& p) { p.ellipse_n = kInf; }},
      {"ellipse_b", [](YarnParams& p) { p.ellipse_b = -0.0; }},
      {"alpha", [](YarnParams& p) { p.alpha = kNaN; }},
      {"alpha", [](YarnParams& p) { p.alpha = 1e-300; }},
      {"alpha_yarn", [](YarnParams& p) { p.alpha_yarn = -kInf; }},
      {"eps", [](YarnParams& p) { p.eps = -0.1; }},
      {"eps", [](YarnParams& p) { p.eps = kNaN; }},
      {"eps", [](YarnParams& p) { p.eps = 1.5; }},
      {"beta", [](YarnParams& p) { p.beta = -1; }},
      {"beta", [](YarnParams& p) { p.beta = 1e9; }},
      {"beta", [](YarnParams& p) { p.beta = kNaN; }},
      {"s", [](YarnParams& p) { p.s = -1; }},
      {"s", [](YarnParams& p) { p.s = kInf; }},
      {"rho_max", [](YarnParams& p) { p.rho_max = 0; }},
      {"rho_max", [](YarnParams& p) { p.rho_max = 2; }},
      {"rho_max", [](YarnParams& p) { p.rho_max = kNaN; }},
      {"rho_min", [](YarnParams& p) { p.rho_min = -0.5; }},
      {"rho_min", [](YarnParams& p) { p.rho_min = kNaN; }},
      {"rho_min", [](YarnParams& p) { p.rho_max = 0.5, p.rho_min = 0.6; }},
      {"hair_density", [](YarnParams& p) { p.hair_density = kNaN; }},
      {"hair_density", [](YarnParams& p) { p.hair_density = -1; }},
      {"hair_density", [](YarnParams& p) { p.hair_density = 1e12; }},
      {"hair_density", [](YarnParams& p) { p.hair_density = 300; }},  // > 1 flyaway per fiber twist
      {"loop_density", [](YarnParams& p) { p.loop_density = kInf; }},
      {"fiber_width", [](YarnParams& p) { p.fiber_width = 0; }},
      {"fiber_width", [](YarnParams& p) { p.fiber_width = kNaN; }},
      {"length", [](YarnParams& p) { p.length = kNaN; }},
      {"length", [](YarnParams& p) { p.length = -1; }},
      {"length", [](YarnParams& p) { p.length = 1e9; }},
  };
  for (const Case& c : cases) {
    YarnParams p;
    c.mutate(p);
    const std::string err = ValidateYarnParams(p);
    EXPECT_EQ(err.rfind(std::string(c.field) + ": ", 0), 0u) << c.field << " -> " << err;
    YarnGeometry out;
    EXPECT_EQ(GenerateStraightYarn(p, {}, {}, &out), err);
    EXPECT_TRUE(out.fibers.empty());
  }

  struct OptionCase {
    const char* field;
    std::function<void(DetailOptions&)> mutate;
  };
  const std::vector<OptionCase> option_cases = {
      {"core_radius", [](DetailOptions& o) { o.core_radius = kNaN; }},
      {"core_radius", [](DetailOptions& o) { o.core_radius = 1.5; }},
      {"footprint", [](DetailOptions& o) { o.footprint = kNaN; }},
      {"footprint", [](DetailOptions& o) { o.footprint = -1; }},
      {"footprint", [](DetailOptions& o) { o.footprint = kInf; }},
      {"footprint", [](DetailOptions& o) { o.footprint = 0.01, o.core = false; }},
      {"points_per_twist", [](DetailOptions& o) { o.points_per_twist = 0; }},
      {"points_per_twist", [](DetailOptions& o) { o.points_per_twist = 1 << 30; }},
      {"threads", [](DetailOptions& o) { o.threads = 0; }},
      {"threads", [](DetailOptions& o) { o.threads = 100000; }},
  };
  for (const OptionCase& c : option_cases) {
    DetailOptions o;
    c.mutate(o);
    YarnGeometry out;
    const std::string err = GenerateStraightYarn(YarnParams(), o, {}, &out);
    EXPECT_EQ(err.rfind(std::string(c.field) + ": ", 0), 0u) << c.field << " -> " << err;
  }
  YarnGeometry out;
  const std::string err = GenerateYarn(YarnParams(), StraightYarnCurve(kNaN), {}, {}, &out);
  EXPECT_EQ(err.rfind("curve: ", 0), 0u) << err;
}

// ---- The centre curve ----

PolylineYarnCurve Polyline(std::vector<Vec3> vertices, std::vector<Vec3> normals) {
  PolylineYarnCurve c;
  EXPECT_EQ(PolylineYarnCurve::Make(std::move(vertices), std::move(normals), &c), "");
  return c;
}

TEST(YarnCurve, StraightPolylineIsTheStraightYarn) {
  YarnParams p = Preset("silk1");
  p.length = 1.2;
  const YarnGeometry straight = Generate(p);
  const PolylineYarnCurve line = Polyline({{0, 0, 0}, {0, 0, 0.5}, {0, 0, 1.2}}, {{1, 0, 0}, {1, 0, 0}, {1, 0, 0}});
  YarnGeometry g;
  ASSERT_EQ(GenerateYarn(p, line, {}, {}, &g), "");
  ASSERT_EQ(g.fibers.size(), straight.fibers.size());
  for (size_t i = 0; i < g.fibers.size(); ++i) {
    ASSERT_EQ(g.fibers[i].points.size(), straight.fibers[i].points.size());
    for (size_t k = 0; k < g.fibers[i].points.size(); ++k)
      ASSERT_LT(Norm(g.fibers[i].points[k] - straight.fibers[i].points[k]), 1e-14);
  }
}

// Moving the centre curve rigidly moves every fiber with it.
TEST(YarnCurve, RigidMotionMovesTheFibers) {
  YarnParams p = Preset("rayon2");
  p.length = 0.8;
  const YarnGeometry straight = Generate(p);
  // Rotation by 40 degrees about (1, 2, 2) / 3, then a translation.
  const double a = 40 * kPi / 180, c = std::cos(a), s = std::sin(a);
  const Vec3 u{1.0 / 3, 2.0 / 3, 2.0 / 3}, t{0.3, -1.2, 5};
  const auto rotate = [&](Vec3 v) { return c * v + s * Cross(u, v) + ((1 - c) * Dot(u, v)) * u; };
  const PolylineYarnCurve moved = Polyline({t, rotate({0, 0, 0.8}) + t}, {rotate({1, 0, 0}), rotate({1, 0, 0})});
  YarnGeometry g;
  ASSERT_EQ(GenerateYarn(p, moved, {}, {}, &g), "");
  ASSERT_EQ(g.fibers.size(), straight.fibers.size());
  for (size_t i = 0; i < g.fibers.size(); ++i)
    for (size_t k = 0; k < g.fibers[i].points.size(); ++k)
      ASSERT_LT(Norm(g.fibers[i].points[k] - (rotate(straight.fibers[i].points[k]) + t)), 1e-12);
}

// A yarn going over and under (a woven thread's path): every fiber stays within its reach of the curve.
TEST(YarnCurve, BentPolylineKeepsFibersAroundIt) {
  std::vector<Vec3> vertices, normals;
  for (int i = 0; i <= 40; ++i) vertices.push_back({0.05 * i, 0, 0.1 * std::sin(2 * kPi * 0.05 * i)});
  for (size_t i = 0; i < vertices.size(); ++i) {
    // "Up" in the x-z plane, perpendicular to the polyline's tangent there (the bisector of its segments).
    const auto unit = [](Vec3 v) { return (1 / Norm(v)) * v; };
    Vec3 d{0, 0, 0};
    if (i > 0) d = d + unit(vertices[i] - vertices[i - 1]);
    if (i + 1 < vertices.size()) d = d + unit(vertices[i + 1] - vertices[i]);
    normals.push_back(unit(Vec3{-d.z, 0, d.x}));
  }
  const PolylineYarnCurve path = Polyline(vertices, normals);
  YarnParams p = Preset("cotton1");
  YarnGeometry g;
  ASSERT_EQ(GenerateYarn(p, path, {}, {}, &g), "");
  // Farthest a fiber can be from the centre: R_ply / 2 plus the hair tip reach 3 e_B.
  const double reach = p.yarn_radius / 2 + 3 * p.ellipse_b + 1e-9;
  for (const FiberCurve& f : g.fibers) {
    for (const Vec3& q : f.points) {
      ASSERT_TRUE(std::isfinite(q.x) && std::isfinite(q.y) && std::isfinite(q.z));
      double nearest = 1e9;
      for (size_t i = 0; i + 1 < vertices.size(); ++i) {
        const Vec3 d = vertices[i + 1] - vertices[i];
        const double t = std::clamp(Dot(q - vertices[i], d) / Dot(d, d), 0.0, 1.0);
        nearest = std::min(nearest, Norm(q - (vertices[i] + t * d)));
      }
      ASSERT_LE(nearest, reach);
    }
  }
}

TEST(YarnCurve, BadPolylinesNameTheirField) {
  PolylineYarnCurve c;
  const Vec3 x{1, 0, 0};
  EXPECT_EQ(PolylineYarnCurve::Make({{0, 0, 0}}, {x}, &c).rfind("vertices: ", 0), 0u);
  EXPECT_EQ(PolylineYarnCurve::Make({{0, 0, 0}, {0, 0, 1}}, {x}, &c).rfind("normals: ", 0), 0u);
  EXPECT_EQ(PolylineYarnCurve::Make({{0, 0, 0}, {0, 0, kNaN}}, {x, x}, &c).rfind("vertices: ", 0), 0u);
  EXPECT_EQ(PolylineYarnCurve::Make({{0, 0, 0}, {0, 0, 1e300}}, {x, x}, &c).rfind("vertices: ", 0), 0u);
  EXPECT_EQ(PolylineYarnCurve::Make({{0, 0, 1}, {0, 0, 1}}, {x, x}, &c).rfind("vertices: ", 0), 0u);
  EXPECT_EQ(PolylineYarnCurve::Make({{0, 0, 0}, {0, 0, 1}, {0, 0, 0}}, {x, x, x}, &c).rfind("vertices: ", 0), 0u);
  EXPECT_EQ(PolylineYarnCurve::Make({{0, 0, 0}, {0, 0, 1}}, {x, {2, 0, 0}}, &c).rfind("normals: ", 0), 0u);
  EXPECT_EQ(PolylineYarnCurve::Make({{0, 0, 0}, {0, 0, 1}}, {x, {0, 0, 1}}, &c).rfind("normals: ", 0), 0u);
  EXPECT_EQ(PolylineYarnCurve::Make({{0, 0, 0}, {0, 0, 1}}, {x, {-1, 0, 0}}, &c).rfind("normals: ", 0), 0u);
  EXPECT_EQ(PolylineYarnCurve::Make({{0, 0, 0}, {0, 0, 1}}, {x, {kNaN, 0, 0}}, &c).rfind("normals: ", 0), 0u);
}

}  // namespace
}  // namespace loomlight::yarn
