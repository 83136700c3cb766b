// The cheap visibility of fibers in yarns (Wu and Yuksel Sec. 4.1-4.2 on centre curves, other yarns as
// tubes) against its parts and against rays traced through the fibers of a generated woven patch.
#include "server/yarn/visibility.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <thread>
#include <vector>

#include "server/yarn/fiber_scene.h"
#include "server/yarn/layout.h"

namespace loomlight::yarn {
namespace {

constexpr double kPi = std::numbers::pi;

struct Patch {
  YarnParams params;
  WovenLayout layout;
  LayoutGeometry geometry;
  FiberScene fibers;
  YarnVisibility visibility;
};

// cotton1 on a plain weave, 2 x 2 repeats (8 yarns), fibers at full detail.
std::unique_ptr<Patch> MakePatch() {
  auto patch = std::make_unique<Patch>();
  EXPECT_EQ(YarnPreset("cotton1", &patch->params), "");
  EXPECT_EQ(BuildLayout(models::weave::PlainWeave(), {.repeats_u = 2, .repeats_v = 2}, &patch->layout), "");
  EXPECT_EQ(GenerateLayout(patch->params, patch->layout, {}, {1'000'000, 50'000'000}, &patch->geometry), "");
  std::vector<const YarnGeometry*> yarns;
  for (const YarnGeometry& y : patch->geometry.yarns) yarns.push_back(&y);
  EXPECT_EQ(FiberScene::Build(yarns, {}, &patch->fibers), "");
  std::vector<std::shared_ptr<const YarnCurve>> centres;
  for (const LayoutYarn& y : patch->layout.yarns) centres.push_back(std::make_shared<PolylineYarnCurve>(y.curve));
  EXPECT_EQ(YarnVisibility::Make(patch->params, centres, LayoutParams{}.yarn_radius, {}, nullptr, &patch->visibility), "");
  return patch;
}

TEST(PolylineYarnCurve, ClosestArcFindsTheCrossSectionOfPointsAroundTheCurve) {
  WovenLayout layout;
  ASSERT_EQ(BuildLayout(models::weave::PlainWeave(), {.repeats_u = 3, .repeats_v = 2}, &layout), "");
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> unit(0, 1);
  for (const LayoutYarn& y : layout.yarns) {
    for (int k = 0; k < 200; ++k) {
      const double arc = y.curve.Length() * (0.02 + 0.96 * unit(rng));
      const CurveFrame f = y.curve.At(arc);
      // A point in the cross-section plane at arc, up to a yarn radius out.
      const double angle = 2 * kPi * unit(rng), r = 0.0378 * unit(rng);
      const Vec3 b = Cross(f.tangent, f.normal);
      const Vec3 p = f.position + (r * std::cos(angle)) * f.normal + (r * std::sin(angle)) * b;
      // The interpolated frame's plane is not the polyline's perpendicular exactly: within a small fraction of
      // the radius along the curve.
      EXPECT_NEAR(y.curve.ClosestArc(p), arc, 0.25 * 0.0378) << (y.warp ? "warp " : "weft ") << y.index;
      // ClosestFrame is At(ClosestArc) found in one search (the frame from the segment it ends on).
      double found = -1;
      const CurveFrame g = y.curve.ClosestFrame(p, &found);
      const double closest = y.curve.ClosestArc(p);
      EXPECT_NEAR(found, closest, 1e-12);
      const CurveFrame h = y.curve.At(closest);
      EXPECT_LT(Norm(g.position - h.position), 1e-12);
      EXPECT_LT(Norm(g.tangent - h.tangent), 1e-9);
      EXPECT_LT(Norm(g.normal - h.normal), 1e-9);
    }
  }
  // A curve that doubles back is searched segment by segment.
  PolylineYarnCurve hook;
  ASSERT_EQ(PolylineYarnCurve::Make({{0, 0, 0}, {1, 0, 0}, {1.5, 0.8, 0}, {1.2, 1.6, 0}},
                                    {{0, 0, 1}, {0, 0, 1}, {0, 0, 1}, {0, 0, 1}}, &hook),
            "");
  const double total = hook.Length();
  EXPECT_NEAR(hook.ClosestArc({1.2, 1.65, 0.01}), total, 1e-9);
  EXPECT_NEAR(hook.ClosestArc({0.5, -0.1, 0}), 0.5, 1e-9);
  EXPECT_EQ(hook.ClosestArc({NAN, 0, 0}), 0);
  EXPECT_EQ(StraightYarnCurve(2).ClosestArc({0.1, 0.2, 3}), 2);
}

TEST(YarnVisibility, FibersOfEachPlyLieInThatPlyOfTheCrossSection) {
  const auto patch = MakePatch();
  const YarnParams& p = patch->params;
  int checked = 0;
  for (size_t k = 0; k < patch->geometry.yarns.size(); ++k) {
    for (const FiberCurve& fiber : patch->geometry.yarns[k].fibers) {
      if (fiber.type != FiberType::kMigration) continue;
      for (size_t i = 3; i < fiber.points.size(); i += 7) {
        const CrossSectionPoint x = patch->visibility.Locate(int(k), fiber.points[i]);
        // Ply j's centre is at angle 2 pi j / K, half a yarn radius out.
        const double a = 2 * kPi * fiber.ply / p.plies;
        const double dx = x.x - 0.5 * p.yarn_radius * std::cos(a), dy = x.y - 0.5 * p.yarn_radius * std::sin(a);
        EXPECT_LT(std::hypot(dx, dy), 1.1 * p.ellipse_b) << "yarn " << k << " ply " << fiber.ply;
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 5000);
}

TEST(YarnVisibility, OtherYarnsBlockAsTubesAndTheirOwnDoesNot) {
  const auto patch = MakePatch();
  const WovenLayout& layout = patch->layout;
  // Plain weave cell (0, 0): warp 0 on top (the pattern's cell is 1 there), weft 0 below.
  ASSERT_EQ(models::weave::PlainWeave().at(0, 0), 1);
  const double s = 0.1701, h = layout.height;
  const int warp0 = 0, weft0 = layout.warp_yarns;
  const Vec3 up{0, 0, 1}, down{0, 0, -1};
  EXPECT_TRUE(patch->visibility.OtherYarnsBlock(weft0, {0.5 * s, 0.5 * s, -h}, up, INFINITY));
  EXPECT_FALSE(patch->visibility.OtherYarnsBlock(warp0, {0.5 * s, 0.5 * s, h}, up, INFINITY));
  EXPECT_TRUE(patch->visibility.OtherYarnsBlock(warp0, {0.5 * s, 0.5 * s, h}, down, INFINITY));
  // Not past max_distance: the top yarn is about 2 h above.
  EXPECT_FALSE(patch->visibility.OtherYarnsBlock(weft0, {0.5 * s, 0.5 * s, -h}, up, 0.2 * h));
  // Its own tube never blocks a yarn (a hair above the warp, looking down through it, not as far as the weft),
  // another's does; above the layout nothing does.
  const double r = LayoutParams{}.yarn_radius;
  const Vec3 above{0.5 * s, 0.5 * s, h + 2 * r};
  EXPECT_FALSE(patch->visibility.OtherYarnsBlock(warp0, above, down, 2.5 * r));
  EXPECT_TRUE(patch->visibility.OtherYarnsBlock(weft0, above, down, 2.5 * r));
  EXPECT_FALSE(patch->visibility.OtherYarnsBlock(warp0, {0.5 * s, 0.5 * s, 1.0}, up, INFINITY));
  // A fiber of the weft that strays into the warp's tube (they touch at the crossing) is not blocked by it on
  // the way out: a tube blocks where a ray enters it.
  EXPECT_FALSE(patch->visibility.OtherYarnsBlock(weft0, {0.5 * s, 0.5 * s, h}, up, INFINITY));
  EXPECT_FALSE(patch->visibility.OtherYarnsBlock(weft0, {0.5 * s, 0.5 * s, h}, {0.6, 0.8, 0}, 0.9 * r));
}

// The reference: a patch seen from above, each hit fiber's light and ambient visibility traced through the
// fibers (every yarn), against the slices times the other yarns' tubes, and the occlusion approximations.
TEST(YarnVisibility, ApproximationsOnAWovenPatchAgainstRaysTracedThroughTheFibers) {
  const auto patch = MakePatch();
  const double light[3] = {-0.5, 0.4, 0.768};  // unit, toward the light (the woven scene's)
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> unit(0, 1);
  double shadow_traced = 0, shadow_slices = 0, ambient_traced = 0, ambient_texture = 0, ambient_distance = 0,
         ambient_open_distance = 0;
  int hits = 0;
  const int ambient_rays = 32;
  for (int k = 0; k < 1200; ++k) {
    const float x = float(0.1 + 0.48 * unit(rng)), y = float(0.1 + 0.48 * unit(rng));
    FiberRay camera{{x, y, 1.0f}, {0.01f, -0.02f, -1}};
    FiberHit hit;
    ASSERT_EQ(patch->fibers.Intersect({&camera, 1}, {&hit, 1}), "");
    if (!hit.hit) continue;
    const float r = 0.5f * hit.width;
    const Float3 o{hit.position.x - r * hit.normal.x, hit.position.y - r * hit.normal.y, hit.position.z - r * hit.normal.z};
    const Vec3 origin{o.x, o.y, o.z};
    const auto traced = [&](Vec3 w) {
      const double along = w.x * hit.tangent.x + w.y * hit.tangent.y + w.z * hit.tangent.z;
      const double sine = std::sqrt(std::max(0.0, 1 - along * along));
      FiberRay ray{o, {float(w.x), float(w.y), float(w.z)}, float(1.001 * r / std::max(sine, 0.05))};
      uint8_t blocked = 0;
      EXPECT_EQ(patch->fibers.Occluded({&ray, 1}, {&blocked, 1}), "");
      return blocked ? 0.0 : 1.0;
    };
    const Vec3 l{light[0], light[1], light[2]};
    shadow_traced += traced(l);
    if (!patch->visibility.OtherYarnsBlock(hit.yarn, origin, l, INFINITY))
      shadow_slices += patch->visibility.SelfShadow(patch->visibility.Locate(hit.yarn, origin), l, r);
    double tubes = 0;
    for (int m = 0; m < ambient_rays; ++m) {
      const double z = 1 - 2 * unit(rng), phi = 2 * kPi * unit(rng), rho = std::sqrt(1 - z * z);
      const Vec3 w{rho * std::cos(phi), rho * std::sin(phi), z};
      ambient_traced += traced(w) / ambient_rays;
      tubes += patch->visibility.OtherYarnsBlock(hit.yarn, origin, w, INFINITY) ? 0.0 : 1.0 / ambient_rays;
    }
    const CrossSectionPoint at = patch->visibility.Locate(hit.yarn, origin);
    ambient_texture += tubes * patch->visibility.Occlusion(at, OcclusionMethod::kTexture);
    ambient_distance += tubes * patch->visibility.Occlusion(at, OcclusionMethod::kDistance);
    // As the renderer shades it: the tubes' tabulated openness instead of rays.
    ambient_open_distance += patch->visibility.OtherYarnsOpenness(at) * patch->visibility.Occlusion(at, OcclusionMethod::kDistance);
    ++hits;
  }
  ASSERT_GT(hits, 400);
  for (double* v : {&shadow_traced, &shadow_slices, &ambient_traced, &ambient_texture, &ambient_distance,
                    &ambient_open_distance})
    *v /= hits;
  printf("woven cotton1: %d hits; shadow traced %.3f slices %.3f; ambient traced %.3f texture %.3f distance %.3f "
         "(tabulated openness %.3f)\n",
         hits, shadow_traced, shadow_slices, ambient_traced, ambient_texture, ambient_distance, ambient_open_distance);
  EXPECT_NEAR(shadow_slices, shadow_traced, 0.08);
  EXPECT_NEAR(ambient_texture, ambient_traced, 0.08);
  EXPECT_NEAR(ambient_distance, ambient_traced, 0.08);
  EXPECT_NEAR(ambient_open_distance, ambient_traced, 0.08);
  EXPECT_NEAR(ambient_open_distance, ambient_distance, 0.02);
  EXPECT_EQ(patch->visibility.Occlusion(patch->visibility.Locate(0, {0, 0, 0}), OcclusionMethod::kTraced), 1);
}

// The tabulated openness against its definition: at fibers seen from above and from below and at points in
// the gaps between yarns, the share of 512 random directions that no other yarn's tube blocks.
TEST(YarnVisibility, OpennessIsTheShareOfDirectionsTheTubesLeaveOpen) {
  const auto patch = MakePatch();
  const YarnVisibility& v = patch->visibility;
  std::mt19937_64 rng(31);
  std::uniform_real_distribution<double> unit(0, 1);
  std::vector<std::pair<int, Vec3>> points;
  for (int k = 0; k < 400 && points.size() < 300; ++k) {
    const float x = float(0.1 + 0.48 * unit(rng)), y = float(0.1 + 0.48 * unit(rng));
    const float z = k % 2 ? 1.0f : -1.0f;  // from above and from below
    FiberRay camera{{x, y, z}, {0.01f, -0.02f, -z}};
    FiberHit hit;
    ASSERT_EQ(patch->fibers.Intersect({&camera, 1}, {&hit, 1}), "");
    if (!hit.hit) continue;
    const float r = 0.5f * hit.width;
    points.push_back({hit.yarn, {hit.position.x - r * hit.normal.x, hit.position.y - r * hit.normal.y,
                                 hit.position.z - r * hit.normal.z}});
  }
  ASSERT_GT(points.size(), 200u);
  double sum_abs = 0, sum_table = 0, sum_rays = 0, worst = 0;
  int low = 0;
  for (const auto& [yarn, p] : points) {
    const double table = v.OtherYarnsOpenness(v.Locate(yarn, p));
    ASSERT_GE(table, 0.0);
    ASSERT_LE(table, 1.0);
    const int n = 512;
    int open = 0;
    for (int m = 0; m < n; ++m) {
      const double z = 1 - 2 * unit(rng), phi = 2 * kPi * unit(rng), rho = std::sqrt(1 - z * z);
      open += v.OtherYarnsBlock(yarn, p, {rho * std::cos(phi), rho * std::sin(phi), z}, INFINITY) ? 0 : 1;
    }
    const double rays = double(open) / n;
    low += rays < 0.8;
    sum_abs += std::fabs(table - rays);
    worst = std::max(worst, std::fabs(table - rays));
    sum_table += table;
    sum_rays += rays;
  }
  const double count = double(points.size());
  printf("openness at %zu fiber points: table %.3f, rays %.3f, mean |difference| %.3f, worst %.3f (%d points under "
         "0.8)\n",
         points.size(), sum_table / count, sum_rays / count, sum_abs / count, worst, low);
  EXPECT_GT(low, 20);  // the points see the other yarns: a table of ones would fail
  EXPECT_NEAR(sum_table / count, sum_rays / count, 0.01);
  EXPECT_LT(sum_abs / count, 0.05);  // 512 rays alone differ by ~0.015 from the truth
  EXPECT_LT(worst, 0.25);
}

// Nodes are traced on first use; whichever thread and order gets there, the values are the same.
TEST(YarnVisibility, OpennessDoesNotDependOnTheOrderOfQueries) {
  const auto a = MakePatch();
  const auto b = MakePatch();
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> unit(0, 1);
  std::vector<CrossSectionPoint> at;
  for (int k = 0; k < 4000; ++k) {
    const Vec3 p{0.05 + 0.6 * unit(rng), 0.05 + 0.6 * unit(rng), 0.06 * (unit(rng) - 0.5)};
    const int yarn = int(unit(rng) * a->layout.yarns.size());
    at.push_back(a->visibility.Locate(yarn, p));
  }
  std::vector<double> forward(at.size()), racing(at.size());
  for (size_t i = 0; i < at.size(); ++i) forward[i] = a->visibility.OtherYarnsOpenness(at[i]);
  std::thread other([&] {
    for (size_t i = at.size(); i-- > at.size() / 2;) racing[i] = b->visibility.OtherYarnsOpenness(at[i]);
  });
  for (size_t i = 0; i < at.size() / 2; ++i) racing[i] = b->visibility.OtherYarnsOpenness(at[i]);
  other.join();
  EXPECT_EQ(forward, racing);
  CrossSectionPoint nowhere = at[0];
  nowhere.arc = NAN;
  EXPECT_EQ(a->visibility.OtherYarnsOpenness(nowhere), 1);
  EXPECT_GT(a->visibility.openness_bytes(), 0u);
  EXPECT_LE(a->visibility.openness_bytes(), YarnVisibility::kMaxOpennessBytes);
}

TEST(YarnVisibility, RefusesBadInput) {
  YarnParams p;
  YarnVisibility v;
  EXPECT_EQ(YarnVisibility::Make(p, {}, 0.03, {}, nullptr, &v).rfind("centres:", 0), 0u);
  std::vector<std::shared_ptr<const YarnCurve>> one{std::make_shared<StraightYarnCurve>(1)};
  EXPECT_EQ(YarnVisibility::Make(p, one, NAN, {}, nullptr, &v).rfind("tube_radius:", 0), 0u);
  EXPECT_EQ(YarnVisibility::Make(p, one, 0.03, {.resolution = 4}, nullptr, &v).rfind("resolution:", 0), 0u);
  p.plies = 0;
  EXPECT_EQ(YarnVisibility::Make(p, one, 0.03, {}, nullptr, &v).rfind("plies:", 0), 0u);
  // A yarn index out of range sees nothing (never reads past the curves).
  ASSERT_EQ(YarnVisibility::Make(YarnParams{}, one, 0.03, {}, nullptr, &v), "");
  EXPECT_EQ(v.Locate(7, {0, 0, 0.5}).yarn, -1);
  EXPECT_EQ(v.SelfShadow(v.Locate(7, {0, 0, 0.5}), {1, 0, 0}, 0.001), 1);
  EXPECT_EQ(v.Occlusion(v.Locate(-3, {0, 0, 0.5}), OcclusionMethod::kTexture), 1);
  EXPECT_FALSE(v.OtherYarnsBlock(-1, {0, 0, 0.5}, {1, 0, 0}, INFINITY));
  // One yarn: nothing else to block, no table.
  EXPECT_EQ(v.OtherYarnsOpenness(v.Locate(0, {0, 0, 0.5})), 1);
  EXPECT_EQ(v.OtherYarnsOpenness(v.Locate(9, {0, 0, 0.5})), 1);
  EXPECT_EQ(v.openness_bytes(), 0u);
}

}  // namespace
}  // namespace loomlight::yarn
