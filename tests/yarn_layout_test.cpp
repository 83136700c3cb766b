// Woven yarn layouts (server/yarn/layout.h): over and under at every crossing as the pattern says, positions,
// crimp, frames, tiling, parameter and limit errors, and the fibers generated along a layout. Expected
// values come from the pattern cells and the documented geometry, computed here, not from the code under test.
#include "server/yarn/layout.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <set>
#include <string>
#include <vector>

#include "server/models/weave/pattern.h"
#include "server/models/weave/wif.h"

namespace loomlight::yarn {
namespace {

using models::weave::WeavePattern;

constexpr double kPi = 3.14159265358979323846;

// 4 warps x 3 picks, not square: a straight draw on 4 shafts, treadle t lifting shafts t and t + 1, pressed
// 1, 2, 3. By hand: pick 0 has warps 0, 1 up; pick 1 warps 1, 2; pick 2 warps 2, 3.
const char kWif[] = R"([WIF]
Version=1.1
Date=April 20, 1997
Developers=loomlight
Source Program=hand
[CONTENTS]
WEAVING=yes
WARP=yes
WEFT=yes
THREADING=yes
TIEUP=yes
TREADLING=yes
[WEAVING]
Shafts=4
Treadles=3
Rising Shed=true
[WARP]
Threads=4
[WEFT]
Threads=3
[THREADING]
1=1
2=2
3=3
4=4
[TIEUP]
1=1,2
2=2,3
3=3,4
[TREADLING]
1=1
2=2
3=3
)";

struct Named {
  std::string name;
  WeavePattern pattern;
};

std::vector<Named> Patterns() {
  std::vector<Named> out;
  out.push_back({"plain", models::weave::PlainWeave()});
  WeavePattern twill;
  EXPECT_EQ(models::weave::MakeTwill(2, 1, models::weave::TwillDirection::kRightward, &twill), "");
  out.push_back({"twill 2/1", twill});
  WeavePattern satin;
  EXPECT_EQ(models::weave::MakeSatin(5, 2, models::weave::SatinFace::kWarpFaced, &satin), "");
  out.push_back({"satin 5/2", satin});
  WeavePattern wif;
  EXPECT_EQ(models::weave::ParseWif(kWif, &wif), "");
  out.push_back({"wif 4x3", wif});
  return out;
}

WeavePattern Tile(const WeavePattern& p, int ru, int rv) {
  WeavePattern t{p.warps * ru, p.picks * rv, {}};
  t.cells.resize(size_t(t.warps) * t.picks);
  for (int pick = 0; pick < t.picks; ++pick)
    for (int warp = 0; warp < t.warps; ++warp)
      t.cells[size_t(pick) * t.warps + warp] = p.at(warp % p.warps, pick % p.picks);
  return t;
}

WovenLayout Build(const WeavePattern& pattern, const LayoutParams& params) {
  WovenLayout layout;
  EXPECT_EQ(BuildLayout(pattern, params, &layout), "");
  return layout;
}

double PolylineLength(const std::vector<Vec3>& v) {
  double l = 0;
  for (size_t i = 1; i < v.size(); ++i) l += Norm(v[i] - v[i - 1]);
  return l;
}

// Distance from point p to segment ab.
double PointSegment(Vec3 p, Vec3 a, Vec3 b) {
  const Vec3 d = b - a;
  const double t = std::clamp(Dot(p - a, d) / Dot(d, d), 0.0, 1.0);
  return Norm(p - (a + t * d));
}

// Smallest distance between any warp and any weft centre polyline (vertex to segment, both ways).
double MinWarpWeftDistance(const WovenLayout& layout) {
  double best = 1e300;
  for (const LayoutYarn& a : layout.yarns) {
    if (!a.warp) continue;
    for (const LayoutYarn& b : layout.yarns) {
      if (b.warp) continue;
      for (const Vec3& p : a.vertices)
        for (size_t i = 1; i < b.vertices.size(); ++i)
          best = std::min(best, PointSegment(p, b.vertices[i - 1], b.vertices[i]));
      for (const Vec3& p : b.vertices)
        for (size_t i = 1; i < a.vertices.size(); ++i)
          best = std::min(best, PointSegment(p, a.vertices[i - 1], a.vertices[i]));
    }
  }
  return best;
}

uint64_t ReferenceSplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

// ---- Layout geometry ----

TEST(YarnLayoutTest, WifDraftIsTheHandDrawdown) {
  WeavePattern p;
  ASSERT_EQ(models::weave::ParseWif(kWif, &p), "");
  const WeavePattern expected{4, 3, {1, 1, 0, 0,  //
                                     0, 1, 1, 0,  //
                                     0, 0, 1, 1}};
  EXPECT_EQ(p, expected);
}

TEST(YarnLayoutTest, CrossingsFollowThePattern) {
  for (const Named& n : Patterns()) {
    SCOPED_TRACE(n.name);
    LayoutParams params;
    params.repeats_u = 2;
    params.repeats_v = 3;
    const WovenLayout layout = Build(n.pattern, params);
    const double s = params.spacing, r = params.yarn_radius;
    const int per = params.points_per_crossing;
    ASSERT_EQ(layout.warp_yarns, 2 * n.pattern.warps);
    ASSERT_EQ(layout.weft_yarns, 3 * n.pattern.picks);
    int over = 0, under = 0;
    for (int i = 0; i < layout.warp_yarns; ++i) {
      const LayoutYarn& warp = layout.yarns[size_t(i)];
      for (int j = 0; j < layout.weft_yarns; ++j) {
        const LayoutYarn& weft = layout.yarns[size_t(layout.warp_yarns + j)];
        // The crossing is vertex j * per + per / 2 of the warp and i * per + per / 2 of the weft.
        const Vec3 a = warp.vertices[size_t(j * per + per / 2)];
        const Vec3 b = weft.vertices[size_t(i * per + per / 2)];
        const double x = (i + 0.5) * s, y = (j + 0.5) * s;
        ASSERT_NEAR(a.x, x, 1e-12);
        ASSERT_NEAR(a.y, y, 1e-12);
        ASSERT_NEAR(b.x, x, 1e-12);
        ASSERT_NEAR(b.y, y, 1e-12);
        const bool cell = n.pattern.cells[size_t(j % n.pattern.picks) * n.pattern.warps + i % n.pattern.warps] != 0;
        EXPECT_EQ(a.z > b.z, cell) << "warp " << i << " weft " << j;
        // Full crimp: the centres are at least a diameter apart, so the round yarns do not interpenetrate.
        EXPECT_GE(std::abs(a.z - b.z), 2 * r * (1 - 1e-12)) << "warp " << i << " weft " << j;
        EXPECT_NEAR(std::abs(a.z), r, 1e-15);
        EXPECT_NEAR(std::abs(b.z), r, 1e-15);
        // The curve (not only its vertex list) passes there too.
        double arc = 0;
        for (int k = 1; k <= j * per + per / 2; ++k)
          arc += Norm(warp.vertices[size_t(k)] - warp.vertices[size_t(k - 1)]);
        const Vec3 c = warp.curve.At(arc).position;
        EXPECT_NEAR(Norm(c - a), 0, 1e-12);
        (cell ? over : under)++;
      }
    }
    // Every pattern above has crossings of both kinds.
    EXPECT_GT(over, 0);
    EXPECT_GT(under, 0);
  }
}

TEST(YarnLayoutTest, CountsPositionsAndBounds) {
  for (const Named& n : Patterns()) {
    SCOPED_TRACE(n.name);
    LayoutParams params;
    params.spacing = 0.1;
    params.crimp = 0.7;
    params.repeats_u = 3;
    params.repeats_v = 2;
    const WovenLayout layout = Build(n.pattern, params);
    const double s = params.spacing, h = 0.7 * params.yarn_radius;
    ASSERT_EQ(layout.warp_yarns, 3 * n.pattern.warps);
    ASSERT_EQ(layout.weft_yarns, 2 * n.pattern.picks);
    ASSERT_EQ(layout.yarns.size(), size_t(layout.warp_yarns + layout.weft_yarns));
    EXPECT_NEAR(layout.size_u, 3 * n.pattern.warps * s, 1e-12);
    EXPECT_NEAR(layout.size_v, 2 * n.pattern.picks * s, 1e-12);
    EXPECT_NEAR(layout.height, h, 1e-15);
    EXPECT_NEAR(layout.lower.z, -(h + params.yarn_radius), 1e-15);
    EXPECT_NEAR(layout.upper.z, h + params.yarn_radius, 1e-15);
    EXPECT_EQ(layout.lower.x, 0);
    EXPECT_EQ(layout.lower.y, 0);
    EXPECT_NEAR(layout.upper.x, layout.size_u, 1e-12);
    EXPECT_NEAR(layout.upper.y, layout.size_v, 1e-12);
    std::set<uint64_t> offsets;
    int64_t vertices = 0;
    for (size_t k = 0; k < layout.yarns.size(); ++k) {
      const LayoutYarn& y = layout.yarns[k];
      const bool warp = int(k) < layout.warp_yarns;
      const int index = warp ? int(k) : int(k) - layout.warp_yarns;
      EXPECT_EQ(y.warp, warp);
      EXPECT_EQ(y.index, index);
      EXPECT_EQ(y.thread, index % (warp ? n.pattern.warps : n.pattern.picks));
      offsets.insert(y.seed_offset);
      vertices += int64_t(y.vertices.size());
      const int crossings = warp ? layout.weft_yarns : layout.warp_yarns;
      ASSERT_EQ(y.vertices.size(), size_t(crossings * params.points_per_crossing + 1));
      ASSERT_EQ(y.normals.size(), y.vertices.size());
      const double across = (index + 0.5) * s, end = warp ? layout.size_v : layout.size_u;
      for (size_t m = 0; m < y.vertices.size(); ++m) {
        const Vec3 v = y.vertices[m];
        const double along = warp ? v.y : v.x, fixed = warp ? v.x : v.y;
        EXPECT_EQ(fixed, across);
        EXPECT_NEAR(along, double(m) * s / params.points_per_crossing, 1e-12);
        EXPECT_LE(std::abs(v.z), h * (1 + 1e-12));
        // The round yarn lies inside the reported box.
        EXPECT_GE(v.z - params.yarn_radius, layout.lower.z - 1e-12);
        EXPECT_LE(v.z + params.yarn_radius, layout.upper.z + 1e-12);
        EXPECT_GE(fixed - params.yarn_radius, 0);
        EXPECT_LE(fixed + params.yarn_radius, (warp ? layout.size_u : layout.size_v) + 1e-12);
      }
      // Edge to edge.
      EXPECT_EQ(warp ? y.vertices.front().y : y.vertices.front().x, 0);
      EXPECT_NEAR(warp ? y.vertices.back().y : y.vertices.back().x, end, 1e-12);
    }
    EXPECT_EQ(offsets.size(), layout.yarns.size());
    EXPECT_EQ(layout.vertices, vertices);
  }
}

TEST(YarnLayoutTest, CrimpLengthensTheYarnsAndZeroIsFlat) {
  for (const Named& n : Patterns()) {
    SCOPED_TRACE(n.name);
    LayoutParams params;
    params.repeats_u = 2;
    params.repeats_v = 2;
    std::vector<double> previous;
    for (double crimp : {0.0, 0.25, 0.5, 1.0}) {
      params.crimp = crimp;
      const WovenLayout layout = Build(n.pattern, params);
      std::vector<double> lengths;
      for (const LayoutYarn& y : layout.yarns) {
        const double straight = y.warp ? layout.size_v : layout.size_u;
        const double length = y.curve.Length();
        EXPECT_NEAR(length, PolylineLength(y.vertices), 1e-12 * straight);
        EXPECT_GE(length, straight * (1 - 1e-12));
        if (crimp == 0) {
          EXPECT_NEAR(length, straight, 1e-12 * straight);
          for (size_t m = 0; m < y.vertices.size(); ++m) {
            EXPECT_EQ(y.vertices[m].z, 0);
            EXPECT_EQ(y.normals[m], (Vec3{0, 0, 1}));
          }
        }
        lengths.push_back(length);
      }
      if (!previous.empty())
        for (size_t k = 0; k < lengths.size(); ++k) {
          // Every yarn of these patterns changes sides somewhere, so more crimp makes it strictly longer.
          EXPECT_GT(lengths[k], previous[k] * (1 + 1e-9)) << "yarn " << k << " crimp " << crimp;
        }
      previous = lengths;
    }
  }
}

// A half cosine of amplitude h per crossing interval s is longer than s by a known integral; check the plain
// weave's yarn length against it (every interval of a plain weave changes sides).
TEST(YarnLayoutTest, PlainWeaveLengthMatchesTheHalfCosine) {
  LayoutParams params;
  params.points_per_crossing = 256;
  const WovenLayout layout = Build(models::weave::PlainWeave(), params);
  const double s = params.spacing, h = params.yarn_radius;
  // Arc length of z = h cos(pi t / s) over one s, by the midpoint rule.
  double interval = 0;
  const int steps = 100000;
  for (int i = 0; i < steps; ++i) {
    const double t = (i + 0.5) * s / steps;
    const double dz = -h * kPi / s * std::sin(kPi * t / s);
    interval += std::sqrt(1 + dz * dz) * s / steps;
  }
  for (const LayoutYarn& y : layout.yarns) EXPECT_NEAR(y.curve.Length(), 2 * interval, 2e-5 * s);
}

TEST(YarnLayoutTest, FramesAreOrthonormalAndUpright) {
  LayoutParams tight;  // the steepest crimp on the tightest spacing with the fewest points
  tight.spacing = 2 * tight.yarn_radius;
  tight.crimp = 1;
  tight.points_per_crossing = kMinPointsPerCrossing;
  LayoutParams loose;
  loose.repeats_u = 2;
  for (const LayoutParams& params : {tight, loose, LayoutParams{}}) {
    for (const Named& n : Patterns()) {
      SCOPED_TRACE(n.name);
      const WovenLayout layout = Build(n.pattern, params);
      double max_turn = 0;
      for (const LayoutYarn& y : layout.yarns) {
        const Vec3 along = y.warp ? Vec3{0, 1, 0} : Vec3{1, 0, 0};
        double arc = 0;
        for (size_t m = 0; m < y.vertices.size(); ++m) {
          if (m > 0) arc += Norm(y.vertices[m] - y.vertices[m - 1]);
          const CurveFrame f = y.curve.At(arc);
          EXPECT_NEAR(Norm(f.tangent), 1, 1e-12);
          EXPECT_NEAR(Norm(f.normal), 1, 1e-12);
          EXPECT_NEAR(Dot(f.tangent, f.normal), 0, 1e-12);
          EXPECT_NEAR(Norm(f.position - y.vertices[m]), 0, 1e-12);
          EXPECT_GT(Dot(f.tangent, along), 0.5);  // runs forward, never steeper than 60 degrees
          EXPECT_GT(f.normal.z, 0.5);             // ply 0 starts on the upper side
          // The normal is +z made perpendicular to the tangent: no sideways component.
          EXPECT_NEAR(Dot(f.normal, y.warp ? Vec3{1, 0, 0} : Vec3{0, 1, 0}), 0, 1e-12);
          EXPECT_NEAR(Norm(y.normals[m]), 1, 1e-12);
          if (m > 0 && m + 1 < y.vertices.size()) {
            const Vec3 a = y.vertices[m] - y.vertices[m - 1], b = y.vertices[m + 1] - y.vertices[m];
            max_turn = std::max(max_turn, std::acos(std::clamp(Dot(a, b) / (Norm(a) * Norm(b)), -1.0, 1.0)));
          }
        }
      }
      // Well inside PolylineYarnCurve's 60 degrees (the header's reading: 34 degrees at worst).
      EXPECT_LT(max_turn * 180 / kPi, 35);
    }
  }
}

TEST(YarnLayoutTest, RepeatsEqualTheTiledPattern) {
  for (const Named& n : Patterns()) {
    SCOPED_TRACE(n.name);
    LayoutParams params;
    params.repeats_u = 2;
    params.repeats_v = 3;
    const WovenLayout repeated = Build(n.pattern, params);
    LayoutParams once = params;
    once.repeats_u = once.repeats_v = 1;
    const WeavePattern tiled = Tile(n.pattern, 2, 3);
    const WovenLayout whole = Build(tiled, once);
    EXPECT_EQ(repeated.size_u, whole.size_u);
    EXPECT_EQ(repeated.size_v, whole.size_v);
    EXPECT_EQ(repeated.vertices, whole.vertices);
    ASSERT_EQ(repeated.yarns.size(), whole.yarns.size());
    for (size_t k = 0; k < whole.yarns.size(); ++k) {
      const LayoutYarn& a = repeated.yarns[k];
      const LayoutYarn& b = whole.yarns[k];
      EXPECT_EQ(a.warp, b.warp);
      EXPECT_EQ(a.index, b.index);
      EXPECT_EQ(a.seed_offset, b.seed_offset);
      EXPECT_EQ(b.thread, b.index % (b.warp ? tiled.warps : tiled.picks));
      EXPECT_EQ(a.vertices, b.vertices) << "yarn " << k;
      EXPECT_EQ(a.normals, b.normals) << "yarn " << k;
    }
  }
}

// Patches side by side join: a yarn ends at the height and slope it starts with (the pattern is periodic).
TEST(YarnLayoutTest, PatchesJoinAtTheEdges) {
  for (const Named& n : Patterns()) {
    SCOPED_TRACE(n.name);
    const WovenLayout layout = Build(n.pattern, LayoutParams{});
    for (const LayoutYarn& y : layout.yarns) {
      const size_t last = y.vertices.size() - 1;
      EXPECT_NEAR(y.vertices[0].z, y.vertices[last].z, 1e-15);
      EXPECT_NEAR(y.vertices[1].z - y.vertices[0].z, y.vertices[last].z - y.vertices[last - 1].z, 1e-15);
    }
  }
}

// The reading on contact: at the default spacing the crossing round yarns touch only at crossings (up to the
// polyline's chords cutting the crests: 0.25% at 16 points per crossing, 0.02% at 64); at a tight spacing
// the half cosine brings them closer than a diameter near the crossings.
TEST(YarnLayoutTest, DefaultSpacingLeavesNoContact) {
  const double diameter = 2 * LayoutParams{}.yarn_radius;
  for (const Named& n : Patterns()) {
    SCOPED_TRACE(n.name);
    const double d16 = MinWarpWeftDistance(Build(n.pattern, LayoutParams{}));
    EXPECT_GE(d16, diameter * (1 - 0.003));
    EXPECT_LE(d16, diameter * (1 + 1e-12));  // they do touch at the crossings
    LayoutParams fine;
    fine.points_per_crossing = 64;
    EXPECT_GE(MinWarpWeftDistance(Build(n.pattern, fine)), diameter * (1 - 0.0003));
  }
  LayoutParams tight;
  tight.spacing = 2.2 * tight.yarn_radius;
  const double d = MinWarpWeftDistance(Build(models::weave::PlainWeave(), tight));
  EXPECT_LT(d, 1.45 * tight.yarn_radius);  // measured 1.39 yarn radii
  EXPECT_GT(d, 1.3 * tight.yarn_radius);
}

TEST(YarnLayoutTest, BadParametersNameTheField) {
  const auto nan = std::nan("");
  const auto inf = INFINITY;
  struct Case {
    std::function<void(LayoutParams&)> change;
    std::string field;
  };
  const std::vector<Case> cases = {
      {[](LayoutParams& p) { p.yarn_radius = 0; }, "yarn_radius"},
      {[&](LayoutParams& p) { p.yarn_radius = nan; }, "yarn_radius"},
      {[](LayoutParams& p) { p.yarn_radius = 2e3; }, "yarn_radius"},
      {[](LayoutParams& p) { p.spacing = 1.99 * p.yarn_radius; }, "spacing"},
      {[&](LayoutParams& p) { p.spacing = inf; }, "spacing"},
      {[&](LayoutParams& p) { p.spacing = nan; }, "spacing"},
      {[](LayoutParams& p) { p.spacing = -1; }, "spacing"},
      {[](LayoutParams& p) { p.crimp = -0.01; }, "crimp"},
      {[](LayoutParams& p) { p.crimp = 1.01; }, "crimp"},
      {[&](LayoutParams& p) { p.crimp = nan; }, "crimp"},
      {[](LayoutParams& p) { p.repeats_u = 0; }, "repeats_u"},
      {[](LayoutParams& p) { p.repeats_u = kMaxLayoutRepeats + 1; }, "repeats_u"},
      {[](LayoutParams& p) { p.repeats_v = -3; }, "repeats_v"},
      {[](LayoutParams& p) { p.repeats_v = kMaxLayoutRepeats + 1; }, "repeats_v"},
      {[](LayoutParams& p) { p.points_per_crossing = 6; }, "points_per_crossing"},
      {[](LayoutParams& p) { p.points_per_crossing = 9; }, "points_per_crossing"},
      {[](LayoutParams& p) { p.points_per_crossing = kMaxPointsPerCrossing + 2; }, "points_per_crossing"},
  };
  const WeavePattern plain = models::weave::PlainWeave();
  for (size_t i = 0; i < cases.size(); ++i) {
    LayoutParams p;
    cases[i].change(p);
    WovenLayout layout;
    layout.warp_yarns = 7;  // must be cleared
    const std::string e = BuildLayout(plain, p, &layout);
    EXPECT_EQ(e.rfind(cases[i].field + ": ", 0), 0u) << "case " << i << ": " << e;
    EXPECT_EQ(ValidateLayoutParams(p), e);
    EXPECT_TRUE(layout.yarns.empty());
    EXPECT_EQ(layout.warp_yarns, 0);
  }
  // The boundaries themselves are accepted.
  LayoutParams edge;
  edge.spacing = 2 * edge.yarn_radius;
  edge.crimp = 0;
  edge.points_per_crossing = kMinPointsPerCrossing;
  EXPECT_EQ(ValidateLayoutParams(edge), "");
  edge.crimp = 1;
  edge.points_per_crossing = kMaxPointsPerCrossing;
  EXPECT_EQ(ValidateLayoutParams(edge), "");

  WovenLayout layout;
  EXPECT_EQ(BuildLayout(WeavePattern{0, 2, {}}, LayoutParams{}, &layout).rfind("pattern: ", 0), 0u);
  EXPECT_EQ(BuildLayout(WeavePattern{2, 2, {1, 0, 2, 1}}, LayoutParams{}, &layout).rfind("pattern: ", 0), 0u);
  EXPECT_TRUE(layout.yarns.empty());
}

TEST(YarnLayoutTest, PatchLimitsNameTheField) {
  WeavePattern satin16;
  ASSERT_EQ(models::weave::MakeSatin(16, 3, models::weave::SatinFace::kWarpFaced, &satin16), "");
  const WeavePattern plain = models::weave::PlainWeave();
  WovenLayout layout;
  LayoutParams p;
  p.points_per_crossing = kMinPointsPerCrossing;
  // Yarns: 16 warps x 129 repeats = 2064 > kMaxLayoutYarns.
  p.repeats_u = kMaxLayoutYarns / 16 + 1;
  std::string e = BuildLayout(satin16, p, &layout);
  EXPECT_EQ(e.rfind("repeats_u: ", 0), 0u) << e;
  p.repeats_u = 1;
  p.repeats_v = kMaxLayoutYarns / 16 + 1;
  e = BuildLayout(satin16, p, &layout);
  EXPECT_EQ(e.rfind("repeats_v: ", 0), 0u) << e;
  // Extent: 2 warps x 2 repeats x 200 = 800 > kMaxLayoutExtent.
  p = LayoutParams{};
  p.yarn_radius = 1;
  p.spacing = 200;
  p.repeats_u = 2;
  e = BuildLayout(plain, p, &layout);
  EXPECT_EQ(e.rfind("repeats_u: ", 0), 0u) << e;
  p.repeats_u = 1;
  p.repeats_v = 2;
  e = BuildLayout(plain, p, &layout);
  EXPECT_EQ(e.rfind("repeats_v: ", 0), 0u) << e;
  p.repeats_v = 1;  // 400 x 400 fits
  EXPECT_EQ(BuildLayout(plain, p, &layout), "");
  // Vertices: a 16 x 16 satin at 8 x 8 repeats is 128 + 128 yarns of 128 * 32 + 1 vertices = 1,048,832.
  p = LayoutParams{};
  p.repeats_u = p.repeats_v = 8;
  p.points_per_crossing = 32;
  e = BuildLayout(satin16, p, &layout);
  EXPECT_EQ(e.rfind("points_per_crossing: ", 0), 0u) << e;
  EXPECT_TRUE(layout.yarns.empty());
  p.points_per_crossing = 30;  // 983,296 vertices fit
  EXPECT_EQ(BuildLayout(satin16, p, &layout), "");
  EXPECT_EQ(layout.vertices, 256 * (128 * 30 + 1));
}

// ---- Fibers along a layout ----

// A lighter yarn than cotton1 for the repeated generations (same geometry rules).
YarnParams LightYarn() {
  YarnParams y;
  EXPECT_EQ(YarnPreset("cotton1", &y), "");
  y.fibers_per_ply = 20;
  y.hair_density = 8;
  y.loop_density = 5;
  return y;
}

WovenLayout TwillLayout(int repeats) {
  WeavePattern twill;
  EXPECT_EQ(models::weave::MakeTwill(2, 1, models::weave::TwillDirection::kRightward, &twill), "");
  LayoutParams params;
  params.repeats_u = params.repeats_v = repeats;
  return Build(twill, params);
}

TEST(YarnLayoutTest, GenerateIsDeterministicWithPerYarnSeeds) {
  const WovenLayout layout = TwillLayout(1);
  const YarnParams yarn = LightYarn();
  DetailOptions options;
  LayoutGeometry a, b, c, d;
  ASSERT_EQ(GenerateLayout(yarn, layout, options, YarnLimits{}, &a), "");
  ASSERT_EQ(GenerateLayout(yarn, layout, options, YarnLimits{}, &b), "");
  EXPECT_TRUE(a.yarns == b.yarns);
  options.threads = 3;
  ASSERT_EQ(GenerateLayout(yarn, layout, options, YarnLimits{}, &c), "");
  EXPECT_TRUE(a.yarns == c.yarns);
  YarnParams other = yarn;
  other.seed = 2;
  ASSERT_EQ(GenerateLayout(other, layout, DetailOptions{}, YarnLimits{}, &d), "");
  ASSERT_EQ(d.yarns.size(), a.yarns.size());
  for (size_t k = 0; k < a.yarns.size(); ++k) EXPECT_FALSE(a.yarns[k] == d.yarns[k]) << "yarn " << k;

  // The documented seed: SplitMix64(SplitMix64(seed) ^ seed_offset), checked against a reference SplitMix64
  // (whose first output from 0 is the published 0xE220A8397B1DCDAF), and distinct per yarn.
  ASSERT_EQ(ReferenceSplitMix64(0), 0xE220A8397B1DCDAFull);
  std::set<uint64_t> seeds;
  ASSERT_EQ(a.yarns.size(), layout.yarns.size());
  for (size_t k = 0; k < layout.yarns.size(); ++k) {
    const LayoutYarn& y = layout.yarns[k];
    const uint64_t seed = ReferenceSplitMix64(ReferenceSplitMix64(yarn.seed) ^ y.seed_offset);
    EXPECT_EQ(LayoutYarnSeed(yarn.seed, y.seed_offset), seed);
    seeds.insert(seed);
    // Each yarn is exactly GenerateYarn along its curve with its own seed.
    YarnParams p = yarn;
    p.seed = seed;
    YarnGeometry alone;
    ASSERT_EQ(GenerateYarn(p, y.curve, DetailOptions{}, YarnLimits{}, &alone), "");
    EXPECT_TRUE(alone == a.yarns[k]) << "yarn " << k;
  }
  EXPECT_EQ(seeds.size(), layout.yarns.size());
  // Different seeds show: the first fiber of warp yarns 0 and 1 sits at a different place in its ply (the two
  // yarns are translates of each other along x where their crossings agree, so compare relative to the centre).
  const LayoutYarn& w0 = layout.yarns[0];
  const LayoutYarn& w1 = layout.yarns[1];
  const auto offset = [](const YarnGeometry& g, const LayoutYarn& y) {
    for (const FiberCurve& f : g.fibers)
      if (f.type == FiberType::kMigration) return f.points.front() - y.vertices.front();
    return Vec3{};
  };
  EXPECT_GT(Norm(offset(a.yarns[0], w0) - offset(a.yarns[1], w1)), 1e-6);

  // Totals add up, and the fibers follow their yarn: every control point within a few yarn radii of the
  // yarn's centre line (hairs reach 3 ply radii past the ply centre).
  int64_t curves = 0, points = 0;
  for (size_t k = 0; k < a.yarns.size(); ++k) {
    curves += int64_t(a.yarns[k].fibers.size());
    points += a.yarns[k].control_points;
    const LayoutYarn& y = layout.yarns[k];
    const double across = (y.index + 0.5) * LayoutParams{}.spacing;
    for (const FiberCurve& f : a.yarns[k].fibers)
      for (const Vec3& q : f.points) ASSERT_LE(std::abs((y.warp ? q.x : q.y) - across), 4 * yarn.yarn_radius);
  }
  EXPECT_EQ(a.fibers, curves);
  EXPECT_EQ(a.control_points, points);
}

TEST(YarnLayoutTest, LimitsApplyToTheWholeLayout) {
  const WovenLayout layout = TwillLayout(1);
  const YarnParams yarn = LightYarn();
  DetailOptions no_core;  // every fiber explicit, so the flyaways make more curves than fibers
  no_core.core = false;
  LayoutGeometry full;
  ASSERT_EQ(GenerateLayout(yarn, layout, no_core, YarnLimits{}, &full), "");
  const int64_t yarns = int64_t(layout.yarns.size());
  const int64_t fibers = yarns * yarn.plies * yarn.fibers_per_ply;
  ASSERT_GT(full.fibers, fibers);
  // Exactly at the totals: accepted, same geometry.
  LayoutGeometry g;
  ASSERT_EQ(GenerateLayout(yarn, layout, no_core, YarnLimits{full.fibers, full.control_points}, &g), "");
  EXPECT_TRUE(g.yarns == full.yarns);
  // With core fibers there are fewer curves than fibers; the fibers still count (as for one yarn).
  LayoutGeometry cored;
  ASSERT_EQ(GenerateLayout(yarn, layout, DetailOptions{}, YarnLimits{}, &cored), "");
  ASSERT_LT(cored.fibers, fibers);
  EXPECT_EQ(GenerateLayout(yarn, layout, DetailOptions{}, YarnLimits{fibers, cored.control_points}, &g), "");
  EXPECT_EQ(GenerateLayout(yarn, layout, DetailOptions{}, YarnLimits{fibers - 1, cored.control_points}, &g)
                .rfind("max_fibers: ", 0),
            0u);
  // Each yarn alone is far under the limits below; only the layout's total is over.
  ASSERT_LT(full.yarns[0].fibers.size() * 2, size_t(full.fibers));
  struct Case {
    YarnLimits limits;
    std::string field;
  };
  const Case cases[] = {
      {{fibers - 1, full.control_points}, "max_fibers"},             // caught before generating
      {{full.fibers - 1, full.control_points}, "max_fibers"},        // caught at the last curves
      {{full.fibers, full.control_points - 1}, "max_control_points"},
      {{full.fibers, 10}, "max_control_points"},                     // caught before generating
      {{-1, full.control_points}, "max_fibers"},
      {{full.fibers, -1}, "max_control_points"},
  };
  for (const Case& c : cases) {
    LayoutGeometry out;
    out.fibers = 99;
    const std::string e = GenerateLayout(yarn, layout, no_core, c.limits, &out);
    EXPECT_EQ(e.rfind(c.field + ": ", 0), 0u) << e;
    EXPECT_TRUE(out.yarns.empty());
    EXPECT_EQ(out.fibers, 0);
  }
  // Bad yarn parameters and options keep their own field names.
  YarnParams bad = yarn;
  bad.plies = 0;
  LayoutGeometry out;
  EXPECT_EQ(GenerateLayout(bad, layout, DetailOptions{}, YarnLimits{}, &out).rfind("plies: ", 0), 0u);
  DetailOptions options;
  options.threads = 0;
  EXPECT_EQ(GenerateLayout(yarn, layout, options, YarnLimits{}, &out).rfind("threads: ", 0), 0u);
  // Cancellation ends with no geometry.
  options = DetailOptions{};
  options.stop = [] { return true; };
  EXPECT_EQ(GenerateLayout(yarn, layout, options, YarnLimits{}, &out), "cancelled");
  EXPECT_TRUE(out.yarns.empty());
}

// Measurement, not a bound: a 2 x 2-repeat 2/1 twill patch of cotton1 at full detail.
TEST(YarnLayoutTest, MeasureTwillPatchOfCotton1) {
  const WovenLayout layout = TwillLayout(2);
  YarnParams yarn;
  ASSERT_EQ(YarnPreset("cotton1", &yarn), "");
  LayoutGeometry g;
  YarnLimits limits;
  limits.max_fibers = 1'000'000;
  limits.max_control_points = 100'000'000;
  const auto start = std::chrono::steady_clock::now();
  ASSERT_EQ(GenerateLayout(yarn, layout, DetailOptions{}, limits, &g), "");
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("twill 2/1, 2x2 repeats, cotton1 full detail: %zu yarns, %lld layout vertices, %lld fiber curves, "
              "%lld control points, %.3f s\n",
              layout.yarns.size(), (long long)layout.vertices, (long long)g.fibers, (long long)g.control_points,
              seconds);
  EXPECT_EQ(layout.yarns.size(), 12u);
  EXPECT_GT(g.fibers, 12 * 3);
}

}  // namespace
}  // namespace loomlight::yarn
